"""Safety limits of a vibration source, checked before any byte is sent.

Sinusoidal motion of peak displacement ``x`` at frequency ``f``: peak velocity ``2πf·x`` and peak
acceleration ``(2πf)²·x``. The same formulas hold for a marker on a rotor at radius ``x`` (centripetal
acceleration, rim speed), so exciter, rotor and shaker share one limits object.

A violation raises :class:`LimitError` naming the quantity, the value and the limit; nothing is ever
clipped to the limit.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

__all__ = ["LimitCheck", "LimitError", "MotionLimits", "peak_acceleration_m_s2", "peak_velocity_mm_s"]


class LimitError(ValueError):
    """A command would exceed a configured limit. Attributes: quantity, value, limit, unit and ``field``,
    the name of the limit (a :class:`MotionLimits` field such as ``max_frequency_hz``; "" when unnamed)."""

    def __init__(self, quantity: str, value: float, limit: float, unit: str, context: str = "", *,
                 field: str = "") -> None:
        self.quantity = quantity
        self.value = value
        self.limit = limit
        self.unit = unit
        self.field = field
        where = f" ({context})" if context else ""
        super().__init__(f"{quantity} {value:.6g} {unit} exceeds the limit {limit:.6g} {unit}{where}; "
                         "nothing was sent")


@dataclass(frozen=True)
class LimitCheck:
    """One quantity of an operating point against its limit: ``field`` is the :class:`MotionLimits` field
    the limit comes from (``max_frequency_hz``, ...); ``formula`` says how ``value`` was computed."""

    quantity: str
    value: float
    limit: float
    unit: str
    field: str
    formula: str = ""

    @property
    def passed(self) -> bool:
        return self.value <= self.limit

    @property
    def margin(self) -> float:
        """limit − value, in ``unit`` (negative when exceeded)."""
        return self.limit - self.value

    def error(self, context: str = "") -> LimitError:
        where = "; ".join(p for p in (self.formula, context) if p)
        return LimitError(self.quantity, self.value, self.limit, self.unit, where, field=self.field)


def peak_acceleration_m_s2(frequency_hz: float, amplitude_mm: float) -> float:
    """Peak acceleration (2πf)²·x of a sine of peak displacement ``amplitude_mm``, in m/s²."""
    return (2.0 * math.pi * frequency_hz) ** 2 * amplitude_mm / 1000.0


def peak_velocity_mm_s(frequency_hz: float, amplitude_mm: float) -> float:
    """Peak velocity 2πf·x in mm/s."""
    return 2.0 * math.pi * frequency_hz * amplitude_mm


def _positive(name: str, value: float | None, *, optional: bool = False) -> None:
    if value is None and optional:
        return
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{name}={value!r}: must be a positive finite number")
    if not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name}={value!r}: must be a positive finite number")


@dataclass(frozen=True)
class MotionLimits:
    """Configured limits (all peak values, for the *mechanical* motion, not the drive's motor).

    max_frequency_hz: highest vibration (or rotation) frequency, Hz.
    max_displacement_mm: highest peak displacement (crank radius, shaker stroke/2, rotor radius), mm.
    max_acceleration_m_s2: highest peak acceleration (2πf)²·x, m/s².
    max_ramp_rate_hz_per_s: fastest frequency change, Hz/s.
    max_velocity_mm_s: optional highest peak velocity 2πf·x, mm/s.
    """

    max_frequency_hz: float
    max_displacement_mm: float
    max_acceleration_m_s2: float
    max_ramp_rate_hz_per_s: float
    max_velocity_mm_s: float | None = None

    def __post_init__(self) -> None:
        _positive("max_frequency_hz", self.max_frequency_hz)
        _positive("max_displacement_mm", self.max_displacement_mm)
        _positive("max_acceleration_m_s2", self.max_acceleration_m_s2)
        _positive("max_ramp_rate_hz_per_s", self.max_ramp_rate_hz_per_s)
        _positive("max_velocity_mm_s", self.max_velocity_mm_s, optional=True)

    @classmethod
    def from_dict(cls, table: dict[str, Any]) -> MotionLimits:
        """From a configuration table with exactly the field names; unknown keys raise."""
        allowed = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(table) - allowed)
        if unknown:
            raise ValueError(f"unknown limit keys {unknown}; allowed: {sorted(allowed)}")
        missing = sorted(f.name for f in dataclasses.fields(cls)
                         if f.default is dataclasses.MISSING and f.name not in table)
        if missing:
            raise ValueError(f"missing limit keys {missing}")
        return cls(**table)

    # single checks ---------------------------------------------------------------------------------
    def check_frequency(self, frequency_hz: float, context: str = "") -> None:
        if not math.isfinite(frequency_hz) or frequency_hz < 0:
            raise ValueError(f"frequency_hz={frequency_hz!r}: must be a finite number >= 0")
        if frequency_hz > self.max_frequency_hz:
            raise LimitError("frequency", frequency_hz, self.max_frequency_hz, "Hz", context,
                             field="max_frequency_hz")

    def check_displacement(self, amplitude_mm: float, context: str = "") -> None:
        if not math.isfinite(amplitude_mm) or amplitude_mm < 0:
            raise ValueError(f"amplitude_mm={amplitude_mm!r}: must be a finite number >= 0")
        if amplitude_mm > self.max_displacement_mm:
            raise LimitError("displacement", amplitude_mm, self.max_displacement_mm, "mm", context,
                             field="max_displacement_mm")

    def check_ramp_rate(self, rate_hz_per_s: float, context: str = "") -> None:
        check = self.evaluate_ramp_rate(rate_hz_per_s)
        if not check.passed:
            raise check.error(context)

    def evaluate(self, frequency_hz: float, amplitude_mm: float) -> tuple[LimitCheck, ...]:
        """Every limit of one operating point (frequency, displacement, (2πf)²·x, 2πf·x when limited), in
        that order; nothing raises for a value beyond its limit (see :meth:`check_point`)."""
        for name, value in (("frequency_hz", frequency_hz), ("amplitude_mm", amplitude_mm)):
            if not math.isfinite(value) or value < 0:
                raise ValueError(f"{name}={value!r}: must be a finite number >= 0")
        out = [LimitCheck("frequency", frequency_hz, self.max_frequency_hz, "Hz", "max_frequency_hz"),
               LimitCheck("displacement", amplitude_mm, self.max_displacement_mm, "mm",
                          "max_displacement_mm"),
               LimitCheck("acceleration", peak_acceleration_m_s2(frequency_hz, amplitude_mm),
                          self.max_acceleration_m_s2, "m/s²", "max_acceleration_m_s2",
                          f"(2π·{frequency_hz:.6g} Hz)²·{amplitude_mm:.6g} mm")]
        if self.max_velocity_mm_s is not None:
            out.append(LimitCheck("velocity", peak_velocity_mm_s(frequency_hz, amplitude_mm),
                                  self.max_velocity_mm_s, "mm/s", "max_velocity_mm_s",
                                  f"2π·{frequency_hz:.6g} Hz·{amplitude_mm:.6g} mm"))
        return tuple(out)

    def evaluate_ramp_rate(self, rate_hz_per_s: float) -> LimitCheck:
        """The ramp-rate limit for a frequency change of ``rate_hz_per_s`` (Hz/s, finite, > 0)."""
        if not math.isfinite(rate_hz_per_s) or rate_hz_per_s <= 0:
            raise ValueError(f"rate_hz_per_s={rate_hz_per_s!r}: must be a finite number > 0")
        return LimitCheck("ramp rate", rate_hz_per_s, self.max_ramp_rate_hz_per_s, "Hz/s",
                          "max_ramp_rate_hz_per_s")

    def check_point(self, frequency_hz: float, amplitude_mm: float, context: str = "") -> None:
        """Frequency, displacement, acceleration (2πf)²·x and velocity 2πf·x of one operating point."""
        for check in self.evaluate(frequency_hz, amplitude_mm):
            if not check.passed:
                raise check.error(context)

    def check_points(self, points: Iterable[tuple[float, float]], context: str = "") -> None:
        """Every (frequency_hz, amplitude_mm) pair."""
        for frequency_hz, amplitude_mm in points:
            self.check_point(frequency_hz, amplitude_mm, context)

    def max_frequency_for_amplitude_hz(self, amplitude_mm: float) -> float:
        """The highest frequency allowed at a given displacement (all limits together)."""
        f = self.max_frequency_hz
        if amplitude_mm > 0:
            f = min(f, math.sqrt(self.max_acceleration_m_s2 * 1000.0 / amplitude_mm) / (2 * math.pi))
            if self.max_velocity_mm_s is not None:
                f = min(f, self.max_velocity_mm_s / (2 * math.pi * amplitude_mm))
        return f
