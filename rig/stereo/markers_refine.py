"""Sub-pixel measurement of markers, batched over square windows of one size.

Every candidate is measured in a square window of ``W = 2·half_px + 1`` pixels around an integer pixel
centre; all windows of one call share one size, so a batch is a few dozen numpy operations on a
``(K, W, W)`` stack, one ``cv2.connectedComponents`` call on a mosaic of the windows and one matrix
product for all the moments — no per-pixel and (except the optional ellipse fit) no per-marker Python.

Per window, in "polarity space" (bright markers as they are, dark markers as 255 − I):

* background ``bg`` = a plane fitted to the outer 2-pixel ring (pixels more than 4 robust spreads from
  its median left out), noise ``σ`` = RMS residual of that fit (:mod:`rig.stereo.markers_background`);
* signal ``d = I − bg``; support = the 8-connected region of ``d > 3σ`` holding the marker (the centre
  pixel's region, else the strong region nearest the centre), so a neighbouring marker is ignored;
* centroid weights ``w = d − 3σ`` on the support (background-subtracted intensity with a noise floor:
  an unclipped ``max(d, 0)`` over the window would add ≈ 0.4 σ of mass per background pixel and pull
  the centre towards the window's centre);
* contrast = the plateau of ``d``: its mean over the pixels above 85 % of the peak (DN);
  area = Σ w / (contrast − 3σ) (px², exact for a flat disc, and nearly so for a blurred one: only the
  skirt below 3σ is missed);
  roundness = √(λmin/λmax) of the weighted second moments (1 for a disc, minor/major axis ratio for
  an ellipse);
* skewness = squared third central moments over det(Σ)^(3/2) (Mardia's b1 for a round blob): 0 for any
  centrally symmetric blob — a disc, an ellipse, a disc seen obliquely — and large for a disc with a
  piece missing;
* optionally, sub-pixel edge points where ``d`` crosses contrast/2 (linear interpolation between pixel
  centres) fitted with an ellipse (``cv2.fitEllipseDirect``): its centre, and the RMS distance of the
  points from it (a few hundredths of a pixel for a whole disc) (:mod:`rig.stereo.markers_outline`).

Coordinates: pixel centres are integers, the centre of the top-left pixel is (0, 0); u = column, v = row.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from rig.stereo.markers_background import RING_PX, matmul_one_thread, ring_background
from rig.stereo.markers_outline import edge_points, fit_ellipses

#: one frame (2-D uint8), or frames (a sequence, or a 3-D stack) addressed by a frame index per window
Images = np.ndarray | Sequence[np.ndarray]

NOISE_FLOOR_K = 3.0  # support and weight threshold, in units of the window's background noise σ
PLATEAU_LEVEL = 0.85  # contrast = mean signal of the support pixels above this fraction of the peak


@dataclass
class Measured:
    """Per-window measurements (arrays of length K); NaN where a window held no marker."""

    u_px: np.ndarray
    v_px: np.ndarray
    area_px: np.ndarray
    roundness: np.ndarray
    contrast: np.ndarray
    background: np.ndarray  # DN at the window's centre pixel, polarity space
    sigma: np.ndarray  # background noise, DN
    skewness: np.ndarray  # third-moment asymmetry of the weights (0 for a centrally symmetric blob)
    u_ellipse_px: np.ndarray  # centre of the ellipse fitted to the outline (NaN unless fitted)
    v_ellipse_px: np.ndarray
    edge_rms_px: np.ndarray  # RMS distance of the outline points from that ellipse
    edge_noise_px: np.ndarray  # the part of edge_rms_px that the background noise σ explains
    skewness_noise: np.ndarray  # expected skewness of a whole disc from noise: 8σ²/(contrast²·area)
    border: np.ndarray  # bool: the window reaches outside the image
    saturated: np.ndarray  # bool: a support pixel is clipped (255 bright / 0 dark)
    cramped: np.ndarray  # bool: the support reaches the background ring (the window is too small)

    @classmethod
    def empty(cls) -> Measured:
        """Measurements of no window (all arrays of length 0)."""
        flags = ("border", "saturated", "cramped")
        return cls(**{key: np.zeros(0, dtype=bool if key in flags else float)
                      for key in cls.__dataclass_fields__})


@dataclass(frozen=True)
class _Geometry:
    """Constant arrays of one window size (cached): coordinates are offsets from the window's centre."""

    moments: np.ndarray  # (W², 11) float32: 1, x, y, x², xy, y², x³, x²y, xy², y³, ring's inner edge
    plane: np.ndarray  # (3, W²) float32: 1, x, y
    dist2: np.ndarray  # (W, W) squared distance from the centre
    ones: np.ndarray  # (W²,) float32 ones (row sums as dot products, cheaper than a reduction)


