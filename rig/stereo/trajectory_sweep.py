"""Sliding local-sinusoid 3D trajectories: instantaneous frequency, amplitude and direction of a sweep.

In each window of ``window_s`` (advanced by ``step_s``) a 3D sinusoid with a linear chirp,
X(t) = c + a·cos φ + b·sin φ, φ = 2π(f·τ + ½·rate·τ²), τ = t − window centre, is fitted to all observations
of all cameras at their row-corrected instants (:class:`rig.stereo.trajectory.SineBasis`, reprojection
error). The first window's frequency comes from the full scan of
:func:`rig.stereo.trajectory.fit_sine_trajectory` (up to the pair's combined Nyquist limit); later windows
search near the previous frequency (± the expected change plus two resolution cells), so a sweep is tracked
through one camera's Nyquist limit fs/2 as long as the cameras' instants interleave (see the trajectory
module on where that fails). Frequency and rate are then refined by Gauss–Newton on the reprojection
residuals. The paper's Figs. 15 and 17 (frequency and amplitude over time) in 3D, without interpolation.

Units: s, Hz, Hz/s, pixels; amplitude in the projection matrices' length unit (mm).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import optimize

from rig.stereo._arrays import FloatArray, IntArray
from rig.stereo.errors import InputArrayError, TooFewSamplesError
from rig.stereo.normalize import Camera
from rig.stereo.trajectory import SineBasis, Trajectory, _check, fit_sine_trajectory, fit_trajectory

MIN_PER_CAMERA = 6


@dataclass(frozen=True)
class SweepTrack:
    """Per window (arrays of length W): centre ``time_s``, ``frequency_hz`` and ``rate_hz_s`` at the centre,
    ``amplitude`` (major semi-axis of the fundamental's motion ellipse), unit ``direction`` (W, 3),
    ``residual_rms_px`` and ``n_observations``."""

    time_s: FloatArray
    frequency_hz: FloatArray
    rate_hz_s: FloatArray
    amplitude: FloatArray
    direction: FloatArray
    residual_rms_px: FloatArray
    n_observations: IntArray


def _fit_chirp(
    Ps: Sequence[FloatArray], ts: Sequence[FloatArray], uvs: Sequence[FloatArray], *, t_mid: float, f0: float,
    rate0: float, n_harmonics: int,
) -> tuple[Trajectory, float, float]:
    """Frequency (Hz) and rate (Hz/s) at ``t_mid`` of a chirped sinusoid, by least squares on the
    reprojection residuals from (f0, rate0); with its trajectory."""

    def residuals(p: FloatArray) -> FloatArray:
        basis = SineBasis(float(p[0]), t_mid, n_harmonics, False, float(p[1]))
        tr = fit_trajectory(Ps, ts, uvs, basis, iterations=3)
        return np.concatenate([r.ravel() for r in tr.residuals_px])

    res = optimize.least_squares(residuals, [f0, rate0], method="lm", x_scale=[0.01, 0.1])
    f, rate = float(res.x[0]), float(res.x[1])
    traj = fit_trajectory(Ps, ts, uvs, SineBasis(f, t_mid, n_harmonics, False, rate), iterations=8)
    return traj, f, rate


def sliding_sine_trajectory(
    cameras: Sequence[Camera],
    t_s: Sequence[object],
    uv_px: Sequence[object],
    *,
    window_s: float,
    step_s: float,
    frequency_range_hz: tuple[float, float] | None = None,
    n_harmonics: int = 1,
) -> SweepTrack:
    """Sliding chirped-sinusoid trajectory fits over all cameras' observations (see module doc).

    ``window_s`` should hold a few periods of the lowest frequency and little enough sweep that a linear
    chirp describes it; ``frequency_range_hz`` bounds the first window's scan. Windows where a camera has
    fewer than 6 observations are skipped; if none is left, TooFewSamplesError.
    """
    Ps, ts, uvs = _check(cameras, t_s, uv_px)
    if not (window_s > 0 and step_s > 0):
        raise InputArrayError(f"window_s and step_s must be positive, got {window_s!r}, {step_s!r}")
    t_lo = max(t[0] for t in ts)
    t_hi = min(t[-1] for t in ts)
    if t_hi - t_lo < window_s:
        raise TooFewSamplesError(
            f"the cameras overlap for {t_hi - t_lo:.3g} s, less than window_s = {window_s} s"
        )
    rows = []
    previous: tuple[float, float] | None = None  # frequency (Hz) and rate (Hz/s) of the last window
    for s0 in np.arange(t_lo, t_hi - window_s + 1e-9, step_s):
        sel = [(t >= s0) & (t < s0 + window_s) for t in ts]
        if min(int(m.sum()) for m in sel) < MIN_PER_CAMERA:
            continue
        tw = [t[m] for t, m in zip(ts, sel, strict=True)]
        uw = [u[m] for u, m in zip(uvs, sel, strict=True)]
        t_mid = s0 + 0.5 * window_s
        if previous is None:
            _, f0 = fit_sine_trajectory(
                Ps, tw, uw, frequency_range_hz=frequency_range_hz, n_harmonics=n_harmonics
            )
            rate0 = 0.0
        else:
            f_prev, rate_prev = previous
            f_pred = f_prev + rate_prev * step_s
            half = abs(rate_prev) * step_s + 2.0 / window_s
            _, f0 = fit_sine_trajectory(
                Ps,
                tw,
                uw,
                frequency_range_hz=(max(f_pred - half, 0.5 / window_s), f_pred + half),
                n_harmonics=n_harmonics,
            )
            rate0 = rate_prev
        traj, f, rate = _fit_chirp(Ps, tw, uw, t_mid=t_mid, f0=f0, rate0=rate0, n_harmonics=n_harmonics)
        previous = (f, rate)
        rows.append((t_mid, f, rate, traj.amplitude, traj.direction, traj.rms_px, sum(len(t) for t in tw)))
    if not rows:
        raise TooFewSamplesError(
            f"no window of {window_s} s holds {MIN_PER_CAMERA} observations of every camera"
        )
    cols = list(zip(*rows, strict=True))
    return SweepTrack(
        np.array(cols[0]),
        np.array(cols[1]),
        np.array(cols[2]),
        np.array(cols[3]),
        np.vstack(cols[4]),
        np.array(cols[5]),
        np.array(cols[6], dtype=np.int64),
    )
