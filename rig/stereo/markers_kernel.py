"""Compiled per-window kernel of the marker measurement: one call measures every window of a frame.

The measurement itself is described in :mod:`rig.stereo.markers_refine` (background plane of the ring,
centre-connected support, weighted moments, plateau contrast); this module is its loop over windows and
pixels, compiled by numba, so a call
costs a few microseconds of dispatch plus the pixels' own work instead of ~150 numpy calls on (K, W, W)
stacks. The arithmetic follows the numpy formulation it replaced: float32 for the background plane and
the signal (so a pixel is on the support exactly when it was), float64 for the sums (more exact than
the float32 matrix products were: centroids agree to ~1e-6 px). The support of a window of up to 64
columns is found through 64-bit row masks (:func:`_support_bits`: a row at a time by bit operations,
no branch per pixel), that of a larger one by a scanline flood fill (:func:`_support`):
the same region.

Background plane and noise of a window, fitted to its outer ring of ``RING_PX`` pixels (offsets in px
from the window's centre pixel): a plane ``a + b·x + c·y`` (DN, polarity space) and the noise ``σ`` (DN),
the RMS residual of the fit. Robust to whatever else crosses the ring (a neighbouring marker, the edge of
a plate) on up to about a third of it: the spread is taken from the quieter side of the median (min of
p50 − p16 and p84 − p50, ≈ σ for Gaussian noise), ring pixels farther than 4 such spreads from the median
are left out, and the plane is fitted to the rest by least squares. A plane, not a constant, so that a
background gradient (vignetting, uneven lighting) does not pull the centroid uphill. The usual ring
holds no outlier (its extremes lie within the 4 spreads): its percentiles come from a histogram of its
uint8 values and the plain fit from its moments (closed form).

Imported lazily by :mod:`rig.stereo.markers_refine` (numba's import and the loading of the compiled
code, ~0.3–1 s, are paid by the first measurement of a process, not by ``import rig.stereo``). The
compiled code is cached on disk next to this file (numba's ``cache=True``; a read-only install falls
back to numba's user-wide cache directory, and with no writable location at all to compiling once per
process, a few seconds).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any, Literal, TypeVar, cast

import numba
import numpy as np
from numba.cpython.unsafe.numbers import leading_zeros as _leading_zeros
from numba.cpython.unsafe.numbers import trailing_zeros as _trailing_zeros

_F = TypeVar("_F", bound=Callable[..., Any])
# numba intrinsics (count of zero bits below the lowest / above the highest set bit), typed for mypy
trailing_zeros = cast(Callable[[np.uint64], np.uint64], _trailing_zeros)
leading_zeros = cast(Callable[[np.uint64], np.uint64], _leading_zeros)

RING_PX = 2  # width of the background ring at the window's edge
MIN_SIGMA_DN = 0.5  # floor of σ: a flat 8-bit background has zero spread but ±0.5 DN quantization
OUTLIER_SPREADS = 4.0  # ring pixels farther than this many spreads from the median are left out

NOISE_FLOOR_K = 3.0  # support and weight threshold, in units of the window's background noise σ
PLATEAU_LEVEL = 0.85  # contrast = mean signal of the support pixels above this fraction of the peak
# A contrast below this many ring σ: the ring lies on the marker's blurred edge, not on background (its
# plane absorbs the edge, σ tens of DN, and the support shrinks off the ring: the window is too small
# without being cramped; r 18–24 px, blur ≥ 1.9 px in a 41 px window: measured c/σ 3–6.5, centre up to
# 14 px off). Whole markers in the domain of rig.stereo.markers have contrast/σ ≥ 7.
MIN_RING_CONTRAST = 5.0

# rows of the float output of measure_range (one column per window)
OUT_U, OUT_V, OUT_AREA, OUT_ROUND, OUT_CONTRAST = range(5)
OUT_BACKGROUND, OUT_SIGMA, OUT_SKEW, OUT_SKEW_NOISE = range(5, 9)
N_OUT = 9
# rows of the bool output
FLAG_ROW_BORDER, FLAG_ROW_SATURATED, FLAG_ROW_CRAMPED = range(3)
LOST_FLAG = np.uint8(8)  # markers.FLAG_LOST (the kernel does not import rig.stereo.markers)


def jit_kernel(fn: _F, inline: Literal["never", "always"] = "never") -> _F:
    """numba.njit with the on-disk cache when a cache location is writable, else without (a warning)."""
    # error_model="numpy": x/0 gives inf/NaN as in numpy, no exception
    try:
        return cast(_F, numba.njit(cache=True, nogil=True, error_model="numpy", inline=inline)(fn))
    except RuntimeError as exc:  # numba: "cannot cache function ...: no locator available"
        warnings.warn(f"numba kernel not cached on disk ({exc}); compiling it in this process",
                      RuntimeWarning, stacklevel=2)
        return cast(_F, numba.njit(nogil=True, error_model="numpy", inline=inline)(fn))


def _stage(fn: _F) -> _F:
    """A named stage of a kernel, compiled into its caller (numba ``inline="always"``: no call cost)."""
    return jit_kernel(fn, inline="always")


@jit_kernel
def _weighted_plane(vals: np.ndarray, xs: np.ndarray, ys: np.ndarray, keep: np.ndarray,
                    ) -> tuple[float, float, float, float]:
    """Plane a + b·x + c·y fitted by least squares to the ``keep`` ring values; (a, b, c, σ) float64.

    Normal equations solved in closed form (symmetric 3×3: adjugate over determinant, 1e-9 added to the
    diagonal so a ring with (almost) no inliers stays finite); σ = RMS residual with n − 3 degrees of
    freedom (at least 1), at least MIN_SIGMA_DN.
    """
    na = nb = nc = nd = ne = nf = 0.0
    r0 = r1 = r2 = 0.0
    for p in range(len(vals)):
        if keep[p]:
            x, y, v = xs[p], ys[p], float(vals[p])
            na += 1.0
            nb += x
            nc += y
            nd += x * x
            ne += x * y
            nf += y * y
            r0 += v
            r1 += v * x
            r2 += v * y
    count = na
    na += 1e-9
    nd += 1e-9
    nf += 1e-9
    c00 = nd * nf - ne * ne
    c01 = nc * ne - nb * nf
    c02 = nb * ne - nc * nd
    c11 = na * nf - nc * nc
    c12 = nb * nc - na * ne
    c22 = na * nd - nb * nb
    det = na * c00 + nb * c01 + nc * c02
    a = (c00 * r0 + c01 * r1 + c02 * r2) / det
    b = (c01 * r0 + c11 * r1 + c12 * r2) / det
    c = (c02 * r0 + c12 * r1 + c22 * r2) / det
    rss = 0.0
    for p in range(len(vals)):
        if keep[p]:
            res = float(vals[p]) - (a + b * xs[p] + c * ys[p])
            rss += res * res
    sigma = max(np.sqrt(rss / max(count - 3.0, 1.0)), MIN_SIGMA_DN)
    return a, b, c, sigma


@jit_kernel
def _hist_levels(hist: np.ndarray, n: int) -> tuple[float, float, float, float, float]:
    """'lower' percentiles p0, p16, p50, p84, p100 (DN) of ``n`` uint8 values from their histogram."""
    ranks = (0, int(0.16 * (n - 1)), int(0.5 * (n - 1)), int(0.84 * (n - 1)), n - 1)
    lo = p16 = p50 = p84 = hi = 0.0
    seen, level, r = 0, 0, 0
    while r < 5:
        if seen + hist[level] > ranks[r]:
            if r == 0:
                lo = float(level)
            elif r == 1:
                p16 = float(level)
            elif r == 2:
                p50 = float(level)
            elif r == 3:
                p84 = float(level)
            else:
                hi = float(level)
            r += 1
        else:
            seen += hist[level]
            level += 1
    return lo, p16, p50, p84, hi


@jit_kernel
def _plain_fit(  # noqa: PLR0917 (numba: no keyword-only arguments)
        i0: int, ix: int, iy: int, i2: int, ixx: int, iyy: int,
        n_ring: int) -> tuple[float, float, float, float]:
    """Plane (a, b, c) and σ of a whole ring from its integer sums of v, v·x, v·y, v², x², y² (the ring is
    symmetric: the normal matrix is diagonal)."""
    m0, mx, my, s2 = float(i0), float(ix), float(iy), float(i2)
    a, b, c = m0 / n_ring, mx / float(ixx), my / float(iyy)
    rss = s2 - (a * m0 + b * mx + c * my)
    return a, b, c, max(np.sqrt(max(rss, 0.0) / (n_ring - 3.0)), MIN_SIGMA_DN)


@_stage
def _ring_inside(win: np.ndarray, flip: int, hist: np.ndarray) -> tuple[float, float, float, float, bool]:
    """:func:`_ring_plane` of a window lying wholly inside the image, read in place: ``win`` (W, W) the
    image's pixels, ``flip`` 255 for dark markers (polarity space: 255 − I = I ^ 255), else 0.

    Returns (a, b, c, σ, clean); clean False: the ring has outliers, (a, b, c, σ) are not computed and the
    caller fits the ring's values with :func:`_ring_plane` (the same histogram and sums, in any order:
    integers)."""
    w = win.shape[0]
    half_px = w // 2
    hist[:] = 0
    i0 = ix = iy = i2 = ixx = iyy = 0
    for i in range(w):
        y = i - half_px
        if i < RING_PX or i >= w - RING_PX:  # a whole row of the ring
            row_sum = row_x = 0
            for j in range(w):
                v = int(win[i, j] ^ flip)
                hist[v] += 1
                row_sum += v
                row_x += v * (j - half_px)
                i2 += v * v
                ixx += (j - half_px) * (j - half_px)
            i0 += row_sum
            ix += row_x
            iy += y * row_sum
            iyy += w * y * y
        else:  # RING_PX pixels at each end of the row
            for k in range(2 * RING_PX):
                j = k if k < RING_PX else w - 2 * RING_PX + k
                v = int(win[i, j] ^ flip)
                hist[v] += 1
                i0 += v
                ix += v * (j - half_px)
                iy += v * y
                i2 += v * v
                ixx += (j - half_px) * (j - half_px)
                iyy += y * y
    n_ring = w * w - (w - 2 * RING_PX) ** 2
    lo, p16, p50, p84, hi = _hist_levels(hist, n_ring)
    if max(hi - p50, p50 - lo) > OUTLIER_SPREADS * max(min(p50 - p16, p84 - p50), 1.0):
        return 0.0, 0.0, 0.0, 0.0, False
    a, b, c, sigma = _plain_fit(i0, ix, iy, i2, ixx, iyy, n_ring)
    return a, b, c, sigma, True


@jit_kernel
def _ring_plane(  # noqa: PLR0917 (numba: no keyword-only arguments)
        vals: np.ndarray, ok: np.ndarray, all_ok: bool, xs: np.ndarray, ys: np.ndarray,
                keep: np.ndarray, hist: np.ndarray) -> tuple[float, float, float, float]:
    """Robust background plane of one ring: values (P,) uint8, ``ok`` the pixels inside the image.

    'lower' percentiles p16, p50, p84 of the valid values; pixels farther than OUTLIER_SPREADS·spread
    (spread = min(p50 − p16, p84 − p50), at least 1 DN) from the median are left out. A whole ring without
    outliers (the usual case) is fitted from its moments (the ring is symmetric: the normal matrix is
    diagonal); otherwise the weighted fit. ``keep``, ``hist``: scratch (P,) bool and (256,) int64.
    Returns (a, b, c, σ) float64.
    """
    n_ring = len(vals)
    if all_ok:
        hist[:] = 0
        for p in range(n_ring):
            hist[vals[p]] += 1
        lo, p16, p50, p84, hi = _hist_levels(hist, n_ring)
        reach = OUTLIER_SPREADS * max(min(p50 - p16, p84 - p50), 1.0)
        if max(hi - p50, p50 - lo) <= reach:  # no outlier: the plain fit from the ring's moments
            # integer sums (vectorized; exact, as the float64 sums of these integers were)
            i0 = ix = iy = i2 = ixx = iyy = 0
            for p in range(n_ring):
                v, x, y = int(vals[p]), int(xs[p]), int(ys[p])
                i0 += v
                ix += v * x
                iy += v * y
                i2 += v * v
                ixx += x * x
                iyy += y * y
            return _plain_fit(i0, ix, iy, i2, ixx, iyy, n_ring)
    else:
        good = np.sort(vals[ok])
        n_ok = len(good)
        p16 = p50 = p84 = 0.0
        if n_ok:
            p16 = float(good[int(0.16 * (n_ok - 1))])
            p50 = float(good[int(0.5 * (n_ok - 1))])
            p84 = float(good[int(0.84 * (n_ok - 1))])
        reach = OUTLIER_SPREADS * max(min(p50 - p16, p84 - p50), 1.0)
    for p in range(n_ring):
        keep[p] = ok[p] and abs(float(vals[p]) - p50) <= reach
    return _weighted_plane(vals, xs, ys, keep)


@jit_kernel
def ring_offsets(half_px: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ring pixels of a window of half size ``half_px``, in row-major order: (row, column) indices in the
    window (int64) and their offsets (x, y) from the centre pixel (float64)."""
    w = 2 * half_px + 1
    n_ring = w * w - (w - 2 * RING_PX) ** 2
    ri, ci = np.empty(n_ring, np.int64), np.empty(n_ring, np.int64)
    xs, ys = np.empty(n_ring), np.empty(n_ring)
    p = 0
    for i in range(w):
        for j in range(w):
            if i < RING_PX or i >= w - RING_PX or j < RING_PX or j >= w - RING_PX:
                ri[p], ci[p], xs[p], ys[p] = i, j, j - half_px, i - half_px
                p += 1
    return ri, ci, xs, ys


