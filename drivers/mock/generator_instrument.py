"""The simulated function generator (Keysight 33521B-like, one channel) behind the SCPI mock server.

:meth:`GeneratorInstrument.handle_line` takes one program message and returns the reply line (or
``None`` when it held no query). State changes move the twin's shaker (and a timing fiducial LED on the
sync output, below): with the output ON and a sine
selected, the shaker vibrates at the generator frequency (or sweeps, repeating, as with trigger IMM) with
peak displacement ``s(f) · V_peak`` where ``s`` is the amplifier + shaker sensitivity (mm per V peak) —
the physics, given to the mock like the rig's calibration table — and ``V_peak`` the real voltage at the
amplifier's high-impedance input.

Levels are kept as the instrument keeps them: the open-circuit voltage (EMF behind the fixed 50 Ω output
impedance). The displayed amplitude/offset follow the ``OUTP:LOAD`` setting R: EMF·R/(R+50), so the
displayed value doubles from 50 Ω to INF while the real output stays (Keysight 33500 user's guide,
"Output Termination"). Limits are checked on the EMF in every unit (VPP, VRMS, DBM): 2 mVpp … 20 Vpp and
|offset| + Vpp/2 ≤ 10 V open-circuit. During a sweep the displacement amplitude is that of the start
frequency (the twin's amplitude is piecewise constant; exact for a flat sensitivity table). Non-sine
functions leave the shaker at rest. The status model (error queue, ESR/ESE/SRE/STB) is
:mod:`drivers.mock.scpi_status`.

Sync output and the timing fiducial: ``OUTPut:SYNC ON|OFF`` switches the rear Sync connector (on after
``*RST``, as on the 33500); with a ``sync_led`` (:class:`drivers.sim.fiducial.SyncLed`) it drives that
LED with the carrier's square wave (high over phase 0…π) whatever the main output's state — the
instrument's oscillator runs at the set frequency (or sweep) also with OUTPut OFF, so the fiducial can
blink with the shaker at rest. ``PHASe:SYNChronize`` restarts the oscillator at phase 0 at the instant
the command is executed: the controller, which knows when it sent it and when ``*OPC?`` came back,
knows every later sync edge in its own clock to within that round trip. (UNVERIFIED against a real
33521B: that Sync runs with the output off, and carrier sync during a sweep; the 33500's default sync
in a sweep marks the sweep's start instead.)
"""

from __future__ import annotations

import math
import re
import threading
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Literal

import numpy as np

from drivers.mock.scpi_parser import Pattern, ScpiCommandError, Unit, split_units
from drivers.mock.scpi_status import ERROR_QUEUE_DEPTH, StatusModel
from drivers.sim.fiducial import SyncLed

if TYPE_CHECKING:
    from drivers.clock import Clock
    from drivers.sim.oscillator import OscillatorBody

_Command = tuple[Pattern, Callable[[Unit], None] | None, Callable[[], str] | None]
"""(pattern, setter(unit), query() -> reply) of one SCPI command."""

__all__ = ["ERROR_QUEUE_DEPTH", "LINES_KEPT", "GeneratorInstrument"]

IDN = "Keysight Technologies,33521B,MY00000001,4.03-1.19-2.00-52-00"
SCPI_VERSION = "1999.0"
FREQ_RANGE_HZ = (1e-6, 30e6)
SWEEP_TIME_RANGE_S = (1e-3, 3600.0)  # (UNVERIFIED for a real 33500B)
EMF_RANGE_VPP = (2e-3, 20.0)  # open circuit: 1 mVpp … 10 Vpp into 50 Ω
EMF_PEAK_LIMIT_V = 10.0  # |offset| + amplitude/2, open circuit
SOURCE_OHM = 50.0
LINES_KEPT = 256  # received program messages kept for inspection (the newest)
FUNCTIONS = {"SIN": "SINUSOID", "SQU": "SQUARE", "TRI": "TRIANGLE", "RAMP": "RAMP", "DC": "DC",
             "NOIS": "NOISE", "PULS": "PULSE"}
# Vpp / Vrms per function (crest factor × 2); others as a sine (our choice)
_PP_PER_RMS = {"SIN": 2 * math.sqrt(2), "SQU": 2.0, "TRI": 2 * math.sqrt(3), "RAMP": 2 * math.sqrt(3)}
_NUMBER = re.compile(r"^([+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?)\s*([A-Za-z]*)$")
_SUFFIX = {"": 1.0, "HZ": 1.0, "KHZ": 1e3, "MHZ": 1e6, "V": 1.0, "MV": 1e-3, "S": 1.0, "MS": 1e-3}
_LEVEL_UNITS = ("VPP", "VRMS", "DBM")


