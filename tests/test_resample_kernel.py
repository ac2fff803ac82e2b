"""The band-limited kernel's rows (one sine per row, scipy's i0) against the straightforward windowed sinc."""

from __future__ import annotations

import numpy as np

from rig.stereo.resample import kaiser_sinc

HALF, BETA = 32, 5.65


def _reference(frac: np.ndarray) -> np.ndarray:
    """h(f − o) = sinc(f − o) · I0(β√(1 − r²)) / I0(β), r = (f − o)/half, zero for |r| ≥ 1 (numpy's i0)."""
    tau = frac[:, None] - np.arange(-HALF, HALF + 1)[None, :]
    r = tau / HALF
    inside = np.abs(r) < 1.0
    win = np.zeros_like(tau)
    win[inside] = np.i0(BETA * np.sqrt(1.0 - r[inside] ** 2)) / np.i0(BETA)
    return np.sinc(tau) * win


def test_kernel_rows_equal_the_windowed_sinc_within_float_rounding() -> None:
    rng = np.random.default_rng(7)
    edges = [0.0, 1e-300, 1e-14, 0.5, 1.0 - 1e-14, np.nextafter(1.0, 0.0)]  # next to either sample
    frac = np.concatenate([edges, rng.random(2000)])
    got, want = kaiser_sinc(frac, HALF, BETA), _reference(frac)
    assert got.shape == want.shape == (frac.size, 2 * HALF + 1)
    # Both i0 are cephes' Chebyshev series (a few ulp apart; |h| ≤ 1). numpy's sinc rounds π(f − o): up to
    # |π(f − o)|·2⁻⁵³ in the sine's argument, ≤ 2⁻⁵³ ≈ 1.1e-16 in h once divided by π|f − o|; ours rounds
    # π·min(f, 1 − f) alone. A few ulp of 1 in all (3.3e-16 measured over 2·10⁵ rows): 2e-15 bounds every
    # term. Zero beyond ±half; at f = 0 exactly the unit sample (numpy's sinc leaves ~1e-18 at the integers).
    assert np.max(np.abs(got - want)) <= 2e-15
    tau = frac[:, None] - np.arange(-HALF, HALF + 1)[None, :]
    assert np.all(got[np.abs(tau) >= HALF] == 0.0)
    assert np.array_equal(got[0], np.eye(2 * HALF + 1)[HALF])