@jit_kernel
def ring_fit(flat: np.ndarray, valid: np.ndarray, half_px: int, coef: np.ndarray, sigma: np.ndarray) -> None:
    """Background plane of each window (K, W²) uint8 into ``coef`` (K, 3) and ``sigma`` (K,) float32.

    ``valid``: (K, W²) bool, False outside the image, or an empty (0, 0) array when all pixels are valid.
    """
    ri, ci, xs, ys = ring_offsets(half_px)
    idx = ri * (2 * half_px + 1) + ci
    n_ring = len(idx)
    vals = np.empty(n_ring, np.uint8)
    ok = np.ones(n_ring, np.bool_)
    keep = np.empty(n_ring, np.bool_)
    hist = np.empty(256, np.int64)
    for k in range(flat.shape[0]):
        all_ok = True
        for p in range(n_ring):
            vals[p] = flat[k, idx[p]]
            if valid.shape[0]:
                ok[p] = valid[k, idx[p]]
                all_ok = all_ok and ok[p]
        a, b, c, s = _ring_plane(vals, ok, all_ok, xs, ys, keep, hist)
        coef[k, 0], coef[k, 1], coef[k, 2], sigma[k] = a, b, c, s


def ring_background(flat: np.ndarray, valid: np.ndarray | None,
                    half_px: int) -> tuple[np.ndarray, np.ndarray]:
    """Background plane and noise of each window (K, W²) uint8 (``valid``: bool (K, W²) or None).

    Returns (coefficients float32 (K, 3) of a + b·x + c·y in DN, DN/px, DN/px; σ float32 (K,) in DN,
    at least MIN_SIGMA_DN). Pixels with ``valid`` False (outside the image) are ignored.
    """
    coef = np.empty((len(flat), 3), dtype=np.float32)
    sigma = np.empty(len(flat), dtype=np.float32)
    no_mask = np.ones((0, 0), dtype=bool)
    ring_fit(np.ascontiguousarray(flat, dtype=np.uint8),
             no_mask if valid is None else np.ascontiguousarray(valid, dtype=bool), half_px, coef, sigma)
    return coef, sigma


