"""Validation of time series shared by timing, resample, trajectory and spectrum (private helpers)."""

from __future__ import annotations

import numpy as np

from rig.stereo._arrays import FloatArray, IntArray
from rig.stereo.errors import (
    InputArrayError,
    NonMonotonicTimestampsError,
    NonUniformSamplingError,
    TooFewSamplesError,
)


def as_times(t_s: object, name: str = "t_s", *, min_count: int = 2) -> FloatArray:
    """Return ``t_s`` as a finite, strictly increasing 1-D float array of at least ``min_count`` values."""
    t = np.asarray(t_s, dtype=float)
    if t.ndim != 1:
        raise InputArrayError(f"{name} must be 1-D, got shape {t.shape}")
    if t.size < min_count:
        raise TooFewSamplesError(f"{name} has {t.size} samples; at least {min_count} are needed")
    if not np.all(np.isfinite(t)):
        raise InputArrayError(f"{name} holds NaN or inf at index {int(np.flatnonzero(~np.isfinite(t))[0])}")
    steps = np.diff(t)
    if np.any(steps <= 0):
        k = int(np.flatnonzero(steps <= 0)[0])
        raise NonMonotonicTimestampsError(
            f"{name} must increase strictly: {name}[{k + 1}] = {t[k + 1]!r} s follows "
            f"{name}[{k}] = {t[k]!r} s"
        )
    return t


def as_values(x: object, n: int, name: str = "x") -> FloatArray:
    """Return ``x`` as a finite float array whose first axis has length ``n``."""
    a = np.asarray(x, dtype=float)
    if a.ndim == 0 or a.shape[0] != n:
        raise InputArrayError(f"{name} must have {n} rows (one per time stamp), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputArrayError(f"{name} holds NaN or inf; drop lost observations before calling")
    return a


def uniform_grid(
    t: FloatArray, name: str = "t_s", *, tolerance: float = 0.02
) -> tuple[float, float, IntArray]:
    """Fit t_k ≈ t0 + n_k·T with integer n_k (gaps allowed); return (t0_s, period_s, n_k).

    Raises NonUniformSamplingError when a time stamp deviates from the grid by more than
    ``tolerance`` × T (e.g. row-corrected times of a rolling shutter: use a method for irregular times).
    """
    steps = np.diff(t)
    period = float(np.median(steps))
    n = np.rint((t - t[0]) / period).astype(np.int64)
    if np.any(np.diff(n) < 1):
        raise NonUniformSamplingError(f"{name}: two time stamps fall in the same sampling interval")
    A = np.column_stack([np.ones_like(t), n.astype(float)])
    (t0, period), *_ = np.linalg.lstsq(A, t, rcond=None)
    dev = np.abs(t - (t0 + n * period))
    if dev.max() > tolerance * period:
        k = int(np.argmax(dev))
        raise NonUniformSamplingError(
            f"{name}[{k}] deviates {dev[k] * 1e3:.3f} ms from a uniform grid of period {period * 1e3:.4f} ms "
            f"(allowed {tolerance:.0%} of a period)"
        )
    return float(t0), float(period), n
