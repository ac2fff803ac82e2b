"""The simulated function generator (Keysight 33500 series: the one-channel 33521B or the two-channel
33522B) behind the SCPI mock server.

:meth:`GeneratorInstrument.handle_line` takes one program message and returns the reply line (or
``None`` when it held no query). Every channel has its own state (function, frequency or sweep, levels,
load, output; ``SOURce1|2``, ``OUTPut1|2``, ``TRIGger1|2``; no suffix means channel 1). Channel 1 feeds
the amplifier of the twin's shaker: with its output ON and a sine selected, the shaker vibrates with peak
displacement ``s(f) · V_peak`` where ``s`` is the amplifier + shaker sensitivity (mm per V peak) — the
physics, given to the mock like the rig's calibration table — and ``V_peak`` the real voltage at the
amplifier's high-impedance input. The shaker's phase is channel 1's phase generator itself: the body
(``body``) follows channel 1's frequency law whatever the output state (the oscillator runs; OUTPut only
connects it), and its amplitude is 0 while the output is OFF or the function is not a sine — so the
shaker's motion is ``A · sin φ₁(t)`` with φ₁ the generator's own phase.

Levels are kept as the instrument keeps them: the open-circuit voltage (EMF behind the fixed 50 Ω output
impedance). The displayed amplitude/offset follow the ``OUTP:LOAD`` setting R: EMF·R/(R+50), so the
displayed value doubles from 50 Ω to INF while the real output stays (Keysight 33500 user's guide,
"Output Termination"). Limits are checked on the EMF in every unit (VPP, VRMS, DBM): 2 mVpp … 20 Vpp and
|offset| + Vpp/2 ≤ 10 V open-circuit. During a sweep the displacement amplitude is that of the start
frequency (the twin's amplitude is piecewise constant; exact for a flat sensitivity table). The status
model (error queue, ESR/ESE/SRE/STB) is :mod:`drivers.mock.scpi_status`.

Sync output and the timing fiducial: the instrument has one Sync connector. ``OUTPut:SYNC ON|OFF``
switches it (on after ``*RST``); on the two-channel model ``OUTPut:SYNC:SOURce CH1|CH2`` chooses the
channel it follows (CH1 after ``*RST``). With a ``sync_led`` (:class:`drivers.sim.fiducial.SyncLed`) the
connector drives that LED with its channel's carrier square wave (high over phase 0…π), whatever that
channel's output state. ``PHASe:SYNChronize`` (either channel's) restarts the phase generators of every
channel at phase 0 at the instant the command is executed — a channel in a sweep restarts its sweep (the
twin's reading) — so both channels share one phase origin: the controller, which knows when it sent the
command and when ``*OPC?`` came back, knows every later sync edge in its own clock to within that round
trip, and channel 1's phase relative to the same edges exactly.

A numeric suffix beyond the model's channels (``SOURce2`` on a 33521B, ``OUTPut3``) is refused with −114
"Header suffix out of range" (SCPI-99's error for it) and ``OUTPut:SYNC:SOURce`` on the one-channel model
with −113 "Undefined header" (the command exists on two-channel models only); a source ``CH2`` there
would be −224. (UNVERIFIED against a real 33521B: which of −113/−114 it queues for ``SOUR2``; that Sync
runs with the output off, carrier sync during a sweep, and the sweep's restart by ``PHAS:SYNC``.)
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

_Command = tuple[Pattern, "Callable[[_Channel, Unit], None] | None", "Callable[[_Channel], str] | None"]
"""(pattern, setter(channel, unit), query(channel) -> reply) of one SCPI command."""

__all__ = ["ERROR_QUEUE_DEPTH", "LINES_KEPT", "MODELS", "GeneratorInstrument", "identity_for"]

MODELS = {"33521B": 1, "33522B": 2}  # model → channels
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
TRIGGER_SOURCES = {"IMM": "IMMEDIATE", "EXT": "EXTERNAL", "BUS": "BUS", "TIM": "TIMER"}
_Law = tuple[float, ...] | tuple[float, float, float, str]


class _Channel:
    """One output channel's state (``*RST`` defaults of the Keysight 33500: sine 1 kHz, 100 mVpp into
    the 50 Ω setting, output OFF) and its level conversions."""

    def __init__(self, number: int) -> None:
        self.number = number
        self.reset()

    def reset(self) -> None:
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

    def law(self) -> _Law:
        """The phase generator's frequency law: (f,) or (start, stop, time, spacing)."""
        if self.sweep_on:
            return (self.sweep_start_hz, self.sweep_stop_hz, self.sweep_time_s, self.spacing())
        return (self.frequency_hz,)

    def spacing(self) -> Literal["linear", "log"]:
        return "log" if self.sweep_spacing == "LOG" else "linear"

    def display_ratio(self) -> float:
        """Displayed / open-circuit voltage at the load setting."""
        return 1.0 if math.isinf(self.load_ohm) else self.load_ohm / (self.load_ohm + SOURCE_OHM)

    def to_emf_vpp(self, value: float, unit: str) -> float:
        pp_per_rms = _PP_PER_RMS.get(self.function, _PP_PER_RMS["SIN"])
        if unit == "VRMS":
            value *= pp_per_rms
        elif unit == "DBM":
            # Vrms = √(R · 1 mW) · 10^(dBm/20); the exponent is capped so that absurd levels give inf, not
            # an overflow (they are then out of range)
            value = math.sqrt(1e-3 * self.load_ohm) * 10.0 ** min(value / 20.0, 308.0) * pp_per_rms
        return value / self.display_ratio()

    def from_emf_vpp(self, emf_vpp: float, unit: str) -> float:
        pp_per_rms = _PP_PER_RMS.get(self.function, _PP_PER_RMS["SIN"])
        shown = emf_vpp * self.display_ratio()
        if unit == "VRMS":
            return shown / pp_per_rms
        if unit == "DBM":
            return 10.0 * math.log10((shown / pp_per_rms) ** 2 / self.load_ohm / 1e-3)
        return shown

    def emf_amplitude_limits(self) -> tuple[float, float]:
        hi = min(EMF_RANGE_VPP[1], 2.0 * (EMF_PEAK_LIMIT_V - abs(self.emf_offset_v)))
        return EMF_RANGE_VPP[0], hi