@jit_kernel
def _gather(  # noqa: PLR0917 (numba: no keyword-only arguments)
        image: np.ndarray, row: int, col: int, half_px: int, dark: bool, raw: np.ndarray,
        valid: np.ndarray) -> bool:
    """Window centred on (row, col) into ``raw`` (W, W) uint8, polarity space (dark: 255 − I).

    Returns whether every pixel lies inside the image; if not, out-of-image pixels repeat the nearest
    edge pixel and are False in ``valid`` (which is left untouched for a window inside the image).
    """
    height, width = image.shape
    w = raw.shape[0]
    top, left = row - half_px, col - half_px
    if top >= 0 and left >= 0 and top + w <= height and left + w <= width:
        for i in range(w):
            src = image[top + i]
            if dark:
                for j in range(w):
                    raw[i, j] = 255 - src[left + j]
            else:
                for j in range(w):
                    raw[i, j] = src[left + j]
        return True
    for i in range(w):
        r = top + i
        rc = min(max(r, 0), height - 1)
        for j in range(w):
            c = left + j
            value = image[rc, min(max(c, 0), width - 1)]
            raw[i, j] = 255 - value if dark else value
            valid[i, j] = r == rc and c >= 0 and c < width
    return False


@jit_kernel
def _ring_values(  # noqa: PLR0917 (numba: no keyword-only arguments)
        raw: np.ndarray, valid: np.ndarray, inside: bool, ri: np.ndarray, ci: np.ndarray, vals: np.ndarray,
        ok: np.ndarray) -> None:
    """The ring pixels (``ri``, ``ci``: :func:`ring_offsets`) of the window ``raw`` (W, W) into ``vals``,
    and whether each lies inside the image into ``ok``."""
    for p in range(len(ri)):
        vals[p] = raw[ri[p], ci[p]]
        ok[p] = inside or valid[ri[p], ci[p]]


@_stage
def _weigh(  # noqa: PLR0917 (numba: no keyword-only arguments)
        raw: np.ndarray, flip: int, valid: np.ndarray, inside: bool, plane: tuple[float, float, float],
        floor: np.float32, d: np.ndarray, clipped: np.ndarray, free: np.ndarray) -> None:
    """Signal above the background plane and the noise floor (float32, > 0 on the support) into the
    padded flat ``d`` ((W + 2)², its one-pixel frame left 0; 0 outside the image), and whether a pixel is
    clipped (255) into the padded flat ``clipped`` (bool), and ``free`` = d > 0 (uint8: candidates of the
    support, cleared by :func:`_support` as it takes them). ``raw`` (W, W): the window in polarity space
    after ``^ flip`` (0, or 255 for dark markers read in place from the image: 255 − I = I ^ 255)."""
    w = raw.shape[0]
    half_px, pw = w // 2, w + 2
    a = np.float32(plane[0]) + floor
    b, c = np.float32(plane[1]), np.float32(plane[2])
    bx = np.empty(w, np.float32)
    for j in range(w):
        bx[j] = a + b * np.float32(j - half_px)
    for i in range(w):
        cy = c * np.float32(i - half_px)
        row = (i + 1) * pw + 1
        for j in range(w):
            level = raw[i, j] ^ flip
            value = np.float32(level) - (bx[j] + cy)
            d[row + j] = value
            clipped[row + j] = level == 255
            free[row + j] = value > 0
    if not inside:  # out-of-image pixels: no signal
        # (d zeroed first, then free = d > 0 row by row: clearing both in one conditional loop was
        # compiled on this AVX-512 VM into stores that also cleared free where valid was True — eight
        # columns of a marker lost, its centre 2.8 px off; tests/test_stereo_markers_flags.py)
        for i in range(w):
            row = (i + 1) * pw + 1
            for j in range(w):
                if not valid[i, j]:
                    d[row + j] = 0.0
            for j in range(w):
                free[row + j] = d[row + j] > 0


@_stage
def _seed(d: np.ndarray, half_px: int, free: np.ndarray) -> int:
    """Where the support grows from (flat padded index): the centre pixel when it is on ``d > 0``, else
    :func:`_strongest_near_centre`."""
    pw = 2 * half_px + 3
    seed = (half_px + 1) * pw + half_px + 1
    return seed if free[seed] else _strongest_near_centre(d, half_px)


@_stage
def _strongest_near_centre(d: np.ndarray, half_px: int) -> int:
    """The strong pixel nearest the centre among those at least half as strong as the window's strongest
    (so a noise speck is never chosen; ties: the first in row-major order) (flat padded index); −1 when no
    pixel is on ``d > 0``."""
    w = 2 * half_px + 1
    pw = w + 2
    peak = np.float32(-np.inf)
    for i in range(w):
        for j in range(w):
            peak = max(peak, d[(i + 1) * pw + j + 1])
    half_peak = np.float32(0.5) * peak
    best, seed = np.inf, -1
    for i in range(w):
        for j in range(w):
            q = (i + 1) * pw + j + 1
            if d[q] > 0 and d[q] >= half_peak:
                dist2 = float((i - half_px) ** 2 + (j - half_px) ** 2)
                if dist2 < best:
                    best, seed = dist2, q
    return seed


@_stage
def _run_ends(free: np.ndarray, q: int) -> tuple[int, int]:
    """First and last flat index of the run of ``free`` pixels holding ``q`` (the padding frame is 0: a
    run never leaves its row)."""
    left, right = q, q
    while free[left - 1]:
        left -= 1
    while free[right + 1]:
        right += 1
    return left, right