def _fmt(value: float) -> str:
    return f"{value:+.14E}"


class GeneratorInstrument:
    """Instrument state + SCPI command set, moving ``body`` (the twin's shaker) on ``clock``.

    sensitivity_mm_per_v: [(f_hz, mm per V peak), ...] of amplifier + shaker (linear interpolation,
    held constant outside the table). ``lines_received`` counts program messages; ``commands_seen`` keeps
    the newest :data:`LINES_KEPT`.
    """

    def __init__(self, body: OscillatorBody, clock: Clock, *,
                 sensitivity_mm_per_v: list[tuple[float, float]] | None = None,
                 identity: str = IDN, sync_led: SyncLed | None = None) -> None:
        self.body = body
        self.clock = clock
        self.sync_led = sync_led
        self._sync_state: tuple[object, bool] | None = None
        table = sensitivity_mm_per_v or [(1.0, 0.5), (100.0, 0.5)]
        self._sens_f = np.array([p[0] for p in table], float)
        self._sens_s = np.array([p[1] for p in table], float)
        self.identity = identity
        self.status = StatusModel()
        self.lock = threading.RLock()
        self.commands_seen: deque[str] = deque(maxlen=LINES_KEPT)
        self.lines_received = 0
        self._replies_pending = 0
        self._reset_state()
        self._commands = self._command_table()
        self._update_sync(self.clock.now_s())  # powered on: the oscillator runs, sync on

    # state ---------------------------------------------------------------------------------------------
    def _reset_state(self) -> None:
        """``*RST`` defaults (Keysight 33500): sine 1 kHz, 100 mVpp into the 50 Ω setting, output OFF."""
        self.function = "SIN"
        self.frequency_hz = 1000.0
        self.load_ohm = 50.0
        self.emf_vpp = 0.2
        self.emf_offset_v = 0.0
        self.volt_unit = "VPP"
        self.output = False
        self.sweep_on = False
        self.sweep_start_hz, self.sweep_stop_hz = 100.0, 1000.0
        self.sweep_spacing = "LIN"
        self.sweep_time_s = 1.0
        self.trigger_source = "IMM"
        self.sync_on = True

    @property
    def errors(self) -> deque[tuple[int, str]]:
        """The error queue (oldest first)."""
        return self.status.errors

    def push_error(self, code: int, message: str | None = None) -> None:
        """Queue an error (20 deep, −350 on overflow) and set its ESR bit."""
        with self.lock:
            self.status.push_error(code, message)

    def real_vpeak(self) -> float:
        """Volts peak at the amplifier's high-impedance input (the open-circuit voltage)."""
        return self.emf_vpp / 2.0

    def sensitivity(self, f_hz: float) -> float:
        return float(np.interp(f_hz, self._sens_f, self._sens_s))

    def _update_sync(self, t: float) -> None:
        """The oscillator (running whatever the output state) and the sync output drive the fiducial LED."""
        led = self.sync_led
        if led is None:
            return
        spacing: Literal["linear", "log"] = "log" if self.sweep_spacing == "LOG" else "linear"
        state = ((self.sweep_start_hz, self.sweep_stop_hz, self.sweep_time_s, spacing) if self.sweep_on
                 else (self.frequency_hz,), self.sync_on)
        if state == self._sync_state:  # unchanged: no new segment in the oscillator's bounded history
            return
        if state[0] != (self._sync_state or (None,))[0]:
            if self.sweep_on:
                led.waveform.sweep(t, self.sweep_start_hz, self.sweep_stop_hz, self.sweep_time_s, spacing,
                                   repeat=True)
            else:
                led.waveform.set_frequency(t, self.frequency_hz)
        led.set_enabled(t, self.sync_on)
        self._sync_state = state

    def _synchronize_phase(self) -> None:
        """``PHASe:SYNChronize``: the oscillator restarts at phase 0 now."""
        if self.sync_led is not None:
            self.sync_led.restart_phase(self.clock.now_s())
            self._sync_state = None  # the new oscillator takes the state at the next update
            self._update_sync(self.clock.now_s())

    def _update_body(self) -> None:
        """Move the twin to the instrument's state: O(1) per call (a sweep is one repeating segment)."""
        t = self.clock.now_s()
        self._update_sync(t)
        active = self.output and self.function == "SIN"
        f_ref = self.sweep_start_hz if self.sweep_on else self.frequency_hz
        self.body.set_amplitude(t, self.sensitivity(f_ref) * self.real_vpeak() if active else 0.0)
        if self.sweep_on and active:
            spacing: Literal["linear", "log"] = "log" if self.sweep_spacing == "LOG" else "linear"
            self.body.sweep(t, self.sweep_start_hz, self.sweep_stop_hz, self.sweep_time_s, spacing,
                            repeat=True)
        else:
            self.body.set_frequency(t, self.frequency_hz if active else 0.0)

    # levels: displayed value in a unit ↔ open-circuit Vpp ----------------------------------------------
    def _display_ratio(self) -> float:
        """Displayed / open-circuit voltage at the load setting."""
        return 1.0 if math.isinf(self.load_ohm) else self.load_ohm / (self.load_ohm + SOURCE_OHM)

    def _to_emf_vpp(self, value: float, unit: str) -> float:
        pp_per_rms = _PP_PER_RMS.get(self.function, _PP_PER_RMS["SIN"])
        if unit == "VRMS":
            value *= pp_per_rms
        elif unit == "DBM":
            # Vrms = √(R · 1 mW) · 10^(dBm/20); the exponent is capped so that absurd levels give inf, not
            # an overflow (they are then out of range)
            value = math.sqrt(1e-3 * self.load_ohm) * 10.0 ** min(value / 20.0, 308.0) * pp_per_rms
        return value / self._display_ratio()

    def _from_emf_vpp(self, emf_vpp: float, unit: str) -> float:
        pp_per_rms = _PP_PER_RMS.get(self.function, _PP_PER_RMS["SIN"])
        shown = emf_vpp * self._display_ratio()
        if unit == "VRMS":
            return shown / pp_per_rms
        if unit == "DBM":
            return 10.0 * math.log10((shown / pp_per_rms) ** 2 / self.load_ohm / 1e-3)
        return shown

    def _emf_amplitude_limits(self) -> tuple[float, float]:
        hi = min(EMF_RANGE_VPP[1], 2.0 * (EMF_PEAK_LIMIT_V - abs(self.emf_offset_v)))
        return EMF_RANGE_VPP[0], hi

    # parameters -----------------------------------------------------------------------------------------
    @staticmethod
    def _one(unit: Unit) -> str:
        if not unit.params:
            raise ScpiCommandError(-109, "Missing parameter")
        if len(unit.params) > 1:
            raise ScpiCommandError(-108, "Parameter not allowed")
        return unit.params[0]

    def _value(self, unit: Unit, lo: float, hi: float, default: float,
               suffixes: dict[str, float] = _SUFFIX) -> tuple[float, str]:
        """A numeric parameter (MIN/MAX/DEF → lo/hi/default) and its unit suffix, not range-checked."""
        text = self._one(unit).upper()
        named = {"MIN": lo, "MINIMUM": lo, "MAX": hi, "MAXIMUM": hi, "DEF": default, "DEFAULT": default}
        if text in named:
            return named[text], ""
        m = _NUMBER.match(text)
        if not m:
            raise ScpiCommandError(-104, "Data type error")
        suffix = m.group(4)
        if suffix not in suffixes:
            raise ScpiCommandError(-131, "Invalid suffix")
        value = float(m.group(1)) * suffixes[suffix]
        if not math.isfinite(value):
            raise ScpiCommandError(-222, "Data out of range")
        return value, suffix

    def _number(self, unit: Unit, lo: float, hi: float, default: float) -> float:
        value, _ = self._value(unit, lo, hi, default)
        if not lo <= value <= hi:
            raise ScpiCommandError(-222, "Data out of range")
        return value

    def _register(self, unit: Unit) -> int:
        """An 8-bit register value (``*ESE``, ``*SRE``): decimal numeric, rounded (IEEE 488.2 §7.7.2)."""
        value, _ = self._value(unit, 0.0, 255.0, 0.0, {"": 1.0})
        rounded = math.floor(value + 0.5)
        if not 0 <= rounded <= 255:
            raise ScpiCommandError(-222, "Data out of range")
        return int(rounded)

    def _choice(self, unit: Unit, choices: dict[str, str]) -> str:
        text = self._one(unit).upper()
        for short, long in choices.items():
            if text in (short, long):
                return short
        raise ScpiCommandError(-224, "Illegal parameter value")

    def _bool(self, unit: Unit) -> bool:
        text = self._one(unit).upper()
        if text in ("1", "ON"):
            return True
        if text in ("0", "OFF"):
            return False
        raise ScpiCommandError(-224, "Illegal parameter value")

    # commands -------------------------------------------------------------------------------------------
    def _set(self, name: str, value: float | str) -> None:
        setattr(self, name, value)
        self._update_body()

    def _set_amplitude(self, u: Unit) -> None:
        lo, hi = self._emf_amplitude_limits()
        unit_lo, unit_hi = (self._from_emf_vpp(v, self.volt_unit) for v in (lo, hi))
        suffixes = {"": 1.0, "V": 1.0, "MV": 1e-3, "VPP": 1.0, "VRMS": 1.0, "DBM": 1.0}
        value, suffix = self._value(u, unit_lo, unit_hi, self._from_emf_vpp(0.2, self.volt_unit), suffixes)
        unit = suffix if suffix in _LEVEL_UNITS else self.volt_unit
        if unit == "DBM" and math.isinf(self.load_ohm):
            raise ScpiCommandError(-221, "Settings conflict")
        emf = self._to_emf_vpp(value, unit)
        if not lo * (1 - 1e-12) <= emf <= hi * (1 + 1e-12):
            raise ScpiCommandError(-222, "Data out of range")
        self._set("emf_vpp", min(max(emf, lo), hi))

    def _set_offset(self, u: Unit) -> None:
        ratio = self._display_ratio()
        room = EMF_PEAK_LIMIT_V - self.emf_vpp / 2.0
        value = self._number(u, -room * ratio, room * ratio, 0.0)
        self._set("emf_offset_v", value / ratio)

    def _set_unit(self, u: Unit) -> None:
        unit = self._choice(u, {v: v for v in _LEVEL_UNITS})
        if unit == "DBM" and math.isinf(self.load_ohm):
            raise ScpiCommandError(-221, "Settings conflict")  # no dBm into high impedance
        self.volt_unit = unit

    def _set_load(self, u: Unit) -> None:
        text = self._one(u).upper()
        self.load_ohm = math.inf if text in ("INF", "INFINITY") else self._number(u, 1.0, 10e3, 50.0)
        if math.isinf(self.load_ohm) and self.volt_unit == "DBM":
            self.volt_unit = "VPP"  # vendor: units are converted to Vpp into high impedance
        self._update_body()  # the real output does not change; only what is displayed does

    def _set_spacing(self, u: Unit) -> None:
        value = self._choice(u, {"LIN": "LINEAR", "LOG": "LOGARITHMIC"})
        if value == "LOG" and min(self.sweep_start_hz, self.sweep_stop_hz) <= 0:
            raise ScpiCommandError(-221, "Settings conflict")
        self._set("sweep_spacing", value)

    def _status_commands(self) -> list[_Command]:
        """IEEE 488.2 common commands and the SCPI-99 SYSTem items."""
        s = self.status

        def set_ese(u: Unit) -> None:
            s.ese = self._register(u)

        def set_sre(u: Unit) -> None:
            s.sre = self._register(u) & ~(1 << 6)  # bit 6 of SRE is ignored

        def rst(_: Unit) -> None:
            self._reset_state()
            self._update_body()

        def syst_err() -> str:
            code, message = s.pop_error()
            return f"{code:+d},\"{message}\""

        return [
            (Pattern("*IDN"), None, lambda: self.identity),
            (Pattern("*RST"), rst, None),
            (Pattern("*CLS"), lambda u: s.clear(), None),
            (Pattern("*OPC"), lambda u: s.operation_complete(), lambda: "1"),
            (Pattern("*WAI"), lambda u: None, None),  # no overlapped commands: nothing to wait for
            (Pattern("*TST"), None, lambda: "0"),  # self-test passed
            (Pattern("*ESR"), None, lambda: str(s.read_esr())),
            (Pattern("*ESE"), set_ese, lambda: str(s.ese)),
            (Pattern("*SRE"), set_sre, lambda: str(s.sre)),
            (Pattern("*STB"), None, lambda: str(s.status_byte(self._replies_pending > 0))),
            (Pattern("*TRG"), lambda u: None, None),
            (Pattern("SYSTem:ERRor[:NEXT]"), None, syst_err),
            (Pattern("SYSTem:ERRor:COUNt"), None, lambda: str(len(s.errors))),
            (Pattern("SYSTem:VERSion"), None, lambda: SCPI_VERSION),
            (Pattern("SYSTem:REMote"), lambda u: None, None),
            (Pattern("SYSTem:LOCal"), lambda u: None, None),
        ]

    def _command_table(self) -> list[_Command]:
        """(pattern, setter(unit), query() -> str)."""
        def freq(attr: str, default: float) -> tuple[Callable[[Unit], None], Callable[[], str]]:
            def setter(u: Unit) -> None:
                self._set(attr, self._number(u, *FREQ_RANGE_HZ, default))
            return setter, lambda: _fmt(getattr(self, attr))

        return [
            *self._status_commands(),
            (Pattern("[SOURce#:]FUNCtion"), lambda u: self._set("function", self._choice(u, FUNCTIONS)),
             lambda: self.function),
            (Pattern("[SOURce#:]FREQuency[:CW]"), *freq("frequency_hz", 1000.0)),
            (Pattern("[SOURce#:]FREQuency:STARt"), *freq("sweep_start_hz", 100.0)),
            (Pattern("[SOURce#:]FREQuency:STOP"), *freq("sweep_stop_hz", 1000.0)),
            (Pattern("[SOURce#:]VOLTage[:AMPLitude]"), self._set_amplitude,
             lambda: _fmt(self._from_emf_vpp(self.emf_vpp, self.volt_unit))),
            (Pattern("[SOURce#:]VOLTage:UNIT"), self._set_unit, lambda: self.volt_unit),
            (Pattern("[SOURce#:]VOLTage:OFFSet"), self._set_offset,
             lambda: _fmt(self.emf_offset_v * self._display_ratio())),
            (Pattern("[SOURce#:]SWEep:SPACing"), self._set_spacing, lambda: self.sweep_spacing),
            (Pattern("[SOURce#:]SWEep:TIME"),
             lambda u: self._set("sweep_time_s", self._number(u, *SWEEP_TIME_RANGE_S, 1.0)),
             lambda: _fmt(self.sweep_time_s)),
            (Pattern("[SOURce#:]SWEep:STATe"), lambda u: self._set("sweep_on", self._bool(u)),
             lambda: "1" if self.sweep_on else "0"),
            (Pattern("OUTPut#[:STATe]"), lambda u: self._set("output", self._bool(u)),
             lambda: "1" if self.output else "0"),
            (Pattern("OUTPut#:SYNC[:STATe]"), lambda u: self._set("sync_on", self._bool(u)),
             lambda: "1" if self.sync_on else "0"),
            (Pattern("[SOURce#:]PHASe:SYNChronize"), lambda u: self._synchronize_phase(), None),
            (Pattern("OUTPut#:LOAD"), self._set_load,
             lambda: "9.9E+37" if math.isinf(self.load_ohm) else _fmt(self.load_ohm)),
            (Pattern("TRIGger#:SOURce"),
             lambda u: setattr(self, "trigger_source", self._choice(u, {"IMM": "IMMEDIATE", "EXT": "EXTERNAL",
                                                                         "BUS": "BUS", "TIM": "TIMER"})),
             lambda: self.trigger_source),
        ]

    def _execute(self, unit: Unit) -> str | None:
        for pattern, setter, query in self._commands:
            suffixes = pattern.match(unit.nodes)
            if suffixes is None:
                continue
            if any(v != 1 for v in suffixes.values()):
                raise ScpiCommandError(-114, "Header suffix out of range")
            if unit.query:
                if query is None:
                    raise ScpiCommandError(-113, "Undefined header")
                if unit.params:
                    raise ScpiCommandError(-108, "Parameter not allowed")
                return str(query())
            if setter is None:
                raise ScpiCommandError(-113, "Undefined header")
            setter(unit)
            return None
        raise ScpiCommandError(-113, "Undefined header")

    def handle_line(self, line: str) -> str | None:
        """Execute one program message; returns the reply (queries joined by ``;``) or None. An error
        goes to the queue and the rest of the message is not executed (replies so far are returned)."""
        with self.lock:
            self.lines_received += 1
            self.commands_seen.append(line)
            replies: list[str] = []
            try:
                for unit in split_units(line):
                    self._replies_pending = len(replies)
                    reply = self._execute(unit)
                    if reply is not None:
                        replies.append(reply)
            except ScpiCommandError as exc:
                self.status.push_error(exc.code, exc.message)
            return ";".join(replies) if replies else None
