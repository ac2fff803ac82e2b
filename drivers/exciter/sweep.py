"""Monotone frequency sweeps: the profiles, and carrying one out on a ramping drive.

A profile is frequency as a function of time since the sweep started, monotone (never turning back):

* :class:`LinearSweep` — ``f(t) = f0 + (f1 − f0)·t/T``;
* :class:`LogSweep` — ``f(t) = f0·(f1/f0)^(t/T)`` (constant time per octave);
* :class:`PointsSweep` — straight lines through ``(t_s, f_hz)`` points, like the time–frequency
  characteristic of the paper's Fig. 17.

:func:`run_sweep` carries a profile out on a device that has a ramp (a VFD, through
:class:`FrequencyActuator`): the profile is cut into straight segments no longer than
``update_interval_s``; at each segment start the setpoint becomes the segment's end frequency and, when
the segment's slope needs it, the drive's ramp rate is rewritten to just above that slope
(``1 + ramp_margin``), so the drive reaches each segment end a little early and never lags. Between
updates the actual frequency is polled every ``poll_interval_s``; those time-stamped samples are the
truth of the sweep. All waiting goes through the injected clock.
"""

from __future__ import annotations

import abc
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

from drivers.clock import Clock

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["FrequencyActuator", "FrequencySample", "LinearSweep", "LogSweep", "PointsSweep",
           "SweepProfile", "SweepResult", "run_sweep"]