def identity_for(channels: int) -> str:
    """The ``*IDN?`` reply of the model with ``channels`` outputs (:data:`MODELS`)."""
    model = next(m for m, n in MODELS.items() if n == channels)
    return IDN.replace("33521B", model)


def _fmt(value: float) -> str:
    return f"{value:+.14E}"


class GeneratorInstrument:
    """Instrument state + SCPI command set (see the module docstring), moving ``body`` (the twin's shaker,
    on channel 1) on ``clock``.

    sensitivity_mm_per_v: [(f_hz, mm per V peak), ...] of amplifier + shaker (linear interpolation,
    held constant outside the table). ``identity``: the ``*IDN?`` reply; its model (second field, a key
    of :data:`MODELS`) sets the number of channels. ``lines_received`` counts program messages;
    ``commands_seen`` keeps the newest :data:`LINES_KEPT`.
    """

    def __init__(self, body: OscillatorBody, clock: Clock, *,
                 sensitivity_mm_per_v: list[tuple[float, float]] | None = None,
                 identity: str = IDN, sync_led: SyncLed | None = None) -> None:
        self.body = body
        self.clock = clock
        self.sync_led = sync_led
        model = identity.split(",")[1].strip() if identity.count(",") >= 1 else ""
        self.channel_count = MODELS.get(model, 1)
        self._sync_state: tuple[object, bool] | None = None
        self._body_law: _Law | None = None
        table = sensitivity_mm_per_v or [(1.0, 0.5), (100.0, 0.5)]
        self._sens_f = np.array([p[0] for p in table], float)
        self._sens_s = np.array([p[1] for p in table], float)
        self.identity = identity
        self.status = StatusModel()
        self.lock = threading.RLock()
        self.commands_seen: deque[str] = deque(maxlen=LINES_KEPT)
        self.lines_received = 0
        self._replies_pending = 0
        self.channels = tuple(_Channel(n) for n in range(1, self.channel_count + 1))
        self._reset_state()
        self._commands = self._command_table()
        self._update(self.clock.now_s())  # powered on: the oscillators run, sync on

    # state ---------------------------------------------------------------------------------------------
    def _reset_state(self) -> None:
        """``*RST``: every channel's defaults; the Sync connector on, following channel 1."""
        for ch in self.channels:
            ch.reset()
        self.sync_on = True
        self.sync_source = 1

    def channel(self, number: int) -> _Channel:
        """Channel ``number`` (1-based)."""
        return self.channels[number - 1]

    # channel 1's state (the shaker's), as tests and tools read it
    @property
    def output(self) -> bool:
        return self.channels[0].output

    @property
    def emf_vpp(self) -> float:
        return self.channels[0].emf_vpp

    @property
    def frequency_hz(self) -> float:
        return self.channels[0].frequency_hz

    @property
    def load_ohm(self) -> float:
        return self.channels[0].load_ohm

    @property
    def errors(self) -> deque[tuple[int, str]]:
        """The error queue (oldest first)."""
        return self.status.errors

    def push_error(self, code: int, message: str | None = None) -> None:
        """Queue an error (20 deep, −350 on overflow) and set its ESR bit."""
        with self.lock:
            self.status.push_error(code, message)

    def real_vpeak(self, number: int = 1) -> float:
        """Volts peak of channel ``number`` at the amplifier's high-impedance input (open-circuit)."""
        return self.channel(number).emf_vpp / 2.0

    def sensitivity(self, f_hz: float) -> float:
        return float(np.interp(f_hz, self._sens_f, self._sens_s))

    @staticmethod
    def _drive(body: OscillatorBody, t: float, law: _Law, phase_rad: float | None) -> None:
        """Command an oscillator to a channel's law at ``t`` (phase continuous, or restarted)."""
        if len(law) == 4:
            f0, f1, time_s, spacing = law
            assert isinstance(f0, float) and isinstance(f1, float) and isinstance(time_s, float)
            body.sweep(t, f0, f1, time_s, "log" if spacing == "log" else "linear", repeat=True,
                       phase_rad=phase_rad)
        else:
            body.set_frequency(t, float(law[0]), phase_rad=phase_rad)

    def _update_sync(self, t: float) -> None:
        """The Sync connector (its channel's oscillator, running whatever the output) drives the LED."""
        led = self.sync_led
        if led is None:
            return
        law = self.channel(self.sync_source).law()
        state = ((self.sync_source, law), self.sync_on)
        if state == self._sync_state:  # unchanged: no new segment in the oscillator's bounded history
            return
        if state[0] != (self._sync_state or (None,))[0]:
            self._drive(led.waveform, t, law, None)
        led.set_enabled(t, self.sync_on)
        self._sync_state = state

    def _update_body(self, t: float) -> None:
        """Channel 1's phase generator moves the shaker; its output and function set the amplitude. O(1)
        per call: the frequency law is commanded only when it changes (a sweep is one repeating segment)."""
        ch = self.channels[0]
        law = ch.law()
        if law != self._body_law:
            self._drive(self.body, t, law, None)
            self._body_law = law
        active = ch.output and ch.function == "SIN"
        f_ref = ch.sweep_start_hz if ch.sweep_on else ch.frequency_hz
        amplitude = self.sensitivity(f_ref) * self.real_vpeak(1) if active else 0.0
        if amplitude != float(self.body.amplitude_at_mm(t)):
            self.body.set_amplitude(t, amplitude)

    def _update(self, t: float) -> None:
        self._update_sync(t)
        self._update_body(t)

    def _synchronize_phase(self) -> None:
        """``PHASe:SYNChronize``: every channel's phase generator restarts at phase 0 now."""
        t = self.clock.now_s()
        self._drive(self.body, t, self.channels[0].law(), 0.0)
        self._body_law = self.channels[0].law()
        if self.sync_led is not None:
            self.sync_led.restart_phase(t)
            self._sync_state = None  # the new oscillator takes the state at the next update
        self._update(t)

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
    def _set(self, ch: _Channel, name: str, value: float | str) -> None:
        setattr(ch, name, value)
        self._update(self.clock.now_s())

    def _set_amplitude(self, ch: _Channel, u: Unit) -> None:
        lo, hi = ch.emf_amplitude_limits()
        unit_lo, unit_hi = (ch.from_emf_vpp(v, ch.volt_unit) for v in (lo, hi))
        suffixes = {"": 1.0, "V": 1.0, "MV": 1e-3, "VPP": 1.0, "VRMS": 1.0, "DBM": 1.0}
        value, suffix = self._value(u, unit_lo, unit_hi, ch.from_emf_vpp(0.2, ch.volt_unit), suffixes)
        unit = suffix if suffix in _LEVEL_UNITS else ch.volt_unit
        if unit == "DBM" and math.isinf(ch.load_ohm):
            raise ScpiCommandError(-221, "Settings conflict")
        emf = ch.to_emf_vpp(value, unit)
        if not lo * (1 - 1e-12) <= emf <= hi * (1 + 1e-12):
            raise ScpiCommandError(-222, "Data out of range")
        self._set(ch, "emf_vpp", min(max(emf, lo), hi))

    def _set_offset(self, ch: _Channel, u: Unit) -> None:
        ratio = ch.display_ratio()
        room = EMF_PEAK_LIMIT_V - ch.emf_vpp / 2.0
        value = self._number(u, -room * ratio, room * ratio, 0.0)
        self._set(ch, "emf_offset_v", value / ratio)

    def _set_unit(self, ch: _Channel, u: Unit) -> None:
        unit = self._choice(u, {v: v for v in _LEVEL_UNITS})
        if unit == "DBM" and math.isinf(ch.load_ohm):
            raise ScpiCommandError(-221, "Settings conflict")  # no dBm into high impedance
        ch.volt_unit = unit

    def _set_load(self, ch: _Channel, u: Unit) -> None:
        text = self._one(u).upper()
        ch.load_ohm = math.inf if text in ("INF", "INFINITY") else self._number(u, 1.0, 10e3, 50.0)
        if math.isinf(ch.load_ohm) and ch.volt_unit == "DBM":
            ch.volt_unit = "VPP"  # vendor: units are converted to Vpp into high impedance
        self._update(self.clock.now_s())  # the real output does not change; only what is displayed does

    def _set_spacing(self, ch: _Channel, u: Unit) -> None:
        value = self._choice(u, {"LIN": "LINEAR", "LOG": "LOGARITHMIC"})
        if value == "LOG" and min(ch.sweep_start_hz, ch.sweep_stop_hz) <= 0:
            raise ScpiCommandError(-221, "Settings conflict")
        self._set(ch, "sweep_spacing", value)

    def _set_sync_source(self, u: Unit) -> None:
        choices = {f"CH{n}": f"CH{n}" for n in range(1, self.channel_count + 1)}
        self.sync_source = int(self._choice(u, choices)[2:])
        self._update(self.clock.now_s())

    def _status_commands(self) -> list[_Command]:
        """IEEE 488.2 common commands and the SCPI-99 SYSTem items."""
        s = self.status

        def set_ese(u: Unit) -> None:
            s.ese = self._register(u)

        def set_sre(u: Unit) -> None:
            s.sre = self._register(u) & ~(1 << 6)  # bit 6 of SRE is ignored

        def rst(_: Unit) -> None:
            self._reset_state()
            self._update(self.clock.now_s())

        def syst_err() -> str:
            code, message = s.pop_error()
            return f"{code:+d},\"{message}\""

        def cmd(pattern: str, setter: Callable[[Unit], None] | None,
                query: Callable[[], str] | None) -> _Command:
            return (Pattern(pattern), None if setter is None else (lambda _c, u: setter(u)),
                    None if query is None else (lambda _c: query()))

        return [cmd(*c) for c in [
            ("*IDN", None, lambda: self.identity),
            ("*RST", rst, None),
            ("*CLS", lambda u: s.clear(), None),
            ("*OPC", lambda u: s.operation_complete(), lambda: "1"),
            ("*WAI", lambda u: None, None),  # no overlapped commands: nothing to wait for
            ("*TST", None, lambda: "0"),  # self-test passed
            ("*ESR", None, lambda: str(s.read_esr())),
            ("*ESE", set_ese, lambda: str(s.ese)),
            ("*SRE", set_sre, lambda: str(s.sre)),
            ("*STB", None, lambda: str(s.status_byte(self._replies_pending > 0))),
            ("*TRG", lambda u: None, None),
            ("SYSTem:ERRor[:NEXT]", None, syst_err),
            ("SYSTem:ERRor:COUNt", None, lambda: str(len(s.errors))),
            ("SYSTem:VERSion", None, lambda: SCPI_VERSION),
            ("SYSTem:REMote", lambda u: None, None),
            ("SYSTem:LOCal", lambda u: None, None),
        ]]

    def _command_table(self) -> list[_Command]:
        """(pattern, setter(channel, unit), query(channel) -> str)."""
        def freq(attr: str, default: float) -> tuple[Callable[[_Channel, Unit], None],
                                                     Callable[[_Channel], str]]:
            def setter(ch: _Channel, u: Unit) -> None:
                self._set(ch, attr, self._number(u, *FREQ_RANGE_HZ, default))
            return setter, lambda ch: _fmt(getattr(ch, attr))

        def flag(attr: str) -> tuple[Callable[[_Channel, Unit], None], Callable[[_Channel], str]]:
            return (lambda ch, u: self._set(ch, attr, self._bool(u)),
                    lambda ch: "1" if getattr(ch, attr) else "0")

        def set_sync(_: _Channel, u: Unit) -> None:
            self.sync_on = self._bool(u)
            self._update(self.clock.now_s())

        sync_source: list[_Command] = [] if self.channel_count < 2 else [
            (Pattern("OUTPut:SYNC:SOURce"), lambda ch, u: self._set_sync_source(u),
             lambda ch: f"CH{self.sync_source}")]
        return [
            *self._status_commands(),
            (Pattern("[SOURce#:]FUNCtion"),
             lambda ch, u: self._set(ch, "function", self._choice(u, FUNCTIONS)), lambda ch: ch.function),
            (Pattern("[SOURce#:]FREQuency[:CW]"), *freq("frequency_hz", 1000.0)),
            (Pattern("[SOURce#:]FREQuency:STARt"), *freq("sweep_start_hz", 100.0)),
            (Pattern("[SOURce#:]FREQuency:STOP"), *freq("sweep_stop_hz", 1000.0)),
            (Pattern("[SOURce#:]VOLTage[:AMPLitude]"), self._set_amplitude,
             lambda ch: _fmt(ch.from_emf_vpp(ch.emf_vpp, ch.volt_unit))),
            (Pattern("[SOURce#:]VOLTage:UNIT"), self._set_unit, lambda ch: ch.volt_unit),
            (Pattern("[SOURce#:]VOLTage:OFFSet"), self._set_offset,
             lambda ch: _fmt(ch.emf_offset_v * ch.display_ratio())),
            (Pattern("[SOURce#:]SWEep:SPACing"), self._set_spacing, lambda ch: ch.sweep_spacing),
            (Pattern("[SOURce#:]SWEep:TIME"),
             lambda ch, u: self._set(ch, "sweep_time_s", self._number(u, *SWEEP_TIME_RANGE_S, 1.0)),
             lambda ch: _fmt(ch.sweep_time_s)),
            (Pattern("[SOURce#:]SWEep:STATe"), *flag("sweep_on")),
            (Pattern("OUTPut#[:STATe]"), *flag("output")),
            *sync_source,
            (Pattern("OUTPut#:SYNC[:STATe]"), set_sync, lambda ch: "1" if self.sync_on else "0"),
            (Pattern("[SOURce#:]PHASe:SYNChronize"), lambda ch, u: self._synchronize_phase(), None),
            (Pattern("OUTPut#:LOAD"), self._set_load,
             lambda ch: "9.9E+37" if math.isinf(ch.load_ohm) else _fmt(ch.load_ohm)),
            (Pattern("TRIGger#:SOURce"),
             lambda ch, u: setattr(ch, "trigger_source", self._choice(u, TRIGGER_SOURCES)),
             lambda ch: ch.trigger_source),
        ]

    def _execute(self, unit: Unit) -> str | None:
        for pattern, setter, query in self._commands:
            suffixes = pattern.match(unit.nodes)
            if suffixes is None:
                continue
            numbers = set(suffixes.values()) or {1}
            if len(numbers) > 1 or not 1 <= (number := numbers.pop()) <= self.channel_count:
                raise ScpiCommandError(-114, "Header suffix out of range")
            ch = self.channels[number - 1]
            if unit.query:
                if query is None:
                    raise ScpiCommandError(-113, "Undefined header")
                if unit.params:
                    raise ScpiCommandError(-108, "Parameter not allowed")
                return str(query(ch))
            if setter is None:
                raise ScpiCommandError(-113, "Undefined header")
            setter(ch, unit)
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