_GEOMETRY: dict[int, _Geometry] = {}


def _geometry(half_px: int) -> _Geometry:
    if half_px not in _GEOMETRY:
        w = 2 * half_px + 1
        y, x = np.mgrid[-half_px : half_px + 1, -half_px : half_px + 1].astype(np.float64)
        x, y = x.ravel(), y.ravel()
        # the ring's inner edge: a marker's support, connected to the centre, reaches the ring only here
        edge = np.zeros((w, w))
        edge[[RING_PX - 1, w - RING_PX], RING_PX - 1 : w - RING_PX + 1] = 1.0
        edge[RING_PX - 1 : w - RING_PX + 1, [RING_PX - 1, w - RING_PX]] = 1.0
        moments = np.stack([np.ones_like(x), x, y, x * x, x * y, y * y, x**3, x * x * y, x * y * y, y**3,
                            edge.ravel()], 1)
        _GEOMETRY[half_px] = _Geometry(moments=moments.astype(np.float32),
                                       plane=moments[:, :3].T.astype(np.float32),
                                       dist2=(x * x + y * y).reshape(w, w),
                                       ones=np.ones(w * w, dtype=np.float32))
    return _GEOMETRY[half_px]


def gather_frames(images: Images, frame: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                  half_px: int) -> tuple[np.ndarray, np.ndarray | None]:
    """:func:`gather_windows` of windows in several frames: window i lies in ``images[frame[i]]``.

    ``frame`` must be non-decreasing (windows grouped by frame); one gather per frame.
    """
    if frame[0] == frame[-1]:
        return gather_windows(images[int(frame[0])], rows, cols, half_px)
    w = 2 * half_px + 1
    stack = np.empty((len(rows), w, w), dtype=np.uint8)
    valid: np.ndarray | None = None
    bounds = np.flatnonzero(np.diff(frame)) + 1
    for lo, hi in zip(np.r_[0, bounds], np.r_[bounds, len(rows)], strict=True):
        _, part_valid = gather_windows(images[int(frame[lo])], rows[lo:hi], cols[lo:hi], half_px,
                                          out=stack[lo:hi])
        if part_valid is not None:
            if valid is None:
                valid = np.ones(stack.shape, dtype=bool)
            valid[lo:hi] = part_valid
    return stack, valid


