"""Oscillator bodies of the simulated rig: exciter (crank), shaker (generator) and rotor.

Frequency f(t) ≥ 0 Hz follows piecewise constant, linear (ramp, linear sweep) and exponential (log sweep)
segments; a sweep segment may repeat with its period (a generator's free-running sweep), so a repeating
sweep is one segment however long it runs. The phase φ(t) = φ0 + ∫ 2π f dt is evaluated in closed form,
so it is exact and continuous across commands and across sweep restarts. Same command rule and thread
safety as :mod:`drivers.sim.bodies` (commands at t ≥ the previous command time replace only the planned
future; readers use immutable snapshots).

The history is bounded: at most ``max_segments`` frequency segments and amplitude steps are kept (the
oldest are dropped); asking about a time before the oldest kept one raises :class:`SimCommandError`
instead of answering from a history that is gone.
"""

from __future__ import annotations

import math
import threading
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from drivers.sim.errors import SimCommandError, _finite

__all__ = ["DEFAULT_MAX_SEGMENTS", "OscillatorBody"]

_CONST, _LINEAR, _LOG = 0, 1, 2
# (t0, φ0, kind, f0, c, period_s): period_s > 0 repeats the segment's first period_s seconds forever
_Seg = tuple[float, float, int, float, float, float]
DEFAULT_MAX_SEGMENTS = 4096


def _integral(kind: int, f0: float, c: float, tau: float) -> tuple[float, float]:
    """(f, ∫0^τ f) of one non-repeating segment at τ ≥ 0 s (scalar)."""
    if kind == _LINEAR:
        return f0 + c * tau, f0 * tau + 0.5 * c * tau * tau
    if kind == _LOG:
        return f0 * math.exp(c * tau), f0 * math.expm1(c * tau) / c
    return f0, f0 * tau


def _eval_one(seg: _Seg, t: float) -> tuple[float, float]:
    """(f(t) Hz, φ(t) rad) on one segment (scalar)."""
    t0, phi0, kind, f0, c, period = seg
    tau = t - t0
    cycles = 0.0
    if period > 0.0 and tau >= period:
        cycles = math.floor(tau / period)
        tau -= cycles * period
    f, integral = _integral(kind, f0, c, tau)
    full = _integral(kind, f0, c, period)[1] if cycles else 0.0
    return f, phi0 + 2.0 * math.pi * (cycles * full + integral)