@_stage
def _take_run(  # noqa: PLR0917 (numba: no keyword-only arguments)
        d: np.ndarray, free: np.ndarray, clipped: np.ndarray, pixels: np.ndarray, n: int, left: int,
        right: int, x0: int) -> tuple[int, float, float, float, float, float, bool]:
    """Take the run ``left..right`` into the support: cleared in ``free``, its pixels into ``pixels[n:]``.
    Returns (new n, the run's sums of v, v·x, v·x², v·x³ with x = index − ``x0``, its peak v, whether a
    pixel is ``clipped``)."""
    s0 = s1 = s2 = s3 = 0.0
    peak_w, saturated = 0.0, False
    for x in range(left, right + 1):
        free[x] = 0
        pixels[n] = x
        n += 1
        v, xo = float(d[x]), float(x - x0)
        vx = v * xo
        s0 += v
        s1 += vx
        s2 += vx * xo
        s3 += vx * xo * xo
        peak_w = max(peak_w, v)
        saturated |= clipped[x]
    return n, s0, s1, s2, s3, peak_w, saturated


@_stage
def _reaches(iy: int, lo_x: int, hi_x: int, edge: int) -> bool:
    """Whether the run of row offset ``iy`` over column offsets ``lo_x..hi_x`` holds a pixel with
    max(|x|, |y|) == ``edge``."""
    if abs(iy) == edge:  # |x| ≤ edge on this row
        return lo_x <= edge and hi_x >= -edge
    if abs(iy) < edge:  # … or x = ±edge
        return (lo_x <= -edge <= hi_x) or (lo_x <= edge <= hi_x)
    return False


@_stage
def _push_spans(  # noqa: PLR0917 (numba: no keyword-only arguments)
        free: np.ndarray, stack: np.ndarray, top: int, left: int, right: int, pw: int) -> int:
    """Push one seed per run of ``free`` pixels among the 8-neighbours of the run ``left..right`` in the
    rows above and below (row length ``pw``) onto ``stack[top:]``; returns the new top."""
    for shift in (-pw, pw):
        new_run = True
        for x in range(left - 1 + shift, right + 2 + shift):
            if free[x]:
                if new_run:
                    stack[top] = x
                    top += 1
                new_run = False
            else:
                new_run = True
    return top


@_stage
def _add_row_moments(  # noqa: PLR0917 (numba: no keyword-only arguments)
        ms: tuple[float, ...], y: float, s0: float, s1: float, s2: float,
        s3: float) -> tuple[float, ...]:
    """The support's ten moment sums (Σw, Σwx, Σwy, Σwx², Σwxy, Σwy², Σwx³, Σwx²y, Σwxy², Σwy³) with one row's
    run added: ``s0..s3`` its Σw, Σwx, Σwx², Σwx³ at row offset ``y``."""
    return (ms[0] + s0, ms[1] + s1, ms[2] + y * s0, ms[3] + s2, ms[4] + y * s1, ms[5] + y * y * s0,
            ms[6] + s3, ms[7] + y * s2, ms[8] + y * y * s1, ms[9] + y * y * y * s0)


@jit_kernel
def _support(  # noqa: PLR0917 (numba: no keyword-only arguments)
        d: np.ndarray, half_px: int, free: np.ndarray, clipped: np.ndarray, pixels: np.ndarray,
        stack: np.ndarray, m: np.ndarray) -> tuple[int, float, bool, bool]:
    """The 8-connected region of ``d > 0`` holding the window's marker: its pixels (flat padded indices)
    into ``pixels[:n]``, cleared in ``free`` (uint8, padded flat: 1 where d > 0 on entry), and its weighted
    raw moments (1, x, y, xx, xy, yy, xxx, xxy, xyy, yyy; offsets from the centre pixel) into ``m``, summed
    run by run. Returns (n, peak weight, saturated: a pixel ``clipped``, cramped: the region reaches the
    ring's inner edge, RING_PX − 1 pixels from the window's border: the window is too small).
    ``stack``: scratch, 4·(W + 2)² int64 (a pixel is pushed at most once from each of the runs beside it).

    The marker is the region of the seed (:func:`_seed`), filled scanline by scanline: each popped seed
    grows into its row's run (:func:`_run_ends`, :func:`_take_run`), whose 8-neighbour spans in the rows
    above and below seed their own runs (:func:`_push_spans`). The stages are compiled into this function
    (``inline="always"``): it is called per marker per frame, where a call between stages would cost more
    than a stage.
    """
    seed = _seed(d, half_px, free)
    if seed < 0:
        m[:] = 0.0
        return 0, 0.0, False, False
    pw = 2 * half_px + 3
    stack[0] = seed
    top, n = 1, 0
    ms: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # scalars: kept in registers
    peak_w, saturated, cramped = 0.0, False, False
    edge = half_px - RING_PX + 1
    while top:
        top -= 1
        q = stack[top]
        if not free[q]:
            continue
        left, right = _run_ends(free, q)
        row = left // pw
        iy, x0 = row - 1 - half_px, row * pw + 1 + half_px
        n, s0, s1, s2, s3, run_peak, run_saturated = _take_run(d, free, clipped, pixels, n, left, right, x0)
        peak_w = max(peak_w, run_peak)
        saturated |= run_saturated
        ms = _add_row_moments(ms, float(iy), s0, s1, s2, s3)
        cramped |= _reaches(iy, left - x0, right - x0, edge)
        top = _push_spans(free, stack, top, left, right, pw)
    for j in range(10):
        m[j] = ms[j]
    return n, peak_w, saturated, cramped


MASK_BITS = 64  # windows of at most this many columns take their support through 64-bit row masks
_ONE = np.uint64(1)


@_stage
def _row_masks(d: np.ndarray, w: int, masks: np.ndarray) -> None:
    """Each row i of the window's ``d > 0`` (padded flat ``d`` of a (W, W) window, W ≤ MASK_BITS) as bits
    (bit j = column j) into ``masks[i]`` (uint64)."""
    pw = w + 2
    for i in range(w):
        row = (i + 1) * pw + 1
        bits = np.uint64(0)
        for j in range(w):
            bits |= np.uint64(d[row + j] > 0) << np.uint64(j)
        masks[i] = bits


@_stage
def _fill_runs(seeds: np.uint64, mask: np.uint64) -> np.uint64:
    """The runs of set bits of ``mask`` holding a bit of ``seeds`` (a subset of ``mask``): upward by the
    carry of mask + seeds, downward by doubling shifts (Kogge–Stone)."""
    up = (mask & ~(mask + seeds)) | seeds
    down, pass_ = seeds, mask
    for shift in (1, 2, 4, 8, 16, 32):
        down |= pass_ & (down >> np.uint64(shift))
        pass_ &= pass_ >> np.uint64(shift)
    return np.uint64(up | down)


@_stage
def _spread(bits: np.uint64) -> np.uint64:
    """``bits`` and their left and right neighbours (8-connectivity between rows)."""
    return bits | (bits << _ONE) | (bits >> _ONE)


@_stage
def _grow_row(masks: np.ndarray, region: np.ndarray, i: int, w: int) -> np.uint64:
    """Row i of the region grown by the runs of ``masks[i]`` touching the region's rows above and below;
    returns its new bits (also written to ``region[i]``)."""
    near = np.uint64(0)
    if i > 0:
        near |= _spread(region[i - 1])
    if i < w - 1:
        near |= _spread(region[i + 1])
    grown = region[i] | _fill_runs(near & masks[i], masks[i])
    added: np.uint64 = grown & ~region[i]
    region[i] = grown
    return added


