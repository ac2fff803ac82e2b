"""The simulated function generator (Keysight 33521B-like, one channel) behind the SCPI mock server.

:meth:`GeneratorInstrument.handle_line` takes one program message and returns the reply line (or
``None`` when it held no query). State changes move the twin's shaker: with the output ON and a sine
selected, the shaker vibrates at the generator frequency (or sweeps) with peak displacement
``s(f) · V_peak`` where ``s`` is the amplifier + shaker sensitivity (mm per V peak) — the physics, given
to the mock like the rig's calibration table — and ``V_peak`` the real voltage at the amplifier's
high-impedance input: the displayed amplitude when ``OUTP:LOAD INF``, twice it with the 50 Ω default.
During a sweep the displacement amplitude is that of the start frequency (the twin's amplitude is
piecewise constant; exact for a flat sensitivity table). Non-sine functions leave the shaker at rest.
"""

from __future__ import annotations

import math
import re
import threading
from collections import deque
from typing import Any

import numpy as np

from drivers.mock.scpi_parser import Pattern, ScpiCommandError, Unit, split_units

__all__ = ["ERROR_QUEUE_DEPTH", "GeneratorInstrument"]

ERROR_QUEUE_DEPTH = 20
IDN = "Keysight Technologies,33521B,MY00000001,4.03-1.19-2.00-52-00"
FREQ_RANGE_HZ = (1e-6, 30e6)
SWEEP_TIME_RANGE_S = (1e-3, 3600.0)  # (UNVERIFIED for a real 33500B)
FUNCTIONS = {"SIN": "SINUSOID", "SQU": "SQUARE", "TRI": "TRIANGLE", "RAMP": "RAMP", "DC": "DC",
             "NOIS": "NOISE", "PULS": "PULSE"}
_NUMBER = re.compile(r"^([+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?)\s*([A-Za-z]*)$")
_SUFFIX = {"": 1.0, "HZ": 1.0, "KHZ": 1e3, "MHZ": 1e6, "V": 1.0, "MV": 1e-3, "VPP": 1.0, "S": 1.0, "MS": 1e-3}


def _fmt(value: float) -> str:
    return f"{value:+.14E}"


