"""The band-limited reconstruction's compiled parts (rig/stereo/resample_kernel.py): the kernel rows against
the straightforward windowed sinc, and rows, solved grid, values and noise gains against the numpy and
scipy.sparse code they replaced (kept here as the reference), to the bit."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scipy import linalg, sparse, special
from scipy.interpolate import CubicSpline

from rig.stereo.errors import InputArrayError
from rig.stereo.resample import (
    Bandlimited,
    _filter_penalty,
    _grid,
    _lower_bands,
    _missing_slots,
    bridging_filter,
)
from rig.stereo.resample_kernel import kaiser_sinc_rows

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
    got, want = kaiser_sinc_rows(frac, HALF, BETA), _reference(frac)
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
    assert np.array_equal(kaiser_sinc_rows(frac, half, beta), _numpy_rows(frac, half, beta))


class _SparseReference:
    """The reconstruction as solved and evaluated before its sums were compiled: scipy.sparse S, S.T @ S + R,
    scipy.linalg.solveh_banded, K @ grid values, the noise gain through K.T.toarray()."""

    def __init__(self, fit: Bandlimited, t_src: np.ndarray, values: np.ndarray, **bridge: object) -> None:
        self.fit = fit
        if fit.R is None:  # a regular grid: nothing solved
            self.grid_values, self.bands = values - _trend(t_src, fit.trend), None
            return
        _, _, m = _grid(t_src)
        S = _numpy_matrix((t_src - fit.t0) / fit.period, fit.n_grid, fit.half, fit.beta)
        rhs = np.asarray(S.T @ (values - _trend(t_src, fit.trend)))
        weights = np.full(fit.n_grid, 1e-8)
        short, long_ = _missing_slots(m, int(bridge.get("bridge_max_samples", 0)))
        if long_.size:
            weights[long_] = 1.0
            prior = CubicSpline(t_src, values - _trend(t_src, fit.trend), axis=0)(fit.t0 + long_ * fit.period)
            rhs[long_] += prior.reshape(rhs[long_].shape)
        R = sparse.diags(weights).tocsr()
        if short.size:
            taps = np.asarray(bridge["bridge_filter"], dtype=float)
            R = (R + _filter_penalty(taps, short, long_, fit.n_grid)).tocsr()
        self.R = R
        self.bands = _lower_bands((S.T @ S + R).tocsr(), 2 * fit.half + 1)
        self.grid_values = linalg.solveh_banded(self.bands, rhs, lower=True)

    def values_and_gain(self, t_dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        fit = self.fit
        K = _numpy_matrix((t_dst - fit.t0) / fit.period, fit.n_grid, fit.half, fit.beta)
        B = np.column_stack([np.ones_like(t_dst), t_dst - fit.t_first])
        values = np.asarray(K @ self.grid_values) + B @ fit.trend
        if self.bands is None:
            return values, np.asarray(K.multiply(K).sum(axis=1)).ravel()
        Z = linalg.solveh_banded(self.bands, K.T.toarray(), lower=True)
        through_data = np.asarray(K.multiply(Z.T).sum(axis=1)).ravel()
        return values, through_data - np.sum(Z * np.asarray(self.R @ Z), axis=0)


def _trend(t_src: np.ndarray, trend: np.ndarray) -> np.ndarray:
    trend_values: np.ndarray = np.column_stack([np.ones_like(t_src), t_src - t_src[0]]) @ trend
    return trend_values


@settings(max_examples=40, deadline=None)
@given(st.tuples(st.integers(60, 400), st.integers(0, 2**32 - 1), st.sampled_from([0.0, 0.05, 0.3]),
                 st.sampled_from([0.0, 0.1]), st.booleans(), st.booleans()))
@example((333, 333, 0.0, 0.0, False, False))  # regular grid: the last row summed with a pad 0.0, 1 ulp off
def test_compiled_reconstruction_equals_the_sparse_one_to_the_bit(
        case: tuple[int, int, float, float, bool, bool]) -> None:
    n, seed, jitter, lost, long_gap, bridged = case
    # a two-column track at ~60 frames/s: row-time-like smooth jitter, frames lost at random (bridged or
    # not) and a long gap (the cubic prior); values, noise gains and the solved grid to the bit
    rng = np.random.default_rng(seed)
    m = np.arange(n)
    keep = rng.random(n) >= lost
    if long_gap:
        keep[n // 3: n // 3 + 8] = False
    keep[[0, -1]] = True
    m = m[keep]
    t_src = (m + jitter * np.sin(0.07 * m + seed % 7)) / 60.0 + 2.0
    values = np.column_stack([np.sin(2 * np.pi * 7 * t_src), np.cos(2 * np.pi * 3 * t_src)]) * 50
    values += rng.normal(0.0, 0.1, values.shape)
    bridge: dict[str, object] = {}
    if bridged and lost:
        taps, _ = bridging_filter(t_src, values, max_gap_samples=3)
        bridge = {"bridge_max_samples": 3, "bridge_filter": taps}
    fit = Bandlimited(t_src, values, **bridge)  # type: ignore[arg-type]
    reference = _SparseReference(fit, t_src, values, **bridge)
    t_dst = np.sort(rng.uniform(t_src[0], t_src[-1], 150))
    K = fit.kernel(t_dst)
    want_values, want_gain = reference.values_and_gain(t_dst)
    assert np.array_equal(fit.grid_values, reference.grid_values)
    assert np.array_equal(fit.values_at(K, t_dst), want_values)
    assert np.array_equal(fit.noise_gain(K), want_gain)


@pytest.mark.parametrize("beta", [0.0, -1.0, 8.5, float("nan")])
def test_a_beta_outside_the_series_range_is_refused(beta: float) -> None:
    t = np.arange(40) / 60.0
    with pytest.raises(InputArrayError, match="beta"):
        Bandlimited(t, np.sin(t)[:, None], beta=beta)
