"""Background plane and noise of marker windows, fitted to each window's outer ring of pixels.

The ring is the outer ``RING_PX`` pixels of a square window of ``W = 2·half_px + 1`` pixels; coordinates
are offsets in px from the window's centre pixel. For every window the ring gives a plane
``a + b·x + c·y`` (DN, polarity space) and the noise ``σ`` (DN), the RMS residual of the fit.

Robust to whatever else crosses the ring (a neighbouring marker, the edge of a plate) on up to about a
third of it: the spread is taken from the quieter side of the median (min of p50 − p16 and p84 − p50,
≈ σ for Gaussian noise), ring pixels farther than 4 such spreads from the median are left out, and the
plane is fitted to the rest by least squares. A plane, not a constant, so that a background gradient
(vignetting, uneven lighting) does not pull the centroid uphill.

Speed: the usual ring holds no outlier (its extremes lie within the 4 spreads), so the percentiles come
from one radix sort of the uint8 ring values (min, p16, p50, p84 and max in one go) and the plain fit
and its residual from the ring's moments (closed form, no residual pass). Only windows with outliers
take the weighted fit, batched.
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass

import numpy as np

MIN_SIGMA_DN = 0.5  # floor of σ: a flat 8-bit background has zero spread but ±0.5 DN quantization
RING_PX = 2  # width of the background ring at the window's edge
OUTLIER_SPREADS = 4.0  # ring pixels farther than this many spreads from the median are left out
# OpenBLAS runs a product on all its threads when rows·columns·inner ≥ 65536·4: on a busy machine its
# spinning threads cost far more than these small products, and their work escapes the caller's thread
BLAS_SINGLE_THREAD_OPS = 200_000


def matmul_one_thread(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` for 2-D ``a`` (K, P), ``b`` (P, N), as stacked products small enough to stay on one thread.

    numpy's stacked matmul calls BLAS once per (rows, P) block, each below OpenBLAS's threading threshold.
    """
    rows = max(1, BLAS_SINGLE_THREAD_OPS // (b.shape[0] * b.shape[1]))
    k = a.shape[0]
    if k <= rows:
        product: np.ndarray = a @ b
        return product
    out = np.empty((k, b.shape[1]), dtype=np.result_type(a, b))
    main = k - k % rows
    np.matmul(a[:main].reshape(-1, rows, a.shape[1]), b, out=out[:main].reshape(-1, rows, b.shape[1]))
    if main < k:
        np.matmul(a[main:], b, out=out[main:])
    return out


@dataclass(frozen=True)
class Ring:
    """Constant arrays of the ring of one window size (cached)."""

    idx: np.ndarray  # flat indices of the ring pixels in the W² window
    design: np.ndarray  # (P, 3): 1, x, y on the ring
    normal_inv: np.ndarray  # (3,): inverse of designᵀ·design, diagonal for the symmetric ring
    outer: np.ndarray  # (P, 9): outer products of the design rows, for batched weighted normal equations
    kth: np.ndarray  # ranks in the sorted ring of min, p16, p50, p84, max ("lower" percentiles)
    dtype: type  # float32 when sums of squared uint8 ring values are exact in it, else float64
    design_t: np.ndarray  # (3, P) design transposed, contiguous, in ``dtype``


@functools.lru_cache(maxsize=32)
def ring_geometry(half_px: int) -> Ring:
    """The :class:`Ring` of windows of half size ``half_px`` (px, ≥ RING_PX + 1)."""
    w = 2 * half_px + 1
    y, x = np.mgrid[-half_px : half_px + 1, -half_px : half_px + 1].astype(np.float64)
    ring = np.ones((w, w), dtype=bool)
    ring[RING_PX:-RING_PX, RING_PX:-RING_PX] = False
    idx = np.flatnonzero(ring)
    design = np.column_stack([np.ones(len(idx)), x.ravel()[idx], y.ravel()[idx]])
    n = len(idx)
    kth = np.array([0, int(0.16 * (n - 1)), int(0.5 * (n - 1)), int(0.84 * (n - 1)), n - 1])
    dtype = np.float32 if n * 255**2 < 2**24 else np.float64
    normal = design.T @ design  # diagonal: the ring is symmetric about the centre (Σx = Σy = Σxy = 0)
    assert not normal[~np.eye(3, dtype=bool)].any(), "ring normal matrix must be diagonal"
    return Ring(idx=idx, design=design, normal_inv=1.0 / np.diag(normal),
                outer=(design[:, :, None] * design[:, None, :]).reshape(-1, 9), kth=kth, dtype=dtype,
                design_t=np.ascontiguousarray(design.T, dtype=dtype))


def ring_background(flat: np.ndarray, valid: np.ndarray | None,
                    half_px: int) -> tuple[np.ndarray, np.ndarray]:
    """Background plane and noise of each window (K, W²) uint8 (``valid``: bool (K, W²) or None).

    Returns (coefficients float32 (K, 3) of a + b·x + c·y in DN, DN/px, DN/px; σ float32 (K,) in DN,
    at least MIN_SIGMA_DN). Pixels with ``valid`` False (outside the image) are ignored.
    """
    geo = ring_geometry(half_px)
    vals = flat[:, geo.idx]
    if valid is not None:  # windows reaching outside the image (rare)
        return _robust(vals, valid[:, geo.idx], geo)
    lo, p16, p50, p84, hi = np.sort(vals, axis=1, kind="stable")[:, geo.kth].T.astype(np.float64)
    reach = OUTLIER_SPREADS * np.maximum(np.minimum(p50 - p16, p84 - p50), 1.0)
    # plain least squares from the ring's moments m = Aᵀy and Σy²: coef = N⁻¹m (N diagonal), and the
    # residual sum of squares is Σy² − coef·m; uint8 values make every product and sum an integer,
    # exact in float32 while P·255² < 2²⁴ (rings of windows up to 33 px), else computed in float64
    values: np.ndarray = vals.astype(geo.dtype)
    moments = matmul_one_thread(values, geo.design_t.T).astype(np.float64)
    coef = moments * geo.normal_inv
    rss = np.vecdot(values, values).astype(np.float64) - np.vecdot(coef, moments)
    sigma = np.maximum(np.sqrt(np.maximum(rss, 0.0) / (len(geo.idx) - 3.0)), MIN_SIGMA_DN)
    coef, sigma = coef.astype(np.float32), sigma.astype(np.float32)
    outliers = np.nonzero(np.maximum(hi - p50, p50 - lo) > reach)[0]
    if len(outliers):  # a few per cent of the rings (noise tails, a neighbour): refit without outliers
        values = vals[outliers].astype(np.float64)
        inlier = np.abs(values - p50[outliers, None]) <= reach[outliers, None]
        coef[outliers], sigma[outliers] = _weighted_fit(values, inlier, geo)
    return coef, sigma


def _robust(ring_vals: np.ndarray, ring_valid: np.ndarray, geo: Ring) -> tuple[np.ndarray, np.ndarray]:
    """The fit of windows reaching outside the image: ring values (K, P) uint8, invalid pixels ignored."""
    vals = np.where(ring_valid, ring_vals.astype(np.float32), np.nan)
    with warnings.catch_warnings():  # a ring wholly outside the frame: NaN, replaced just below
        warnings.simplefilter("ignore", RuntimeWarning)
        p16, p50, p84 = np.nanpercentile(vals, [16, 50, 84], axis=1, method="lower")
    p16, p50, p84 = (np.nan_to_num(p, nan=0.0) for p in (p16, p50, p84))
    reach = OUTLIER_SPREADS * np.maximum(np.minimum(p50 - p16, p84 - p50), 1.0)
    values = ring_vals.astype(np.float64)
    inlier = (np.abs(values - p50[:, None]) <= reach[:, None]) & ring_valid
    coef, sigma = _weighted_fit(values, inlier, geo)
    return coef.astype(np.float32), sigma.astype(np.float32)


def _weighted_fit(values: np.ndarray, inlier: np.ndarray, geo: Ring) -> tuple[np.ndarray, np.ndarray]:
    """Plane fitted to the inlier ring values of each window: (coef (K, 3), σ (K,)), float64.

    Batched weighted normal equations (AᵀMA) coef = AᵀMy, M the inlier mask, solved in closed form
    (symmetric 3×3: adjugate over determinant; a LAPACK call per batch costs more than the whole fit);
    σ is the RMS residual of the inliers (with K − 3 degrees of freedom), at least MIN_SIGMA_DN.
    """
    mask = inlier.astype(np.float64)
    # (K, 9): row-major symmetric 3×3 [[a, b, c], [b, d, e], [c, e, f]]
    normal = matmul_one_thread(mask, geo.outer)
    normal[:, ::4] += 1e-9  # keeps a ring with (almost) no inliers finite
    cof = normal[:, _COF_A] * normal[:, _COF_B] - normal[:, _COF_C] * normal[:, _COF_D]
    det = np.vecdot(normal[:, :3], cof[:, :3])
    rhs = matmul_one_thread(mask * values, geo.design)
    coef = np.vecdot(cof[:, _COF_FULL].reshape(-1, 3, 3), rhs[:, None, :]) / det[:, None]
    resid = (values - matmul_one_thread(coef, geo.design.T)) * mask
    dof = np.maximum(mask.sum(axis=1) - 3.0, 1.0)
    return coef, np.maximum(np.sqrt(np.vecdot(resid, resid) / dof), MIN_SIGMA_DN)


# cofactors of a symmetric 3×3 matrix flattened row-major (a=0, b=1, c=2, d=4, e=5, f=8), in the order
# C00 = df − e², C01 = ce − bf, C02 = be − cd, C11 = af − c², C12 = bc − ae, C22 = ad − b²
_COF_A = np.array([4, 2, 1, 0, 1, 0])
_COF_B = np.array([8, 5, 5, 8, 2, 4])
_COF_C = np.array([5, 1, 2, 2, 0, 1])
_COF_D = np.array([5, 8, 4, 2, 5, 1])
_COF_FULL = np.array([0, 1, 2, 1, 3, 4, 2, 4, 5])  # the symmetric adjugate from the six cofactors