class OscillatorBody:
    """Frequency f(t) ≥ 0 Hz, phase φ(t) rad (exact integral of 2π f) and amplitude A(t) mm of a driven body.

    Segments are (t0, φ0, kind, f0, c, period): constant f0; linear f0 + c·τ; log f0·exp(c·τ) (τ = t − t0,
    taken modulo ``period`` when it is > 0). ``initial_hz`` and ``amplitude_mm`` hold from ``t_origin_s``
    (earlier times extrapolate the constant while no history has been dropped). ``max_segments`` bounds
    the kept history (≥ 2).
    """

    def __init__(self, name: str = "oscillator", *, amplitude_mm: float = 0.0, initial_hz: float = 0.0,
                 t_origin_s: float = 0.0, max_segments: int = DEFAULT_MAX_SEGMENTS) -> None:
        if int(max_segments) < 2:
            raise SimCommandError(f"max_segments must be >= 2, got {max_segments!r}")
        self.name = name
        self.max_segments = int(max_segments)
        f = _finite(initial_hz, "initial_hz", nonneg=True)
        self._segs: tuple[_Seg, ...] = ((float(t_origin_s), 0.0, _CONST, f, 0.0, 0.0),)
        self._amps: tuple[tuple[float, float], ...] = (
            (-math.inf, _finite(amplitude_mm, "amplitude_mm", nonneg=True)),)
        self._history_start_s = -math.inf  # earliest time still answerable
        self._last_command_s = -math.inf
        self._lock = threading.Lock()
        self._table_cache: tuple[tuple[_Seg, ...] | None, NDArray[np.float64]] = (None, np.zeros((0, 6)))
        self._amp_cache: tuple[tuple[tuple[float, float], ...] | None, NDArray[np.float64],
                               NDArray[np.float64]] = (None, np.zeros(0), np.zeros(0))

    # -- evaluation
    def _table(self, segs: tuple[_Seg, ...]) -> NDArray[np.float64]:
        cached = self._table_cache  # (segments, their array): rebuilt only when the segments change
        if cached[0] is segs:
            return cached[1]
        arr = np.array(segs, dtype=float)
        self._table_cache = (segs, arr)
        return arr

    def _check_history(self, t: NDArray[np.float64]) -> None:
        if t.size and float(np.min(t)) < self._history_start_s:
            raise SimCommandError(f"{self.name}: t_s={float(np.min(t))!r} is before the kept history "
                                  f"(from {self._history_start_s!r} s; at most {self.max_segments} segments)")

    def _eval(self, segs: tuple[_Seg, ...],
              t: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        self._check_history(t)
        arr = self._table(segs)
        k = np.clip(np.searchsorted(arr[:, 0], t, side="right") - 1, 0, len(segs) - 1)
        t0, phi0, kind, f0, c, period = (arr[k, j] for j in range(6))
        tau = t - t0
        if not np.any(kind) and not np.any(period):  # constant-frequency segments only
            return f0, phi0 + 2.0 * np.pi * f0 * tau
        repeats = period > 0.0
        cycles = np.where(repeats, np.floor(tau / np.where(repeats, period, 1.0)), 0.0)
        cycles = np.maximum(cycles, 0.0)
        tau = tau - cycles * np.where(repeats, period, 0.0)
        f, integral = self._integrals(kind, f0, c, tau)
        if np.any(repeats):
            full = self._integrals(kind, f0, c, np.where(repeats, period, 0.0))[1]
            integral = integral + cycles * full
        return f, phi0 + 2.0 * np.pi * integral

    @staticmethod
    def _integrals(kind: NDArray[np.float64], f0: NDArray[np.float64], c: NDArray[np.float64],
                   tau: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        f = np.where(kind == _LINEAR, f0 + c * tau, f0)
        integral = np.where(kind == _LINEAR, f0 * tau + 0.5 * c * tau * tau, f0 * tau)
        log = kind == _LOG
        if np.any(log):
            cl = np.where(log, c, 1.0)
            growth = np.exp(np.where(log, cl * tau, 0.0))
            f = np.where(log, f0 * growth, f)
            integral = np.where(log, f0 * np.expm1(np.where(log, cl * tau, 0.0)) / cl, integral)
        return f, integral

    def frequency_hz(self, t_s: float | NDArray[np.float64]) -> float | NDArray[np.float64]:
        t = np.asarray(t_s, dtype=float)
        f = self._eval(self._segs, t)[0]
        return float(f) if t.ndim == 0 else f

    def frequency_and_phase(self, t_s: NDArray[np.float64]) -> tuple[NDArray[np.float64],
                                                                     NDArray[np.float64]]:
        """(f Hz, φ rad) at the times ``t_s`` (an array), from one evaluation."""
        return self._eval(self._segs, np.asarray(t_s, dtype=float))

    def phase_rad(self, t_s: float | NDArray[np.float64]) -> float | NDArray[np.float64]:
        t = np.asarray(t_s, dtype=float)
        p = self._eval(self._segs, t)[1]
        return float(p) if t.ndim == 0 else p

    def amplitude_at_mm(self, t_s: float | NDArray[np.float64]) -> float | NDArray[np.float64]:
        t = np.asarray(t_s, dtype=float)
        self._check_history(t)
        amps = self._amps
        cached = self._amp_cache  # (steps, their start times, their values): rebuilt when they change
        if cached[0] is not amps:
            cached = (amps, np.array([a[0] for a in amps]), np.array([a[1] for a in amps]))
            self._amp_cache = cached
        _, starts, vals = cached
        out = vals[np.maximum(np.searchsorted(starts, t, side="right") - 1, 0)]
        return float(out) if t.ndim == 0 else out

    def displacement_mm(self, t_s: float | NDArray[np.float64]) -> float | NDArray[np.float64]:
        """A(t)·sin φ(t) in mm."""
        t = np.asarray(t_s, dtype=float)
        out = np.asarray(self.amplitude_at_mm(t)) * np.sin(self._eval(self._segs, t)[1])
        return float(out) if t.ndim == 0 else out

    def angle_deg(self, t_s: float | NDArray[np.float64]) -> float | NDArray[np.float64]:
        """φ(t) in degrees (unwrapped; for the rotor)."""
        t = np.asarray(t_s, dtype=float)
        out = np.degrees(self._eval(self._segs, t)[1])
        return float(out) if t.ndim == 0 else out

    def profile_breakpoints(self) -> list[tuple[float, float]]:
        """(t_s, f_hz) at the start of every kept segment, for reports and tests (a repeating sweep is one
        segment: its restarts are not listed)."""
        return [(s[0], s[3]) for s in self._segs]

    @property
    def segment_count(self) -> int:
        """Frequency segments plus amplitude steps kept (bounded by 2 × ``max_segments``)."""
        return len(self._segs) + len(self._amps)

    # -- commands
    def _at(self, t: float) -> tuple[float, float]:
        """(f, φ) at a command time t ≥ the previous command (O(log n), no array rebuild)."""
        segs = self._segs
        i = len(segs) - 1
        while i > 0 and segs[i][0] > t:  # commands land at or near the end: a short walk back
            i -= 1
        return _eval_one(segs[i], t)

    def _begin(self, t_s: float) -> tuple[float, float, float]:
        t = _finite(t_s, "t_s")
        if t < self._last_command_s:
            raise SimCommandError(f"{self.name}: t_s={t!r} is before the previous command at "
                                  f"{self._last_command_s!r}; commands must not go back in time")
        f, phi = self._at(t)
        return t, f, phi

    def _replace_future(self, t: float, new: list[_Seg]) -> None:
        old = self._segs
        i = len(old)
        while i > 0 and old[i - 1][0] >= t:  # only the planned future (a few segments) is replaced
            i -= 1
        segs = (old[:i] or old[:1]) + tuple(new)
        if len(segs) > self.max_segments:
            segs = segs[len(segs) - self.max_segments:]
            self._history_start_s = max(self._history_start_s, segs[0][0])
        self._segs = segs
        self._last_command_s = t

    def set_frequency(self, t_s: float, hz: float, *, phase_rad: float | None = None) -> None:
        """Step the frequency to ``hz`` (≥ 0) at ``t_s``: the phase stays continuous, or restarts at
        ``phase_rad`` when given (a generator's ``PHASe:SYNChronize``)."""
        f_new = _finite(hz, "hz", nonneg=True)
        with self._lock:
            t, _, phi = self._begin(t_s)
            phi = phi if phase_rad is None else _finite(phase_rad, "phase_rad")
            self._replace_future(t, [(t, phi, _CONST, f_new, 0.0, 0.0)])

    def ramp_to(self, t_s: float, target_hz: float, rate_hz_per_s: float) -> float:
        """Ramp linearly from f(t_s) to ``target_hz`` at ``rate_hz_per_s`` (> 0), then hold.

        Returns the time of arrival at ``target_hz``."""
        target = _finite(target_hz, "target_hz", nonneg=True)
        rate = _finite(rate_hz_per_s, "rate_hz_per_s", positive=True)
        with self._lock:
            t, f, phi = self._begin(t_s)
            if target == f:
                self._replace_future(t, [(t, phi, _CONST, f, 0.0, 0.0)])
                return t
            slope = rate if target > f else -rate
            ramp: _Seg = (t, phi, _LINEAR, f, slope, 0.0)
            t_end = t + (target - f) / slope
            self._replace_future(t, [ramp, (t_end, _eval_one(ramp, t_end)[1], _CONST, target, 0.0, 0.0)])
            return t_end

    def sweep(self, t_s: float, start_hz: float, stop_hz: float, duration_s: float,
              spacing: Literal["linear", "log"] = "linear", *, repeat: bool = False,
              phase_rad: float | None = None) -> float:
        """Generator sweep: jump to ``start_hz`` at ``t_s`` and sweep to ``stop_hz`` over ``duration_s``;
        then hold ``stop_hz``, or with ``repeat`` start over from ``start_hz`` at every end (a free-running
        generator sweep; one segment however many restarts). The phase stays continuous, or restarts at
        ``phase_rad`` when given. Returns the end time of the first sweep."""
        f0 = _finite(start_hz, "start_hz", nonneg=True)
        f1 = _finite(stop_hz, "stop_hz", nonneg=True)
        dur = _finite(duration_s, "duration_s", positive=True)
        if spacing not in ("linear", "log"):
            raise SimCommandError(f"spacing must be 'linear' or 'log', got {spacing!r}")
        if spacing == "log" and (f0 <= 0.0 or f1 <= 0.0):
            raise SimCommandError(f"a log sweep needs start_hz > 0 and stop_hz > 0, got {f0!r}, {f1!r}")
        with self._lock:
            t, _, phi = self._begin(t_s)
            phi = phi if phase_rad is None else _finite(phase_rad, "phase_rad")
            if f0 == f1:
                seg: _Seg = (t, phi, _CONST, f0, 0.0, 0.0)
            elif spacing == "linear":
                seg = (t, phi, _LINEAR, f0, (f1 - f0) / dur, dur if repeat else 0.0)
            else:
                seg = (t, phi, _LOG, f0, math.log(f1 / f0) / dur, dur if repeat else 0.0)
            t_end = t + dur
            if repeat or f0 == f1:
                self._replace_future(t, [seg])
            else:
                self._replace_future(t, [seg, (t_end, _eval_one(seg, t_end)[1], _CONST, f1, 0.0, 0.0)])
            return t_end

    def set_amplitude(self, t_s: float, amplitude_mm: float) -> None:
        """Displacement amplitude (≥ 0 mm) from ``t_s`` on (piecewise constant)."""
        amp = _finite(amplitude_mm, "amplitude_mm", nonneg=True)
        with self._lock:
            t, _, _ = self._begin(t_s)
            amps = (*(a for a in self._amps if a[0] < t), (t, amp))
            if len(amps) > self.max_segments:
                amps = amps[len(amps) - self.max_segments:]
                self._history_start_s = max(self._history_start_s, amps[0][0])
            self._amps = amps
            self._last_command_s = t

    def halt(self, t_s: float, rate_hz_per_s: float | None = None) -> float:
        """Stop: ramp to 0 Hz at ``rate_hz_per_s``, or at once (frequency step to 0) if None."""
        if rate_hz_per_s is None:
            self.set_frequency(t_s, 0.0)
            return float(t_s)
        return self.ramp_to(t_s, 0.0, rate_hz_per_s)
