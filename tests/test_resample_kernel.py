"""The band-limited kernel's rows (compiled: rig/stereo/resample_kernel.py) against the straightforward
windowed sinc, and against the numpy/scipy rows and sparse matrix they replaced, to the bit."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scipy import sparse, special

from rig.stereo.errors import InputArrayError
from rig.stereo.resample import Bandlimited, _kernel_matrix, kaiser_sinc

HALF, BETA = 32, 5.65


def _reference(frac: np.ndarray) -> np.ndarray:
    """h(f − o) = sinc(f − o) · I0(β√(1 − r²)) / I0(β), r = (f − o)/half, zero for |r| ≥ 1 (numpy's i0)."""
    tau = frac[:, None] - np.arange(-HALF, HALF + 1)[None, :]
    r = tau / HALF
    inside = np.abs(r) < 1.0
    win = np.zeros_like(tau)
    win[inside] = np.i0(BETA * np.sqrt(1.0 - r[inside] ** 2)) / np.i0(BETA)
    return np.sinc(tau) * win


def _numpy_rows(frac: np.ndarray, half: int, beta: float) -> np.ndarray:
    """The rows as computed before they were compiled: numpy, one sine per row, scipy.special.i0."""
    offsets = np.arange(-half, half + 1)
    tau = frac[:, None] - offsets[None, :]
    r = tau / half
    inside = np.abs(r) < 1.0
    win = np.where(inside, special.i0(beta * np.sqrt(np.where(inside, 1.0 - r**2, 0.0))), 0.0)
    sine = np.sin(np.pi * np.minimum(frac, 1.0 - frac))[:, None] * np.where(offsets % 2 == 0, 1.0, -1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        sinc = np.where(tau == 0.0, 1.0, sine / (np.pi * tau))
    kernel: np.ndarray = sinc * (win / special.i0(beta))
    return kernel


def _numpy_matrix(tau_periods: np.ndarray, n_cols: int, half: int, beta: float) -> sparse.csr_matrix:
    """The sparse kernel matrix as built before (from :func:`_numpy_rows`)."""
    base = np.floor(tau_periods)
    j = base.astype(np.int64)[:, None] + np.arange(-half, half + 1)[None, :]
    vals = _numpy_rows(tau_periods - base, half, beta)
    ok = (j >= 0) & (j < n_cols) & (vals != 0.0)
    indptr = np.concatenate([[0], np.cumsum(np.count_nonzero(ok, axis=1))])
    return sparse.csr_matrix((vals[ok], j[ok], indptr), shape=(tau_periods.size, n_cols))


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


_EDGES = (0.0, 1e-300, 1e-14, 0.25, 0.5, 0.75, 1.0 - 1e-14, float(np.nextafter(1.0, 0.0)))


@settings(max_examples=60, deadline=None)
@given(hnp.arrays(float, st.integers(1, 300), elements=st.one_of(
           st.sampled_from(_EDGES), st.floats(0.0, 1.0, exclude_max=True))),
       st.integers(1, 40), st.floats(1e-3, 8.0))
def test_compiled_rows_equal_the_numpy_rows_to_the_bit(frac: np.ndarray, half: int, beta: float) -> None:
    # the same operations in the same order, cephes' i0 series as scipy evaluates it
    assert np.array_equal(kaiser_sinc(frac, half, beta), _numpy_rows(frac, half, beta))


@settings(max_examples=40, deadline=None)
@given(hnp.arrays(float, st.integers(1, 200), elements=st.floats(-50.0, 350.0)), st.integers(1, 300),
       st.integers(1, 40), st.floats(1e-3, 8.0))
def test_compiled_matrix_equals_the_numpy_matrix_to_the_bit(tau: np.ndarray, n_cols: int, half: int,
                                                            beta: float) -> None:
    got, want = _kernel_matrix(tau, n_cols, half, beta), _numpy_matrix(tau, n_cols, half, beta)
    assert got.shape == want.shape
    for name in ("indptr", "indices", "data"):
        assert np.array_equal(getattr(got, name), getattr(want, name)), name


@pytest.mark.parametrize("beta", [0.0, -1.0, 8.5, float("nan")])
def test_a_beta_outside_the_series_range_is_refused(beta: float) -> None:
    t = np.arange(40) / 60.0
    with pytest.raises(InputArrayError, match="beta"):
        kaiser_sinc(np.array([0.25]), HALF, beta)
    with pytest.raises(InputArrayError, match="beta"):
        Bandlimited(t, np.sin(t)[:, None], beta=beta)