@_stage
def _region(masks: np.ndarray, w: int, seed_row: int, seed_col: int, region: np.ndarray) -> tuple[int, int]:
    """The 8-connected region of the set bits of ``masks`` (W uint64 rows) holding (seed_row, seed_col),
    into ``region`` (W uint64 rows, bits outside the region 0); returns its first and last row.

    Sweeps down and up the rows, each row taking the runs that touch the region in the rows beside it,
    until a sweep finds that no row it grew reaches back into the row it came from (a region that is
    convex down the rows: two sweeps)."""
    region[:w] = 0
    region[seed_row] = _fill_runs(_ONE << np.uint64(seed_col), masks[seed_row])
    first = last = seed_row
    step, i, sweeps, again = 1, seed_row + 1, 0, False
    while True:
        if 0 <= i < w and first - 1 <= i <= last + 1:
            added = _grow_row(masks, region, i, w)
            if added:
                first, last = min(first, i), max(last, i)
                back = i - step
                if 0 <= back < w and _spread(added) & masks[back] & ~region[back]:
                    again = True
            i += step
            continue
        sweeps += 1
        if sweeps >= 2 and not again:
            return first, last
        again = False
        step = -step
        i = min(last + 1, w - 1) if step < 0 else max(first - 1, 0)


@_stage
def _support_bits(  # noqa: PLR0917 (numba: no keyword-only arguments)
        d: np.ndarray, half_px: int, clipped: np.ndarray, masks: np.ndarray, region: np.ndarray,
        m: np.ndarray) -> tuple[int, float, bool, bool, int, int]:
    """:func:`_support` of a window of at most MASK_BITS columns through 64-bit row masks: the region's
    rows as bits into ``region`` (``masks``, ``region``: W uint64, scratch), its moments summed row by row
    (equal to :func:`_support`'s to the last bits of float64: the terms are the same, their order is not).
    Returns (n, peak weight, saturated, cramped, first and last row of the region: empty, 0 and −1,
    when no pixel is on ``d > 0``)."""
    w = 2 * half_px + 1
    pw = w + 2
    _row_masks(d, w, masks)
    centre = (half_px + 1) * pw + half_px + 1
    seed = centre if masks[half_px] >> np.uint64(half_px) & _ONE else _strongest_near_centre(d, half_px)
    if seed < 0:
        m[:] = 0.0
        return 0, 0.0, False, False, 0, -1
    first, last = _region(masks, w, seed // pw - 1, seed % pw - 1, region)
    n = 0
    ms: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    peak_w, saturated, cramped = 0.0, False, False
    edge = half_px - RING_PX + 1
    inner = ((_ONE << np.uint64(w - 1)) - _ONE) & ~_ONE  # columns 1 … W − 2: |x| ≤ edge
    sides = (_ONE << np.uint64(1)) | (_ONE << np.uint64(w - 2))  # x = ±edge
    for i in range(first, last + 1):
        bits = region[i]
        if not bits:
            continue
        iy = i - half_px
        cramped |= bool(bits & (inner if abs(iy) == edge else sides if abs(iy) < edge else np.uint64(0)))
        lo, hi = np.int64(trailing_zeros(bits)), 63 - np.int64(leading_zeros(bits))
        start = (i + 1) * pw + 1 + lo
        run, run_clipped = d[start:start + hi - lo + 1], clipped[start:start + hi - lo + 1]
        on = bits >> np.uint64(lo)  # bit k: column lo + k is in the region (a gap's weight counts 0)
        s0 = s1 = s2 = s3 = 0.0
        xo = float(lo - half_px)
        for k in range(len(run)):
            take = np.int64(on >> np.uint64(k) & _ONE)
            v = float(run[k]) if take else 0.0
            vx = v * xo
            s0 += v
            s1 += vx
            s2 += vx * xo
            s3 += vx * xo * xo
            peak_w = max(peak_w, v)
            saturated |= run_clipped[k] & (take == 1)
            n += int(take)
            xo += 1.0
        ms = _add_row_moments(ms, float(iy), s0, s1, s2, s3)
    for j in range(10):
        m[j] = ms[j]
    return n, peak_w, saturated, cramped, first, last


@_stage
def _plateau_bits(  # noqa: PLR0917 (numba: no keyword-only arguments)
        d: np.ndarray, half_px: int, region: np.ndarray, first: int, last: int, peak: float) -> float:
    """:func:`_plateau` of the region's rows ``first..last`` as bits (:func:`_support_bits`)."""
    pw = 2 * half_px + 3
    level = np.float32(PLATEAU_LEVEL) * np.float32(peak)
    total, count = 0.0, 0
    for i in range(first, last + 1):
        bits = region[i]
        if not bits:
            continue
        lo, hi = np.int64(trailing_zeros(bits)), 63 - np.int64(leading_zeros(bits))
        start = (i + 1) * pw + 1 + lo
        run = d[start:start + hi - lo + 1]
        on = bits >> np.uint64(lo)
        for k in range(len(run)):
            if run[k] >= level and on >> np.uint64(k) & _ONE:
                total += float(run[k])
                count += 1
    return total / count if count else 0.0


@_stage
def _region_pixels(region: np.ndarray, first: int, last: int, half_px: int, pixels: np.ndarray) -> int:
    """The region's pixels (flat padded indices, row-major) into ``pixels``; returns their number."""
    pw = 2 * half_px + 3
    n = 0
    for i in range(first, last + 1):
        for j in range(2 * half_px + 1):
            if region[i] >> np.uint64(j) & _ONE:
                pixels[n] = (i + 1) * pw + 1 + j
                n += 1
    return n


@_stage
def _covariance(m: np.ndarray) -> tuple[float, float, float, float, float]:
    """Centroid offsets (mx, my) px and the weighted covariance (cxx, cxy, cyy) px² from the raw moments."""
    mx, my = m[1] / m[0], m[2] / m[0]
    return mx, my, m[3] / m[0] - mx * mx, m[4] / m[0] - mx * my, m[5] / m[0] - my * my


@_stage
def _moment_shape(m: np.ndarray) -> tuple[float, float, float, float]:
    """Centroid offsets, roundness and skewness from the raw moments (1, x, y, xx, xy, yy, xxx, ...).

    skewness = (μ30² + 3μ21² + 3μ12² + μ03²) / det(Σ)^(3/2) from the central moments: Mardia's b1 for a
    round blob, 0 for every centrally symmetric one. Empty windows give NaN (0/0).
    """
    mx, my, cxx, cxy, cyy = _covariance(m)
    exxx, exxy, exyy, eyyy = m[6] / m[0], m[7] / m[0], m[8] / m[0], m[9] / m[0]
    mx2, my2 = mx * mx, my * my
    det = cxx * cyy - cxy * cxy
    half_trace = 0.5 * (cxx + cyy)
    root = np.sqrt(max(half_trace * half_trace - det, 0.0))
    roundness = np.sqrt(max(half_trace - root, 0.0) / (half_trace + root))
    c30 = exxx - mx * (3.0 * cxx + mx2)
    c03 = eyyy - my * (3.0 * cyy + my2)
    c21 = exxy - my * (cxx + mx2) - 2.0 * mx * cxy
    c12 = exyy - mx * (cyy + my2) - 2.0 * my * cxy
    skew = (c30 * c30 + c03 * c03 + 3.0 * (c21 * c21 + c12 * c12)) / det**1.5
    return mx, my, roundness, skew


@_stage
def _power_sums(lo: float, hi: float) -> tuple[float, float, float, float, float, float, float]:
    """Σ x^k over the integers x = lo..hi (lo ≤ hi), k = 0..6: Faulhaber's F_k(hi) − F_k(lo − 1), where
    F_k(n) = Σ_{x=1..n} x^k as a polynomial (F_k(n) − F_k(n − 1) = n^k for every integer n), in float64
    (relative error ~1e-16: its divisions are multiplications by reciprocals)."""
    fh = _faulhaber(hi)
    fl = _faulhaber(lo - 1.0)
    return (fh[0] - fl[0], fh[1] - fl[1], fh[2] - fl[2], fh[3] - fl[3], fh[4] - fl[4], fh[5] - fl[5],
            fh[6] - fl[6])


@_stage
def _faulhaber(n: float) -> tuple[float, float, float, float, float, float, float]:
    """F_0(n) … F_6(n), F_k(n) = Σ_{x=1..n} x^k (see :func:`_power_sums`)."""
    a = n * (n + 1.0)
    b = a * (2.0 * n + 1.0)
    return (n, 0.5 * a, b * (1.0 / 6.0), 0.25 * a * a, b * (3.0 * a - 1.0) * (1.0 / 30.0),
            a * a * (2.0 * a - 1.0) * (1.0 / 12.0), b * (3.0 * a * a - 3.0 * a + 1.0) * (1.0 / 42.0))


@_stage
def _run_skew_terms(  # noqa: PLR0917 (numba: no keyword-only arguments)
        lo: float, hi: float, y: float, mx: float, cxx: float, cxy: float, cyy: float) -> float:
    """Σ over the pixels x = lo..hi px of one row, y px from the centroid, of f30² + f03² + 3·(f21² + f12²):
    f_pq = ∂(m0·μ_pq)/∂w, how far a pixel's weight moves a central third moment (the centroid's own shift
    included: f30 = X³ − 3cxx·X, f21 = X²y − 2cxy·X − cxx·y, X = x − mx), in closed form from the row's
    power sums of X."""
    s0, s1, s2, s3, s4, s5, s6 = _power_sums(lo, hi)
    u = -mx  # Σ X^j = Σ (x + u)^j
    u2 = u * u
    u3 = u2 * u
    t1 = s1 + u * s0
    t2 = s2 + 2.0 * u * s1 + u2 * s0
    t3 = s3 + 3.0 * u * s2 + 3.0 * u2 * s1 + u3 * s0
    t4 = s4 + 4.0 * u * s3 + 6.0 * u2 * s2 + 4.0 * u3 * s1 + u2 * u2 * s0
    t6 = (s6 + 6.0 * u * s5 + 15.0 * u2 * s4 + 20.0 * u3 * s3 + 15.0 * u2 * u2 * s2 + 6.0 * u2 * u3 * s1
          + u3 * u3 * s0)
    y2 = y * y
    return (t6 + 3.0 * y2 * t4 + 3.0 * y2 * y2 * t2 + y2 * y2 * y2 * s0
            - 6.0 * cxx * t4 - 6.0 * cyy * y2 * y2 * s0 - 12.0 * cxy * (y * t3 + y * y2 * t1)
            - 6.0 * (cxx + cyy) * y2 * t2 + (9.0 * cxx * cxx + 12.0 * cxy * cxy + 3.0 * cyy * cyy) * t2
            + (9.0 * cyy * cyy + 12.0 * cxy * cxy + 3.0 * cxx * cxx) * y2 * s0
            + 12.0 * cxy * (cxx + cyy) * y * t1)


@_stage
def _skew_noise_bits(region: np.ndarray, first: int, last: int, half_px: int, m: np.ndarray) -> float:
    """Skewness of the support's weights expected from unit noise (1 DN² on each of its pixels), 1/DN²:
    Σ_support (f30² + f03² + 3·(f21² + f12²)) / (m0²·det(Σ)^(3/2)) (:func:`_run_skew_terms`), the first-order
    propagation of independent pixel noise into b1 (:func:`_moment_shape`); run by run of the region's rows
    ``first..last`` as bits (:func:`_support_bits`)."""
    mx, my, cxx, cxy, cyy = _covariance(m)
    total = 0.0
    for i in range(first, last + 1):
        bits = region[i]
        y = float(i - half_px) - my
        while bits:  # a row's bits hold one run, unless the region has a hole or a bay
            lo = np.int64(trailing_zeros(bits))
            length = np.int64(trailing_zeros(~(bits >> np.uint64(lo))))  # W ≤ 63 bits: a 0 above the run
            total += _run_skew_terms(float(lo - half_px), float(lo + length - 1 - half_px), y, mx, cxx, cxy,
                                     cyy)
            bits &= ~(((_ONE << np.uint64(length)) - _ONE) << np.uint64(lo))
    det = cxx * cyy - cxy * cxy
    return float(total / (m[0] * m[0] * det * np.sqrt(det)))


@_stage
def _skew_noise(pixels: np.ndarray, half_px: int, m: np.ndarray) -> float:
    """:func:`_skew_noise_bits` of the support ``pixels`` (flat padded indices, each row's runs in order,
    as :func:`_support` lists them)."""
    mx, my, cxx, cxy, cyy = _covariance(m)
    pw = 2 * half_px + 3
    total = 0.0
    start = 0
    for p in range(len(pixels)):
        if p + 1 < len(pixels) and pixels[p + 1] == pixels[p] + 1:
            continue  # the run goes on (the padding column keeps rows apart)
        q0 = pixels[start]
        y = float(q0 // pw - 1 - half_px) - my
        x0 = float(q0 % pw - 1 - half_px)
        total += _run_skew_terms(x0, x0 + float(p - start), y, mx, cxx, cxy, cyy)
        start = p + 1
    det = cxx * cyy - cxy * cxy
    return float(total / (m[0] * m[0] * det * np.sqrt(det)))


@_stage
def _plateau(d: np.ndarray, pixels: np.ndarray, peak: float) -> float:
    """Mean weight of the support ``pixels`` at or above PLATEAU_LEVEL of the peak weight (0 for none)."""
    level = np.float32(PLATEAU_LEVEL) * np.float32(peak)
    total, count = 0.0, 0
    for q in pixels:
        if d[q] >= level:
            total += float(d[q])
            count += 1
    return total / count if count else 0.0


@jit_kernel
def _touch(image: np.ndarray, rows: np.ndarray, cols: np.ndarray, half_px: int, sink: np.ndarray) -> None:
    """Read the first and last pixel of every row of every window before measuring any: independent
    loads, so the memory system fetches the windows' cache lines in parallel (a window read row by row
    after other work has flushed the caches waits for its lines one by one). The sum goes to ``sink[0]``
    (so the loads are not optimized away)."""
    height, width = image.shape
    total = 0
    for k in range(len(rows)):
        c0, c1 = min(max(cols[k] - half_px, 0), width - 1), min(max(cols[k] + half_px, 0), width - 1)
        for r in range(max(rows[k] - half_px, 0), min(rows[k] + half_px + 1, height)):
            total += image[r, c0] + image[r, c1]
    sink[0] = total


@jit_kernel
def scratch(half_px: int) -> tuple[np.ndarray, ...]:
    """Work arrays of :func:`measure_one` for windows of half size ``half_px`` (reused from window to
    window)."""
    w = 2 * half_px + 1
    pw = w + 2
    n_ring = w * w - (w - 2 * RING_PX) ** 2
    ri, ci, ring_x, ring_y = ring_offsets(half_px)
    return (np.empty(n_ring, np.uint8), np.ones(n_ring, np.bool_), np.empty(n_ring, np.bool_),
            ring_x, ring_y, np.empty((w, w), np.uint8), np.ones((w, w), np.bool_),
            np.zeros(pw * pw, np.float32), np.zeros(pw * pw, np.uint8), np.zeros(pw * pw, np.bool_),
            np.empty(w * w, np.int64), np.empty(4 * pw * pw, np.int64), np.empty(10),
            np.empty(w, np.uint64), np.empty(w, np.uint64), ri, ci, np.empty(256, np.int64))


@jit_kernel
def measure_one(  # noqa: PLR0917 (numba: no keyword-only arguments)
        image: np.ndarray, row: int, col: int, half_px: int, dark: bool, scr: tuple[np.ndarray, ...],
        out: np.ndarray, flags: np.ndarray, n: int, signal: np.ndarray, noise_above: float) -> None:
    """Measure the window of half size ``half_px`` centred on the integer pixel (row, col) of ``image``
    into column ``n`` of ``out`` and ``flags`` (and ``signal[n]`` when ``signal`` has rows); ``scr``:
    :func:`scratch` of the same half size. The skewness noise is computed only for a skewness above
    ``noise_above`` (NaN otherwise). See :func:`measure_range`."""
    vals, ok, keep, ring_x, ring_y, raw, valid, d, free, clipped, queue, stack, m = scr[:13]
    masks, region, ri, ci, hist = scr[13:]
    w, pw = 2 * half_px + 1, 2 * half_px + 3
    height, width = image.shape
    top, left = row - half_px, col - half_px
    inside = top >= 0 and left >= 0 and top + w <= height and left + w <= width
    if inside:  # the usual case: the window's pixels read in place, not copied
        win = image[top:top + w, left:left + w]
        flip = 255 if dark else 0
        a, b, c, s, clean = _ring_inside(win, flip, hist)
        if not clean:  # something crosses the ring: the robust fit of its values in ring order
            for p in range(len(ri)):
                vals[p] = win[ri[p], ci[p]] ^ flip
            ok[:] = True
            a, b, c, s = _ring_plane(vals, ok, True, ring_x, ring_y, keep, hist)
        floor = np.float32(NOISE_FLOOR_K) * np.float32(s)
        _weigh(win, flip, valid, True, (a, b, c), floor, d, clipped, free)
    else:  # a copy with the edge pixels repeated and marked invalid
        _gather(image, row, col, half_px, dark, raw, valid)
        _ring_values(raw, valid, False, ri, ci, vals, ok)
        a, b, c, s = _ring_plane(vals, ok, False, ring_x, ring_y, keep, hist)
        floor = np.float32(NOISE_FLOOR_K) * np.float32(s)
        _weigh(raw, 0, valid, False, (a, b, c), floor, d, clipped, free)
    sigma = np.float32(s)
    if w <= MASK_BITS:  # rows as bits; the pixels listed only for the signal
        n_support, peak_w, saturated, cramped, first, last = _support_bits(d, half_px, clipped, masks, region,
                                                                           m)
        plateau = _plateau_bits(d, half_px, region, first, last, peak_w)
        if signal.shape[0]:
            n_support = _region_pixels(region, first, last, half_px, queue)
    else:
        n_support, peak_w, saturated, cramped = _support(d, half_px, free, clipped, queue, stack, m)
        plateau = _plateau(d, queue[:n_support], peak_w)
    pixels = queue[:n_support]
    du, dv, roundness, skew = _moment_shape(m)
    skew_noise = np.nan  # wanted only above noise_above (a skewness below max_skewness is never flagged)
    if skew > noise_above:
        skew_noise = (_skew_noise_bits(region, first, last, half_px, m) if w <= MASK_BITS
                      else _skew_noise(pixels, half_px, m))
    contrast = plateau + float(floor) if m[0] > 0 else np.nan
    area = m[0] / plateau
    out[OUT_U, n], out[OUT_V, n] = col + du, row + dv
    out[OUT_AREA, n], out[OUT_ROUND, n], out[OUT_CONTRAST, n] = area, roundness, contrast
    out[OUT_BACKGROUND, n], out[OUT_SIGMA, n], out[OUT_SKEW, n] = float(np.float32(a)), float(sigma), skew
    out[OUT_SKEW_NOISE, n] = float(sigma) ** 2 * skew_noise
    flags[FLAG_ROW_BORDER, n], flags[FLAG_ROW_SATURATED, n] = not inside, saturated
    flags[FLAG_ROW_CRAMPED, n] = cramped
    if signal.shape[0]:
        signal[n] = 0.0
        for q in pixels:
            signal[n, q // pw - 1, q % pw - 1] = d[q] + floor


@jit_kernel
def measure_range(  # noqa: PLR0917 (numba: no keyword-only arguments)
        image: np.ndarray, rows: np.ndarray, cols: np.ndarray, lo: int, hi: int, half_px: int,
        dark: bool, out: np.ndarray, flags: np.ndarray, signal: np.ndarray) -> None:
    """Measure windows ``lo..hi−1`` of one frame ``image`` (H, W) uint8; window n centred on the integer
    pixel (rows[n], cols[n]), of W = 2·half_px + 1 pixels.

    Writes ``out`` (N_OUT, N) float64 (OUT_* rows: centre in image px, area px², roundness, contrast DN,
    background DN at the centre, σ DN, skewness and the skewness that the noise σ alone would give the
    marker (σ² times :func:`_skew_noise_bits`); NaN for a window without support), ``flags`` (3, N)
    bool (FLAG_ROW_*), and when ``signal`` has N rows the background-subtracted signal on the support
    ((N, W, W) float32, 0 elsewhere) for the outline fit.
    """
    scr = scratch(half_px)
    _touch(image, rows[lo:hi], cols[lo:hi], half_px, scr[12])
    for n in range(lo, hi):
        measure_one(image, rows[n], cols[n], half_px, dark, scr, out, flags, n, signal, -np.inf)


@jit_kernel
def _finish_row(out: np.ndarray, flags: np.ndarray, n: int, limits: np.ndarray, row: Any) -> bool:
    """Output row ``row`` (markers.MARKER_DTYPE) from column ``n`` of ``out`` and ``flags``; whether it
    passes the filters. ``limits`` as in :func:`finish_rows`."""
    row.u_px, row.v_px = out[OUT_U, n], out[OUT_V, n]
    row.area_px, row.roundness, row.contrast = out[OUT_AREA, n], out[OUT_ROUND, n], out[OUT_CONTRAST, n]
    occluded = out[OUT_SKEW, n] > limits[0] + limits[1] * out[OUT_SKEW_NOISE, n]
    row.flags = (np.uint8(flags[FLAG_ROW_BORDER, n]) | np.uint8(occluded) << 1
                 | np.uint8(flags[FLAG_ROW_SATURATED, n]) << 2)
    return bool(np.isfinite(row.u_px + row.v_px) and limits[2] <= row.area_px <= limits[3]
                and row.roundness >= limits[4] and row.contrast >= limits[5])


@jit_kernel
def _measure_retrying(  # noqa: PLR0917 (numba: no keyword-only arguments)
        image: np.ndarray, row: int, col: int, half_px: int, dark: bool, scr: tuple[np.ndarray, ...],
        ladder: np.ndarray, retries: int, out: np.ndarray, flags: np.ndarray, no_signal: np.ndarray,
        max_skewness: float) -> None:
    """:func:`measure_one` into column 0 of ``out`` and ``flags``; a window whose marker reaches the ring
    (cramped) or whose contrast is below MIN_RING_CONTRAST ring σ (the ring on the marker's edge) is
    measured again one step larger on ``ladder`` (ascending half sizes), up to ``retries`` times.
    ``no_signal``: an empty (0, 1, 1) float32 array (allocated once by the caller); ``max_skewness``: the
    skewness noise is computed only above it (where the occlusion test needs it)."""
    measure_one(image, row, col, half_px, dark, scr, out, flags, 0, no_signal, max_skewness)
    size, tries = half_px, 0
    while ((flags[FLAG_ROW_CRAMPED, 0] or out[OUT_CONTRAST, 0] < MIN_RING_CONTRAST * out[OUT_SIGMA, 0])
           and tries < retries and size < ladder[-1]):
        size = ladder[min(int(np.searchsorted(ladder, size, side="right")), len(ladder) - 1)]
        measure_one(image, row, col, size, dark, scratch(size), out, flags, 0, no_signal, max_skewness)
        tries += 1


@jit_kernel
def measure_rows(  # noqa: PLR0917 (numba: no keyword-only arguments)
        image: np.ndarray, rows: np.ndarray, cols: np.ndarray, halves: np.ndarray, dark: bool,
        limits: np.ndarray, ladder: np.ndarray, retries: int, rec: np.ndarray, passed: np.ndarray) -> None:
    """Detection's measurement in one call: the window of half size ``halves[k]`` centred on the integer
    pixel (rows[k], cols[k]) (retried larger as :func:`_measure_retrying`) into row k of ``rec``
    (markers.MARKER_DTYPE) and whether it passes the filters into ``passed[k]`` (``limits`` as in
    :func:`finish_rows`)."""
    out = np.empty((N_OUT, 1))
    flags = np.empty((3, 1), np.bool_)
    no_signal = np.empty((0, 1, 1), np.float32)
    half_px = -1
    scr = scratch(1)
    for k in range(len(rows)):
        if halves[k] != half_px:
            half_px = halves[k]
            scr = scratch(half_px)
        _measure_retrying(image, rows[k], cols[k], half_px, dark, scr, ladder, retries, out, flags,
                          no_signal, limits[0])
        passed[k] = _finish_row(out, flags, 0, limits, rec[k])


@jit_kernel
def track_frame(  # noqa: PLR0917 (numba: no keyword-only arguments)
        image: np.ndarray, pred: np.ndarray, half_px: int, dark: bool, limits: np.ndarray,
        ladder: np.ndarray, retries: int, rec: np.ndarray) -> None:
    """Tracking in one frame, one call: a row of ``rec`` (markers.MARKER_DTYPE, N) per prediction
    ``pred`` (N, 2) (u, v px).

    A prediction inside the frame is measured in the window of half size ``half_px`` centred on its
    rounded position (retried larger as :func:`_measure_retrying`). Rows that fail the filters
    (``limits`` as in :func:`finish_rows`) get u, v NaN and LOST_FLAG added; a prediction that is NaN or
    outside the frame gives a row of NaN with only that flag.
    """
    height, width = image.shape
    out = np.empty((N_OUT, 1))
    flags = np.empty((3, 1), np.bool_)
    no_signal = np.empty((0, 1, 1), np.float32)
    scr = scratch(half_px)
    rows = np.empty(len(pred), np.int64)
    cols = np.empty(len(pred), np.int64)
    for k in range(len(pred)):
        rows[k] = int(np.rint(pred[k, 1])) if np.isfinite(pred[k, 1]) else 0
        cols[k] = int(np.rint(pred[k, 0])) if np.isfinite(pred[k, 0]) else 0
    _touch(image, rows, cols, half_px, scr[12])
    for k in range(len(pred)):
        u, v = pred[k, 0], pred[k, 1]
        row = rec[k]
        if not (u > -0.5 and u < width - 0.5 and v > -0.5 and v < height - 0.5):
            row.u_px, row.v_px, row.area_px = np.nan, np.nan, np.nan
            row.roundness, row.contrast = np.nan, np.nan
            row.flags = LOST_FLAG
            continue
        _measure_retrying(image, rows[k], cols[k], half_px, dark, scr, ladder, retries, out, flags,
                          no_signal, limits[0])
        if not _finish_row(out, flags, 0, limits, row):
            row.u_px, row.v_px = np.nan, np.nan
            row.flags |= LOST_FLAG


@jit_kernel
def finish_rows(  # noqa: PLR0917 (numba: no keyword-only arguments)
        uv: tuple[np.ndarray, np.ndarray], shape: tuple[np.ndarray, np.ndarray, np.ndarray],
        skew: tuple[np.ndarray, np.ndarray], bits: tuple[np.ndarray, np.ndarray], limits: np.ndarray,
        rec: np.ndarray, passed: np.ndarray) -> bool:
    """Output rows (markers.MARKER_DTYPE ``rec``) of measurements without an outline fit, and the filters.

    uv: (u_px, v_px); shape: (area_px, roundness, contrast); skew: (skewness, its noise allowance);
    bits: (border, saturated) bool — arrays of N. ``limits``: max_skewness, skewness noise factor,
    min_area_px, max_area_px, min_roundness, min_contrast. Flags: bit 0 border, bit 1 occluded (skewness
    above max_skewness + factor·noise), bit 2 saturated. ``passed[n]``: a finite centre and area, roundness
    and contrast within the limits. Returns whether all passed.
    """
    all_passed = True
    for n in range(len(rec)):
        row = rec[n]
        row.u_px, row.v_px = uv[0][n], uv[1][n]
        row.area_px, row.roundness, row.contrast = shape[0][n], shape[1][n], shape[2][n]
        occluded = skew[0][n] > limits[0] + limits[1] * skew[1][n]
        row.flags = np.uint8(bits[0][n]) | np.uint8(occluded) << 1 | np.uint8(bits[1][n]) << 2
        ok = (np.isfinite(row.u_px + row.v_px) and limits[2] <= row.area_px <= limits[3]
              and row.roundness >= limits[4] and row.contrast >= limits[5])
        passed[n] = ok
        all_passed = all_passed and ok
    return all_passed