def _finite(name: str, value: float, *, minimum: float | None = None, strict: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{name}={value!r}: must be a finite number")
    if minimum is not None and (value <= minimum if strict else value < minimum):
        raise ValueError(f"{name}={value!r}: must be {'>' if strict else '>='} {minimum:g}")
    return float(value)


class SweepProfile(abc.ABC):
    """Base class: subclasses define :meth:`frequency_hz`, ``start_hz``, ``stop_hz``, ``duration_s``
    and their exact breakpoints (:meth:`_knots`)."""

    start_hz: float
    stop_hz: float
    duration_s: float

    @abc.abstractmethod
    def frequency_hz(self, t_s: float) -> float:
        """Frequency (Hz) at ``t_s`` seconds from the start of the profile."""

    def _knots(self) -> list[float]:
        """Times (s) where the profile's slope may jump (always includes 0 and duration)."""
        return [0.0, self.duration_s]

    def _is_linear_between_knots(self) -> bool:
        return True

    @property
    def rising(self) -> bool:
        return self.stop_hz >= self.start_hz

    def segments(self, max_step_s: float) -> list[tuple[float, float, float, float]]:
        """Straight segments ``(t0_s, f0_hz, t1_s, f1_hz)`` no longer than ``max_step_s``, with exact
        profile values at both ends."""
        _finite("max_step_s", max_step_s, minimum=0.0, strict=True)
        knots = self._knots()
        out: list[tuple[float, float, float, float]] = []
        for ta, tb in itertools.pairwise(knots):
            n = max(1, math.ceil((tb - ta) / max_step_s - 1e-9))
            times = [ta + (tb - ta) * i / n for i in range(n + 1)]
            for t0, t1 in itertools.pairwise(times):
                out.append((t0, self.frequency_hz(t0), t1, self.frequency_hz(t1)))
        return out

    @abc.abstractmethod
    def max_slope_hz_per_s(self) -> float:
        """Largest |df/dt| of the profile (Hz/s)."""

    def points(self, max_step_s: float) -> list[tuple[float, float]]:
        """The segment ends as ``(t_s, f_hz)`` pairs (what a record's ``profile`` field holds)."""
        segs = self.segments(max_step_s)
        return [(segs[0][0], segs[0][1])] + [(s[2], s[3]) for s in segs]


@dataclass(frozen=True)
class LinearSweep(SweepProfile):
    """``f(t) = start_hz + (stop_hz − start_hz)·t/duration_s``; frequencies in Hz, duration in s."""

    start_hz: float
    stop_hz: float
    duration_s: float

    def __post_init__(self) -> None:
        _finite("start_hz", self.start_hz, minimum=0.0)
        _finite("stop_hz", self.stop_hz, minimum=0.0)
        _finite("duration_s", self.duration_s, minimum=0.0, strict=True)

    def frequency_hz(self, t_s: float) -> float:
        u = min(max(t_s / self.duration_s, 0.0), 1.0)
        return self.start_hz + (self.stop_hz - self.start_hz) * u

    def max_slope_hz_per_s(self) -> float:
        return abs(self.stop_hz - self.start_hz) / self.duration_s


@dataclass(frozen=True)
class LogSweep(SweepProfile):
    """``f(t) = start_hz·(stop_hz/start_hz)^(t/duration_s)``; both frequencies > 0 Hz."""

    start_hz: float
    stop_hz: float
    duration_s: float

    def __post_init__(self) -> None:
        _finite("start_hz", self.start_hz, minimum=0.0, strict=True)
        _finite("stop_hz", self.stop_hz, minimum=0.0, strict=True)
        _finite("duration_s", self.duration_s, minimum=0.0, strict=True)

    def frequency_hz(self, t_s: float) -> float:
        u = min(max(t_s / self.duration_s, 0.0), 1.0)
        return self.start_hz * math.pow(self.stop_hz / self.start_hz, u)

    def max_slope_hz_per_s(self) -> float:
        k = abs(math.log(self.stop_hz / self.start_hz)) / self.duration_s
        return k * max(self.start_hz, self.stop_hz)


@dataclass(frozen=True)
class PointsSweep(SweepProfile):
    """Straight lines through ``points = [(t_s, f_hz), ...]``: times strictly increasing from 0,
    frequencies >= 0 and monotone (all non-decreasing or all non-increasing)."""

    points_s_hz: tuple[tuple[float, float], ...]
    start_hz: float = field(init=False)
    stop_hz: float = field(init=False)
    duration_s: float = field(init=False)

    def __init__(self, points: Sequence[Sequence[float]]) -> None:
        pts: list[tuple[float, float]] = []
        for i, p in enumerate(points):
            if len(p) != 2:
                raise ValueError(f"points[{i}]={p!r}: must be a (t_s, f_hz) pair")
            pts.append((_finite(f"points[{i}].t_s", p[0]), _finite(f"points[{i}].f_hz", p[1], minimum=0.0)))
        if len(pts) < 2:
            raise ValueError(f"points: need at least 2 (t_s, f_hz) pairs, got {len(pts)}")
        if pts[0][0] != 0.0:
            raise ValueError(f"points[0].t_s={pts[0][0]!r}: the profile must start at t_s = 0")
        for i in range(1, len(pts)):
            if pts[i][0] <= pts[i - 1][0]:
                raise ValueError(f"points[{i}].t_s={pts[i][0]!r}: times must increase strictly "
                                 f"(previous {pts[i - 1][0]!r})")
        diffs = [b[1] - a[1] for a, b in itertools.pairwise(pts)]
        sign = next((math.copysign(1.0, d) for d in diffs if d != 0), 0.0)
        for k, d in enumerate(diffs):
            if d * sign < 0:
                raise ValueError(f"points[{k + 1}].f_hz={pts[k + 1][1]!r}: the profile must be monotone "
                                 f"(frequency may not turn back; previous {pts[k][1]!r})")
        object.__setattr__(self, "points_s_hz", tuple(pts))
        object.__setattr__(self, "start_hz", pts[0][1])
        object.__setattr__(self, "stop_hz", pts[-1][1])
        object.__setattr__(self, "duration_s", pts[-1][0])

    def frequency_hz(self, t_s: float) -> float:
        pts = self.points_s_hz
        if t_s <= 0.0:
            return pts[0][1]
        for (ta, fa), (tb, fb) in itertools.pairwise(pts):
            if t_s <= tb:
                return fa + (fb - fa) * (t_s - ta) / (tb - ta)
        return pts[-1][1]

    def _knots(self) -> list[float]:
        return [p[0] for p in self.points_s_hz]

    def max_slope_hz_per_s(self) -> float:
        pts = self.points_s_hz
        return max(abs(fb - fa) / (tb - ta) for (ta, fa), (tb, fb) in itertools.pairwise(pts))


@dataclass(frozen=True)
class FrequencySample:
    """One poll of the device: ``t_s`` on the rig clock (middle of the request), the actual frequency,
    the setpoint in force, and the drive's state word decoded (``"running"``, ...)."""

    t_s: float
    frequency_hz: float
    setpoint_hz: float
    status: str

    def as_event(self) -> dict[str, Any]:
        """The ``exciter`` / ``rotor`` event payload of contracts.md."""
        return {"frequency_hz": self.frequency_hz, "setpoint_hz": self.setpoint_hz, "status": self.status,
                "t_s": self.t_s}


@dataclass
class SweepResult:
    """What a sweep did: start/stop on the rig clock, the commanded profile in absolute time
    ``[(t_s, f_hz), ...]``, and the polled samples (the truth)."""

    t_start_s: float
    t_stop_s: float
    profile: list[tuple[float, float]]
    samples: list[FrequencySample]

    def to_dataframe(self) -> pd.DataFrame:
        """The polled samples, one row each (t_s, frequency_hz, setpoint_hz, status)."""
        import pandas as pd

        return pd.DataFrame([vars(s) for s in self.samples],
                            columns=["t_s", "frequency_hz", "setpoint_hz", "status"])


class FrequencyActuator(Protocol):
    """What :func:`run_sweep` needs from a device (the exciter and the rotor provide it).

    ``fixed_ramp_rate_hz_per_s`` returns ``None`` when the ramp rate can be written, else the drive's
    fixed rate (then only setpoints are written and the profile must not be steeper than it).
    """

    clock: Clock

    def fixed_ramp_rate_hz_per_s(self) -> float | None: ...        # None: the ramp rate can be written
    def write_ramp_rate_hz_per_s(self, rate_hz_per_s: float) -> None: ...
    def write_setpoint_hz(self, frequency_hz: float) -> None: ...
    def read_sample(self) -> FrequencySample: ...


def run_sweep(device: FrequencyActuator, profile: SweepProfile, *, update_interval_s: float = 0.5,
              poll_interval_s: float = 0.05, ramp_margin: float = 0.02, max_ramp_rate_hz_per_s: float,
              on_sample: Callable[[FrequencySample], None] | None = None) -> SweepResult:
    """Carry ``profile`` out from now on; the device must already run at ``profile.start_hz``.

    ``max_ramp_rate_hz_per_s`` caps the margin added to a slope (the caller has already checked that
    the profile's own slope is within the limit). Returns the commanded profile and the polled truth.
    """
    _finite("update_interval_s", update_interval_s, minimum=0.0, strict=True)
    _finite("poll_interval_s", poll_interval_s, minimum=0.0, strict=True)
    _finite("ramp_margin", ramp_margin, minimum=0.0)
    clock = device.clock
    segments = profile.segments(update_interval_s)
    fixed = device.fixed_ramp_rate_hz_per_s()
    if fixed is not None and profile.max_slope_hz_per_s() > fixed * (1 + 1e-9):
        raise ValueError(f"profile slope {profile.max_slope_hz_per_s():.6g} Hz/s exceeds the drive's fixed "
                         f"ramp rate {fixed:.6g} Hz/s (this drive's map has no ramp-time registers)")
    samples: list[FrequencySample] = []

    def poll() -> None:
        sample = device.read_sample()
        samples.append(sample)
        if on_sample is not None:
            on_sample(sample)

    t0 = clock.now_s()
    poll()
    rate: float | None = None
    for ta, fa, tb, fb in segments:
        slope = abs(fb - fa) / (tb - ta)
        retune = rate is None or slope > rate or slope < rate / (1 + 2 * ramp_margin)
        if fixed is None and slope > 0 and retune:
            rate = min(slope * (1 + ramp_margin), max(max_ramp_rate_hz_per_s, slope))
            device.write_ramp_rate_hz_per_s(rate)
        device.write_setpoint_hz(fb)
        t_end = t0 + tb
        while True:
            remaining = t_end - clock.now_s()
            if remaining <= 1e-9:
                break
            clock.sleep_s(min(poll_interval_s, remaining))
            poll()
    t_stop = clock.now_s()
    absolute = [(t0 + t, f) for t, f in profile.points(update_interval_s)]
    return SweepResult(t_start_s=t0, t_stop_s=t_stop, profile=absolute, samples=samples)
