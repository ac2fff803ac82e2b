"""Ring background of marker windows: the compiled fit equals a plain per-window reference fit."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig.stereo.markers_kernel import MIN_SIGMA_DN, OUTLIER_SPREADS, ring_background, ring_offsets


class Ring:
    """The ring pixels of a window: flat indices (P,) and the design matrix (P, 3) of 1, x, y."""

    def __init__(self, half_px: int) -> None:
        rows, cols, xs, ys = ring_offsets(half_px)
        self.idx = rows * (2 * half_px + 1) + cols
        self.design = np.column_stack([np.ones(len(xs)), xs, ys])


def ring_geometry(half_px: int) -> Ring:
    return Ring(half_px)


def reference_fit(ring: np.ndarray, design: np.ndarray) -> tuple[np.ndarray, float]:
    """One window, written out plainly: 'lower' percentiles, outliers left out, lstsq on the rest."""
    p16, p50, p84 = np.percentile(ring, [16, 50, 84], method="lower")
    reach = OUTLIER_SPREADS * max(min(p50 - p16, p84 - p50), 1.0)
    keep = np.abs(ring - p50) <= reach
    coef, *_ = np.linalg.lstsq(design[keep], ring[keep], rcond=None)
    resid = ring[keep] - design[keep] @ coef
    sigma = max(np.sqrt(resid @ resid / max(keep.sum() - 3, 1)), MIN_SIGMA_DN)
    return coef, sigma


def windows(rng: np.random.Generator, n: int, half_px: int, noise_dn: float, n_outliers: int) -> np.ndarray:
    """Windows (n, W²) uint8: a random plane plus noise, a few ring pixels replaced by bright outliers."""
    w = 2 * half_px + 1
    y, x = np.mgrid[-half_px : half_px + 1, -half_px : half_px + 1].reshape(2, -1)
    a = rng.uniform(20, 200, (n, 1))
    b, c = rng.uniform(-1.5, 1.5, (2, n, 1))
    img = a + b * x + c * y + rng.normal(0, noise_dn, (n, w * w))
    idx = ring_geometry(half_px).idx
    for k in range(n):
        hit = rng.choice(idx, n_outliers, replace=False)
        img[k, hit] += rng.uniform(60, 150, n_outliers)  # e.g. a neighbouring marker on the ring
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("half_px", [3, 8, 16, 20])
@pytest.mark.parametrize("n_outliers", [0, 1, 30])
def test_batched_fit_equals_the_reference(half_px, n_outliers):
    rng = np.random.default_rng(half_px * 100 + n_outliers)
    flat = windows(rng, 40, half_px, noise_dn=2.0, n_outliers=min(n_outliers, 8 * half_px - 20))
    geo = ring_geometry(half_px)
    coef, sigma = ring_background(flat, None, half_px)
    for k in range(len(flat)):
        ref_coef, ref_sigma = reference_fit(flat[k, geo.idx].astype(float), geo.design)
        # float32 outputs: agreement to float32 rounding of DN-sized values
        np.testing.assert_allclose(coef[k], ref_coef, rtol=1e-5, atol=1e-4)
        assert sigma[k] == pytest.approx(ref_sigma, rel=1e-5, abs=1e-5)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(0.0, 6.0), st.integers(0, 12))
def test_any_ring_matches_the_reference(seed, noise_dn, n_outliers):
    rng = np.random.default_rng(seed)
    flat = windows(rng, 3, 16, noise_dn=noise_dn, n_outliers=n_outliers)
    geo = ring_geometry(16)
    coef, sigma = ring_background(flat, None, 16)
    for k in range(3):
        ref_coef, ref_sigma = reference_fit(flat[k, geo.idx].astype(float), geo.design)
        np.testing.assert_allclose(coef[k], ref_coef, rtol=1e-5, atol=1e-4)
        assert sigma[k] == pytest.approx(ref_sigma, rel=1e-5, abs=1e-5)


def test_invalid_pixels_are_ignored():
    rng = np.random.default_rng(7)
    flat = windows(rng, 5, 8, noise_dn=2.0, n_outliers=0)
    valid = np.ones(flat.shape, dtype=bool)
    valid[:, :17 * 4] = False  # the top four rows lie outside the image
    garbage = flat.copy()
    garbage[~valid] = 255
    geo = ring_geometry(8)
    coef, sigma = ring_background(garbage, valid, 8)
    for k in range(5):
        ok = valid[k, geo.idx]
        ref_coef, ref_sigma = reference_fit(flat[k, geo.idx][ok].astype(float), geo.design[ok])
        np.testing.assert_allclose(coef[k], ref_coef, rtol=1e-5, atol=1e-4)
        assert sigma[k] == pytest.approx(ref_sigma, rel=1e-5, abs=1e-5)
