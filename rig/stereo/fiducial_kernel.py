"""The timing fiducial's levels and coarse offset search (:mod:`rig.stereo.fiducial`), compiled (numba): the
LED's mean level over each row's exposure, and each grid offset's residual sum of squares of the affine fit
brightness ≈ b_off + gain·level, over every row, in one pass per offset.

The rows are taken in order of their start, so each row's first and last edge come from a walk along the
edges (the edges before a row's are before the next row's) instead of two binary searches; a row's level
has the operations, in the order, of the numpy form it replaced (tests/test_stereo_fiducial.py keeps it as
the reference: the same numbers, to the bit). The sums are plain sums in row order (numpy's pairwise sums
round differently: the residuals agree within 1e-9 relative, inside the 1e-6 margin within which
:func:`rig.stereo.fiducial._grid_offset_s` fits the best offsets again by an exact lstsq). A certification
run's fiducial rows (up to 51 offsets × 333,000 rows a search): 2.1 → 0.33 CPU-s a report.

Imported by :mod:`rig.stereo.fiducial` when levels are first needed (numba is loaded then); compiled once
into numba's on-disk cache (:mod:`rig.warm_kernels`).
"""

from __future__ import annotations

import numpy as np

from rig.stereo.markers_kernel import jit_kernel


@jit_kernel
def ramp_integral(x: float, rise_s: float) -> float:
    """∫_{-∞}^{x} clip(u/rise, 0, 1) du (s): the light of one rising edge at 0 accumulated up to ``x`` (s)."""
    if rise_s <= 0:
        return max(x, 0.0)
    if x <= 0:
        return 0.0
    if x < rise_s:
        return 0.5 * x * x / rise_s
    return x - 0.5 * rise_s


@jit_kernel
def levels(  # noqa: PLR0917 (numba: no keyword-only arguments)
        start_s: np.ndarray, offset_s: float, exposure_s: float, edges_s: np.ndarray, signs: np.ndarray,
        state: np.ndarray, rise_s: float, out: np.ndarray) -> None:
    """``out`` ← the mean level of the exposure windows [s, s + ``exposure_s``], s = ``offset_s`` + each of
    ``start_s`` (ascending, finite; s); ``state[k]``: the level after the first k edges (``edges_s``,
    ascending, with their ``signs`` ±1), each a linear ramp of ``rise_s`` (s)."""
    n_edges = edges_s.shape[0]
    lo = 0  # edges before lo are complete (searchsorted(e, s − rise))
    hi = 0  # edges from hi on have not begun (searchsorted(e, s + exposure))
    for r in range(start_s.shape[0]):
        s = offset_s + start_s[r]
        begun = s - rise_s
        while lo < n_edges and edges_s[lo] < begun:
            lo += 1
        ends = s + exposure_s
        while hi < n_edges and edges_s[hi] < ends:
            hi += 1
        level = state[lo]
        for k in range(lo, hi):
            part = (ramp_integral(s + exposure_s - edges_s[k], rise_s)
                    - ramp_integral(s - edges_s[k], rise_s)) / exposure_s
            level += signs[k] * part
        out[r] = level


@jit_kernel
def grid_sse(  # noqa: PLR0917 (numba: no keyword-only arguments)
        start_s: np.ndarray, brightness_dn: np.ndarray, exposure_s: float, edges_s: np.ndarray,
        signs: np.ndarray, state: np.ndarray, rise_s: float, offsets_s: np.ndarray) -> np.ndarray:
    """Per offset of ``offsets_s`` (s): the residual sum of squares (DN²) of brightness ≈ b_off + gain·level
    over the rows (``start_s`` ascending, s; their ``brightness_dn``): with level and brightness centred on
    their means (lc, bc), gain = Σ lc·bc / Σ lc² and the sum Σ (bc − gain·lc)²; inf where every row's level
    is the same (no row lit part-way)."""
    n = start_s.shape[0]
    centred_b = brightness_dn - brightness_dn.sum() / n
    level = np.empty(n)
    out = np.empty(offsets_s.shape[0])
    for i in range(offsets_s.shape[0]):
        levels(start_s, offsets_s[i], exposure_s, edges_s, signs, state, rise_s, level)
        low, high, total = np.inf, -np.inf, 0.0
        for r in range(n):
            low, high, total = min(low, level[r]), max(high, level[r]), total + level[r]
        if not high > low:
            out[i] = np.inf
            continue
        mean = total / n
        cross, square = 0.0, 0.0
        for r in range(n):
            centred = level[r] - mean
            cross += centred * centred_b[r]
            square += centred * centred
        gain = cross / square
        sse = 0.0
        for r in range(n):
            residual = centred_b[r] - gain * (level[r] - mean)
            sse += residual * residual
        out[i] = sse
    return out