class GeneratorInstrument:
    """Instrument state + SCPI command set, moving ``body`` (the twin's shaker) on ``clock``.

    sensitivity_mm_per_v: [(f_hz, mm per V peak), ...] of amplifier + shaker (linear interpolation,
    held constant outside the table).
    """

    def __init__(self, body: Any, clock: Any, *,
                 sensitivity_mm_per_v: list[tuple[float, float]] | None = None,
                 identity: str = IDN) -> None:
        self.body = body
        self.clock = clock
        table = sensitivity_mm_per_v or [(1.0, 0.5), (100.0, 0.5)]
        self._sens_f = np.array([p[0] for p in table], float)
        self._sens_s = np.array([p[1] for p in table], float)
        self.identity = identity
        self.errors: deque[tuple[int, str]] = deque()
        self.lock = threading.RLock()
        self.commands_seen: list[str] = []
        self._sweep_end_s: float | None = None
        self._reset_state()
        self._commands = self._command_table()

    # state ---------------------------------------------------------------------------------------------
    def _reset_state(self) -> None:
        self.function = "SIN"
        self.frequency_hz = 1000.0
        self.amplitude_vpp = 0.1
        self.offset_v = 0.0
        self.volt_unit = "VPP"
        self.load_ohm = 50.0
        self.output = False
        self.sweep_on = False
        self.sweep_start_hz, self.sweep_stop_hz = 100.0, 1000.0
        self.sweep_spacing = "LIN"
        self.sweep_time_s = 1.0
        self.trigger_source = "IMM"

    def push_error(self, code: int, message: str) -> None:
        """Error queue: 20 deep; on overflow the newest entry becomes -350 "Queue overflow"."""
        if len(self.errors) < ERROR_QUEUE_DEPTH:
            self.errors.append((code, message))
        else:
            self.errors[-1] = (-350, "Queue overflow")

    def real_vpeak(self) -> float:
        """Volts peak at the amplifier's high-impedance input."""
        return self.amplitude_vpp / 2.0 * (1.0 if math.isinf(self.load_ohm) else 2.0)

    def sensitivity(self, f_hz: float) -> float:
        return float(np.interp(f_hz, self._sens_f, self._sens_s))

    def advance(self, now_s: float) -> None:
        """Restart a running sweep at each end (trigger IMM sweeps repeat), at the exact end time."""
        with self.lock:
            while self._sweep_end_s is not None and now_s >= self._sweep_end_s:
                t = self._sweep_end_s
                self._start_body_sweep(t)

    def _start_body_sweep(self, t: float) -> None:
        spacing = "log" if self.sweep_spacing == "LOG" else "linear"
        self._sweep_end_s = self.body.sweep(t, self.sweep_start_hz, self.sweep_stop_hz, self.sweep_time_s,
                                            spacing)

    def _update_body(self) -> None:
        t = self.clock.now_s()
        active = self.output and self.function == "SIN"
        f_ref = self.sweep_start_hz if self.sweep_on else self.frequency_hz
        self.body.set_amplitude(t, self.sensitivity(f_ref) * self.real_vpeak() if active else 0.0)
        if self.sweep_on and active:
            self._start_body_sweep(t)
        else:
            self._sweep_end_s = None
            self.body.set_frequency(t, self.frequency_hz if active else 0.0)

    # parameters -----------------------------------------------------------------------------------------
    @staticmethod
    def _one(unit: Unit) -> str:
        if not unit.params:
            raise ScpiCommandError(-109, "Missing parameter")
        if len(unit.params) > 1:
            raise ScpiCommandError(-108, "Parameter not allowed")
        return unit.params[0]

    def _number(self, unit: Unit, lo: float, hi: float, default: float) -> float:
        text = self._one(unit).upper()
        if text in ("MIN", "MINIMUM"):
            return lo
        if text in ("MAX", "MAXIMUM"):
            return hi
        if text in ("DEF", "DEFAULT"):
            return default
        m = _NUMBER.match(text)
        if not m:
            raise ScpiCommandError(-104, "Data type error")
        if m.group(4) not in _SUFFIX:
            raise ScpiCommandError(-131, "Invalid suffix")
        value = float(m.group(1)) * _SUFFIX[m.group(4)]
        if not lo <= value <= hi:
            raise ScpiCommandError(-222, "Data out of range")
        return value

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
    def _amp_range(self) -> tuple[float, float]:
        return (2e-3, 20.0) if math.isinf(self.load_ohm) else (1e-3, 10.0)

    def _set(self, name: str, value: Any) -> None:
        setattr(self, name, value)
        self._update_body()

    def _command_table(self) -> list[tuple[Pattern, Any, Any]]:
        """(pattern, setter(unit), query() -> str)."""
        def freq(attr: str, default: float) -> tuple[Any, Any]:
            def setter(u: Unit) -> None:
                self._set(attr, self._number(u, *FREQ_RANGE_HZ, default))
            return setter, lambda: _fmt(getattr(self, attr))

        def volt(u: Unit) -> None:
            lo, hi = self._amp_range()
            value = self._number(u, lo, hi, 0.1)
            self._set("amplitude_vpp", value if self.volt_unit == "VPP" else value * 2 * math.sqrt(2))

        def load(u: Unit) -> None:
            text = self._one(u).upper()
            value = math.inf if text in ("INF", "INFINITY") else self._number(u, 1.0, 10e3, 50.0)
            self.load_ohm = value
            lo, hi = self._amp_range()
            self.amplitude_vpp = min(max(self.amplitude_vpp, lo), hi)
            self._update_body()

        def spacing(u: Unit) -> None:
            value = self._choice(u, {"LIN": "LINEAR", "LOG": "LOGARITHMIC"})
            if value == "LOG" and min(self.sweep_start_hz, self.sweep_stop_hz) <= 0:
                raise ScpiCommandError(-221, "Settings conflict")
            self._set("sweep_spacing", value)

        def rst(_: Unit) -> None:
            self._reset_state()
            self._update_body()

        def cls(_: Unit) -> None:
            self.errors.clear()

        def syst_err() -> str:
            code, message = self.errors.popleft() if self.errors else (0, "No error")
            return f"{code:+d},\"{message}\""

        f_cw = freq("frequency_hz", 1000.0)
        f_start = freq("sweep_start_hz", 100.0)
        f_stop = freq("sweep_stop_hz", 1000.0)
        return [
            (Pattern("*IDN"), None, lambda: self.identity),
            (Pattern("*RST"), rst, None),
            (Pattern("*CLS"), cls, None),
            (Pattern("*OPC"), lambda u: None, lambda: "1"),
            (Pattern("*TRG"), lambda u: None, None),
            (Pattern("SYSTem:ERRor[:NEXT]"), None, syst_err),
            (Pattern("SYSTem:REMote"), lambda u: None, None),
            (Pattern("SYSTem:LOCal"), lambda u: None, None),
            (Pattern("[SOURce#:]FUNCtion"), lambda u: self._set("function", self._choice(u, FUNCTIONS)),
             lambda: self.function),
            (Pattern("[SOURce#:]FREQuency[:CW]"), *f_cw),
            (Pattern("[SOURce#:]FREQuency:STARt"), *f_start),
            (Pattern("[SOURce#:]FREQuency:STOP"), *f_stop),
            (Pattern("[SOURce#:]VOLTage[:AMPLitude]"), volt,
             lambda: _fmt(self.amplitude_vpp if self.volt_unit == "VPP"
                          else self.amplitude_vpp / 2 / math.sqrt(2))),
            (Pattern("[SOURce#:]VOLTage:UNIT"),
             lambda u: setattr(self, "volt_unit", self._choice(u, {"VPP": "VPP", "VRMS": "VRMS"})),
             lambda: self.volt_unit),
            (Pattern("[SOURce#:]VOLTage:OFFSet"),
             lambda u: setattr(self, "offset_v", self._number(u, -10, 10, 0)),
             lambda: _fmt(self.offset_v)),
            (Pattern("[SOURce#:]SWEep:SPACing"), spacing, lambda: self.sweep_spacing),
            (Pattern("[SOURce#:]SWEep:TIME"),
             lambda u: self._set("sweep_time_s", self._number(u, *SWEEP_TIME_RANGE_S, 1.0)),
             lambda: _fmt(self.sweep_time_s)),
            (Pattern("[SOURce#:]SWEep:STATe"), lambda u: self._set("sweep_on", self._bool(u)),
             lambda: "1" if self.sweep_on else "0"),
            (Pattern("OUTPut#[:STATe]"), lambda u: self._set("output", self._bool(u)),
             lambda: "1" if self.output else "0"),
            (Pattern("OUTPut#:LOAD"), load,
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
                return query()
            if setter is None:
                raise ScpiCommandError(-113, "Undefined header")
            setter(unit)
            return None
        raise ScpiCommandError(-113, "Undefined header")

    def handle_line(self, line: str) -> str | None:
        """Execute one program message; returns the reply (queries joined by ``;``) or None."""
        with self.lock:
            self.advance(self.clock.now_s())
            self.commands_seen.append(line)
            replies: list[str] = []
            try:
                for unit in split_units(line):
                    reply = self._execute(unit)
                    if reply is not None:
                        replies.append(reply)
            except ScpiCommandError as exc:  # the rest of the message is not executed
                self.push_error(exc.code, exc.message)
            return ";".join(replies) if replies else None