def gather_windows(image: np.ndarray, rows: np.ndarray, cols: np.ndarray, half_px: int,
                   out: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Stack the windows centred on integer ``(rows, cols)``: (uint8 (K, W, W), valid bool (K, W, W) | None).

    Out-of-image pixels repeat the nearest edge pixel and are False in ``valid`` (None when every window
    lies inside the image). ``out``: write the stack there (then it is returned).
    """
    height, width = image.shape
    w = 2 * half_px + 1
    fits = height >= w and width >= w
    if fits:
        # every w×w window of the image, indexed by its top-left pixel (a read-only view, no copy)
        shape = (height - w + 1, width - w + 1, w, w)
        if image.flags.c_contiguous:  # the direct constructor costs a tenth of as_strided's overhead
            views = np.ndarray(shape, np.uint8, image, 0, image.strides * 2)
            views.flags.writeable = False
        else:
            views = np.lib.stride_tricks.as_strided(image, shape, image.strides * 2, writeable=False)
        if (len(rows) and rows.min() >= half_px and rows.max() < height - half_px
                and cols.min() >= half_px and cols.max() < width - half_px):
            if out is None:
                return views[rows - half_px, cols - half_px], None  # the usual case: all inside
            out[...] = views[rows - half_px, cols - half_px]
            return out, None
    inside = (rows >= half_px) & (rows < height - half_px) & (cols >= half_px) & (cols < width - half_px)
    stack = np.empty((len(rows), w, w), dtype=np.uint8) if out is None else out
    if fits:
        stack[inside] = views[rows[inside] - half_px, cols[inside] - half_px]
    if inside.all():
        return stack, None
    offsets = np.arange(-half_px, half_px + 1)
    out = ~inside
    r = rows[out, None] + offsets
    c = cols[out, None] + offsets
    stack[out] = image[np.clip(r, 0, height - 1)[:, :, None], np.clip(c, 0, width - 1)[:, None, :]]
    valid = np.ones(stack.shape, dtype=bool)
    valid[out] = ((r >= 0) & (r < height))[:, :, None] & ((c >= 0) & (c < width))[:, None, :]
    return stack, valid


def _select_support(strong: np.ndarray, d: np.ndarray, half_px: int, dist2: np.ndarray) -> np.ndarray:
    """The connected region of ``strong`` (K, W, W) that holds each window's marker, as a bool stack.

    One ``cv2.connectedComponents`` call labels the windows stacked into one tall image. Windows touch
    there, but a region can only cross into the next window through its first/last row — the ring, which
    a marker's region reaches only when its window is too small (then it is measured again, larger).
    """
    k, w, _ = strong.shape
    # 16-bit labels (half the memory traffic) while the count of 8-connected regions, at most one per
    # 2×2 block of the stacked image, fits them
    ltype = cv2.CV_16U if (k * w + 1) * (w + 1) <= 4 * 65_535 else cv2.CV_32S
    _, labels = cv2.connectedComponentsWithAlgorithm(strong.view(np.uint8).reshape(k * w, w), 8, ltype,
                                                     cv2.CCL_BBDT)
    labels = labels.reshape(k, w, w)
    own = labels[:, half_px, half_px].copy()
    if own.all():  # the usual case: every window's centre pixel lies on its marker
        mine: np.ndarray = labels == own[:, None, None]
        return mine
    missing = np.nonzero(own == 0)[0]
    # centre pixel is background: the region of the strong pixel nearest the centre, among pixels
    # at least half as strong as the window's strongest (so noise specks are never chosen)
    sub_d = d[missing]
    peak = sub_d.reshape(len(missing), -1).max(axis=1)
    bright = (sub_d >= 0.5 * peak[:, None, None]) & strong[missing]
    score = np.where(bright, dist2[None], np.inf).reshape(len(missing), -1)
    best = score.argmin(axis=1)
    own[missing] = labels[missing].reshape(len(missing), -1)[np.arange(len(missing)), best]
    support: np.ndarray = (labels == own[:, None, None]) & (own[:, None, None] != 0)
    return support


def _moment_shape(raw_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Centroid offsets, roundness and skewness from raw moments (K, 10) of (1, x, y, xx, xy, yy, xxx, ...).

    skewness = (μ30² + 3μ21² + 3μ12² + μ03²) / det(Σ)^(3/2) from the central moments: Mardia's b1 for a
    round blob, 0 for every centrally symmetric one. Called under measure_windows' np.errstate (empty
    windows give NaN). Works on contiguous rows (one per moment), the cheapest layout for short arrays.
    """
    mx, my, exx, exy, eyy, exxx, exxy, exyy, eyyy = (raw_m[:, 1:10] / raw_m[:, :1]).T.copy()
    mx2, my2 = mx * mx, my * my
    cxx = exx - mx2
    cxy = exy - mx * my
    cyy = eyy - my2
    det = cxx * cyy - cxy * cxy
    half_trace = 0.5 * (cxx + cyy)
    root = np.sqrt(np.maximum(half_trace * half_trace - det, 0.0))
    roundness = np.sqrt(np.maximum(half_trace - root, 0.0) / (half_trace + root))
    # third central moments: μ30 = E[x³] − a(3·cxx + a²), μ21 = E[x²y] − b(cxx + a²) − 2a·cxy, ...
    c30 = exxx - mx * (3.0 * cxx + mx2)
    c03 = eyyy - my * (3.0 * cyy + my2)
    c21 = exxy - my * (cxx + mx2) - 2.0 * mx * cxy
    c12 = exyy - mx * (cyy + my2) - 2.0 * my * cxy
    skew = (c30 * c30 + c03 * c03 + 3.0 * (c21 * c21 + c12 * c12)) / det**1.5
    return mx, my, roundness, skew


@np.errstate(invalid="ignore", divide="ignore")
def measure_windows(image: Images, rows: np.ndarray, cols: np.ndarray, half_px: int, *,
                    dark: bool, fit_ellipse: bool = False, frame: np.ndarray | None = None) -> Measured:
    """Measure the marker in each window centred on the integer pixel ``(rows[i], cols[i])``.

    ``image``: uint8 frame, or with ``frame`` (non-decreasing indices, one per window) a sequence of
    frames, window i lying in ``image[frame[i]]``; ``dark``: dark markers on a bright background;
    ``fit_ellipse``: also fit the outline (``u_ellipse_px``, ``v_ellipse_px``, ``edge_rms_px``; NaN
    otherwise). Windows without any support above the noise floor give NaN measurements.
    """
    n = len(rows)
    if n == 0:
        return Measured.empty()
    w = 2 * half_px + 1
    geo = _geometry(half_px)
    if frame is None:
        raw, valid = gather_windows(np.asarray(image), rows, cols, half_px)
    else:
        raw, valid = gather_frames(image, frame, rows, cols, half_px)
    if dark:
        raw = np.subtract(255, raw, dtype=np.uint8)
    flat = raw.reshape(n, w * w)
    coef, sigma = ring_background(flat, None if valid is None else valid.reshape(n, -1), half_px)
    floor = NOISE_FLOOR_K * sigma
    shifted = coef.copy()
    shifted[:, 0] += floor
    # signal above background plane + noise floor: > 0 on the marker's support
    weights = matmul_one_thread(shifted, geo.plane)
    np.subtract(flat, weights, out=weights)
    if valid is not None:
        weights *= valid.reshape(n, -1)
    grid = weights.reshape(n, w, w)
    support = _select_support(grid > 0, grid, half_px, geo.dist2).reshape(n, -1)
    weights *= support
    raw_m = matmul_one_thread(weights, geo.moments).astype(np.float64)
    du, dv, roundness, skew = _moment_shape(raw_m[:, :10])  # NaN for empty windows (0/0)
    # contrast: the plateau, i.e. the mean signal of the pixels above 85 % of the peak (the peak alone,
    # a maximum of N noisy pixels, would be biased up by ≈ σ·√(2 ln N)); area: the integrated signal
    # above the floor over the plateau above it (exact for a flat disc, nearly so for a blurred one:
    # only its skirt below the floor, 3σ ≪ contrast, is left out)
    top = (weights >= (PLATEAU_LEVEL * weights.max(axis=1))[:, None]).astype(np.float32)
    peak = (np.vecdot(weights, top) / np.vecdot(top, geo.ones)).astype(np.float64)
    contrast = np.where(raw_m[:, 0] > 0, peak + floor, np.nan)
    area = raw_m[:, 0] / peak
    saturated = (support & (flat == 255)).any(axis=1) if raw.max() == 255 else np.zeros(n, bool)
    cramped = raw_m[:, 10] > 0  # weight on the ring's inner edge: the marker reaches the ring
    border = np.zeros(n, dtype=bool) if valid is None else np.logical_not(valid.all(axis=(1, 2)))

    u_e, v_e, edge_rms, edge_noise = np.full((4, n), np.nan)
    if fit_ellipse and n:
        level = np.where(np.isfinite(contrast), 0.5 * contrast, np.inf).astype(np.float32)
        signal = (weights + floor[:, None] * support).reshape(n, w, w)  # d on the support, 0 elsewhere
        centre, edge_rms, edge_noise = fit_ellipses(*edge_points(signal, level), n)
        edge_noise *= sigma
        u_e = cols + centre[:, 0] - half_px
        v_e = rows + centre[:, 1] - half_px

    sigma = sigma.astype(np.float64)
    return Measured(
        u_px=cols + du, v_px=rows + dv, area_px=area, roundness=roundness, contrast=contrast,
        background=coef[:, 0].astype(np.float64), sigma=sigma, skewness=skew,
        u_ellipse_px=u_e, v_ellipse_px=v_e, edge_rms_px=edge_rms,
        edge_noise_px=edge_noise, skewness_noise=8.0 * sigma**2 / (contrast**2 * area),
        border=border, saturated=saturated, cramped=cramped,
    )
