"""Oscillator bodies of the simulated rig: exciter (crank), shaker (generator) and rotor.

Frequency f(t) ≥ 0 Hz follows piecewise constant, linear (ramp, linear sweep) and exponential (log sweep)
segments; the phase φ(t) = φ0 + ∫ 2π f dt is evaluated in closed form, so it is exact and continuous across
commands. Same command rule and thread safety as :mod:`drivers.sim.bodies` (commands at t ≥ the previous
command time replace only the planned future; readers use immutable snapshots).
"""

from __future__ import annotations

import math
import threading
from typing import Literal

import numpy as np

from drivers.sim.errors import SimCommandError, _finite

__all__ = ["OscillatorBody"]

_CONST, _LINEAR, _LOG = 0, 1, 2
_Seg = tuple[float, float, int, float, float]


class OscillatorBody:
    """Frequency f(t) ≥ 0 Hz, phase φ(t) rad (exact integral of 2π f) and amplitude A(t) mm of a driven body.

    Segments are (t0, φ0, kind, f0, c): constant f0; linear f0 + c·τ; log f0·exp(c·τ) (τ = t − t0).
    ``initial_hz`` and ``amplitude_mm`` hold from ``t_origin_s`` (earlier times extrapolate the constant).
    """

    def __init__(self, name: str = "oscillator", *, amplitude_mm: float = 0.0, initial_hz: float = 0.0,
                 t_origin_s: float = 0.0) -> None:
        self.name = name
        f = _finite(initial_hz, "initial_hz", nonneg=True)
        self._segs: tuple[_Seg, ...] = ((float(t_origin_s), 0.0, _CONST, f, 0.0),)
        self._amps: tuple[tuple[float, float], ...] = (
            (-math.inf, _finite(amplitude_mm, "amplitude_mm", nonneg=True)),)
        self._last_command_s = -math.inf
        self._lock = threading.Lock()
        self._table_cache: tuple[tuple[_Seg, ...] | None, np.ndarray] = (None, np.zeros((0, 5)))

    # -- evaluation
    def _eval(self, segs: tuple[_Seg, ...], t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cached = self._table_cache  # (segments, their array): rebuilt only when the segments change
        if cached[0] is segs:
            arr = cached[1]
        else:
            arr = np.array(segs)
            self._table_cache = (segs, arr)
        k = np.clip(np.searchsorted(arr[:, 0], t, side="right") - 1, 0, len(segs) - 1)
        t0, phi0, kind, f0, c = (arr[k, j] for j in range(5))
        tau = t - t0
        if not np.any(kind):  # all constant-frequency segments
            return f0, phi0 + 2.0 * np.pi * f0 * tau
        f = np.where(kind == _LINEAR, f0 + c * tau, f0)
        integral = np.where(kind == _LINEAR, f0 * tau + 0.5 * c * tau * tau, f0 * tau)
        log = kind == _LOG
        if np.any(log):
            cl = np.where(log, c, 1.0)
            growth = np.exp(np.where(log, cl * tau, 0.0))
            f = np.where(log, f0 * growth, f)
            integral = np.where(log, f0 * np.expm1(cl * tau) / cl, integral)
        return f, phi0 + 2.0 * np.pi * integral

    def frequency_hz(self, t_s: float | np.ndarray) -> float | np.ndarray:
        t = np.asarray(t_s, dtype=float)
        f = self._eval(self._segs, t)[0]
        return float(f) if t.ndim == 0 else f

    def phase_rad(self, t_s: float | np.ndarray) -> float | np.ndarray:
        t = np.asarray(t_s, dtype=float)
        p = self._eval(self._segs, t)[1]
        return float(p) if t.ndim == 0 else p

    def amplitude_at_mm(self, t_s: float | np.ndarray) -> float | np.ndarray:
        t = np.asarray(t_s, dtype=float)
        amps = self._amps
        starts = np.array([a[0] for a in amps])
        vals = np.array([a[1] for a in amps])
        out = vals[np.searchsorted(starts, t, side="right") - 1]
        return float(out) if t.ndim == 0 else out

    def displacement_mm(self, t_s: float | np.ndarray) -> float | np.ndarray:
        """A(t)·sin φ(t) in mm."""
        t = np.asarray(t_s, dtype=float)
        out = np.asarray(self.amplitude_at_mm(t)) * np.sin(self._eval(self._segs, t)[1])
        return float(out) if t.ndim == 0 else out

    def angle_deg(self, t_s: float | np.ndarray) -> float | np.ndarray:
        """φ(t) in degrees (unwrapped; for the rotor)."""
        t = np.asarray(t_s, dtype=float)
        out = np.degrees(self._eval(self._segs, t)[1])
        return float(out) if t.ndim == 0 else out

    def profile_breakpoints(self) -> list[tuple[float, float]]:
        """(t_s, f_hz) at the start of every segment, for reports and tests."""
        return [(s[0], s[3]) for s in self._segs]

    # -- commands
    def _begin(self, t_s: float) -> tuple[float, float, float]:
        t = _finite(t_s, "t_s")
        if t < self._last_command_s:
            raise SimCommandError(f"{self.name}: t_s={t!r} is before the previous command at "
                                  f"{self._last_command_s!r}; commands must not go back in time")
        f, phi = self._eval(self._segs, np.array(t))
        return t, float(f), float(phi)

    def _replace_future(self, t: float, new: list[_Seg]) -> None:
        kept = tuple(s for s in self._segs if s[0] < t) or self._segs[:1]
        self._segs = kept + tuple(new)
        self._last_command_s = t

    def _phase_after(self, seg: _Seg, t: float) -> float:
        return float(self._eval((seg,), np.array(t))[1])

    def set_frequency(self, t_s: float, hz: float) -> None:
        """Step the frequency to ``hz`` (≥ 0) at ``t_s`` (phase stays continuous)."""
        f_new = _finite(hz, "hz", nonneg=True)
        with self._lock:
            t, _, phi = self._begin(t_s)
            self._replace_future(t, [(t, phi, _CONST, f_new, 0.0)])

    def ramp_to(self, t_s: float, target_hz: float, rate_hz_per_s: float) -> float:
        """Ramp linearly from f(t_s) to ``target_hz`` at ``rate_hz_per_s`` (> 0), then hold.

        Returns the time of arrival at ``target_hz``."""
        target = _finite(target_hz, "target_hz", nonneg=True)
        rate = _finite(rate_hz_per_s, "rate_hz_per_s", positive=True)
        with self._lock:
            t, f, phi = self._begin(t_s)
            if target == f:
                self._replace_future(t, [(t, phi, _CONST, f, 0.0)])
                return t
            slope = rate if target > f else -rate
            duration = (target - f) / slope
            ramp = (t, phi, _LINEAR, f, slope)
            t_end = t + duration
            self._replace_future(t, [ramp, (t_end, self._phase_after(ramp, t_end), _CONST, target, 0.0)])
            return t_end

    def sweep(self, t_s: float, start_hz: float, stop_hz: float, duration_s: float,
              spacing: Literal["linear", "log"] = "linear") -> float:
        """Generator sweep: jump to ``start_hz`` at ``t_s``, sweep to ``stop_hz`` over ``duration_s``, then
        hold ``stop_hz`` (one sweep; a repeating generator is a new ``sweep`` call). Returns the end time."""
        f0 = _finite(start_hz, "start_hz", nonneg=True)
        f1 = _finite(stop_hz, "stop_hz", nonneg=True)
        dur = _finite(duration_s, "duration_s", positive=True)
        if spacing not in ("linear", "log"):
            raise SimCommandError(f"spacing must be 'linear' or 'log', got {spacing!r}")
        if spacing == "log" and (f0 <= 0.0 or f1 <= 0.0):
            raise SimCommandError(f"a log sweep needs start_hz > 0 and stop_hz > 0, got {f0!r}, {f1!r}")
        with self._lock:
            t, _, phi = self._begin(t_s)
            seg = ((t, phi, _LINEAR, f0, (f1 - f0) / dur) if spacing == "linear"
                   else (t, phi, _LOG, f0, math.log(f1 / f0) / dur))
            if f0 == f1:
                seg = (t, phi, _CONST, f0, 0.0)
            t_end = t + dur
            self._replace_future(t, [seg, (t_end, self._phase_after(seg, t_end), _CONST, f1, 0.0)])
            return t_end

    def set_amplitude(self, t_s: float, amplitude_mm: float) -> None:
        """Displacement amplitude (≥ 0 mm) from ``t_s`` on (piecewise constant)."""
        amp = _finite(amplitude_mm, "amplitude_mm", nonneg=True)
        with self._lock:
            t, _, _ = self._begin(t_s)
            self._amps = (*(a for a in self._amps if a[0] < t), (t, amp))
            self._last_command_s = t

    def halt(self, t_s: float, rate_hz_per_s: float | None = None) -> float:
        """Stop: ramp to 0 Hz at ``rate_hz_per_s``, or at once (frequency step to 0) if None."""
        if rate_hz_per_s is None:
            self.set_frequency(t_s, 0.0)
            return float(t_s)
        return self.ramp_to(t_s, 0.0, rate_hz_per_s)
