"""Circular markers in 8-bit frames: detection (binarization + region-of-interest filter) and tracking.

:func:`detect_markers` follows the paper's two steps — binarize the frame, keep the blobs inside the
regions of interest — and measures each marker with a sub-pixel centre. For speed the binarization
runs on the frame reduced ×2 or ×4 (chosen from ``min_area_px``; :mod:`rig.stereo.markers_binarize`);
each candidate is then measured at full resolution in a small window (:mod:`rig.stereo.markers_refine`;
a window that turns out too small for its marker is measured again, larger). :func:`track_markers` skips the
full-frame search: it measures only windows around predicted positions (the speed mode for
sequences: all windows of a frame in one compiled call). Both measure a marker with
the same pixels and weights; they differ only through the
background plane fitted to the ring of their (differently placed) windows — by less than the
centroid's own noise (tests/test_stereo_markers.py). Both take ``threads``: one frame's work split over
that many threads (:mod:`rig.stereo.markers_threads`: the binarization in row bands, the windows in
parts), with the result of one thread bit for bit; 1 (default) where each camera already has a core.

Results are structured arrays of :data:`MARKER_DTYPE`, one row per marker: ``u_px`` (column) and
``v_px`` (row) with the centre of the top-left pixel at (0, 0); ``area_px`` (px², integrated signal
over contrast); ``roundness`` (minor/major axis ratio from second moments, 1 for a disc);
``contrast`` (DN above the local background, positive for either polarity); ``flags`` (bit set of
``FLAG_*``). A frame without markers gives an empty array (length 0), not an error, unless the caller
passes ``require=True``; then :class:`~rig.stereo.errors.NoMarkersError` is raised.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from rig.stereo.errors import InputArrayError, NoMarkersError
from rig.stereo.markers_binarize import find_candidates
from rig.stereo.markers_refine import Measured, measure_windows
from rig.stereo.markers_roi import inside_any, parse_roi, roi_bounds
from rig.stereo.markers_threads import check_threads, run_parts, split

MARKER_DTYPE = np.dtype([("u_px", "f8"), ("v_px", "f8"), ("area_px", "f8"), ("roundness", "f8"),
                         ("contrast", "f8"), ("flags", "u1")])
FLAG_BORDER = 1  # the measuring window reaches outside the image: the centre may be biased
FLAG_OCCLUDED = 2  # partly hidden: the blob is not centrally symmetric, or its outline is not an ellipse
FLAG_SATURATED = 4  # a marker pixel is clipped (255 for bright markers, 0 for dark ones)
FLAG_LOST = 8  # tracking only: no marker passing the filters in the window (u_px, v_px are NaN)

# Occlusion tests (defaults). A whole disc or ellipse is centrally symmetric: its skewness (third
# moments, see markers_refine) is ~0 and its half-contrast outline lies within a few hundredths of a
# pixel of the fitted ellipse. A marker with a piece hidden is asymmetric and its outline has a chord or
# a corner. Both tests allow for noise: skewness > MAX_SKEWNESS + SKEW_NOISE_FACTOR·skewness_noise and
# outline RMS² > MAX_EDGE_RMS_PX² + (EDGE_NOISE_FACTOR·noise RMS)².
# skewness_noise = σ²·Σ_support(f30² + f03² + 3f21² + 3f12²) / (m0²·det(Σ)^(3/2)), the skewness that pixel
# noise σ gives a whole marker, to first order (markers_kernel._run_skew_terms: f_pq is how far one pixel's
# weight moves m0·μ_pq; m0 = Σw, Σ the weighted covariance). Every support pixel counts with its full σ,
# however small its weight: on a small blurred marker the skirt dominates. The former allowance,
# 8σ²/(contrast²·area), is that sum for a flat disc of full-contrast weights: 5–23× too small on small
# blurred markers (r 3 px, contrast 30, σ 2, blur 2 px: skewness 14× it on average; 17 of 1,000 whole
# markers flagged). Skewness / skewness_noise where noise dominates (blur ≥ 0.5 px, contrast/σ ≤ 15,
# 27,000 rendered draws): mean 0.9, 99.99th percentile 9, largest 13.6 — below 0.6 of a factor 25.
# The pixel grid skews a sharp marker that is narrow across by itself (unblurred, contrast/σ 100: 0.03 at
# a minor semi-axis b of 1.5 px, 0.009 at 2 px, 0.001 at 3 px), which no noise allowance covers; hence
# the domain: r 2.5–30 px, ellipses to 2:1, blur ≤ 2.5 px, contrast/σ 7–400, and √(b²/4 + blur²) ≥ 1.1 px
# (a disc of r ≥ 2.2 px at any blur; a 2:1 ellipse of r 2.5 px from blur 0.92 px). There, over 180,000
# rendered draws, whole markers reach at most 0.58 of the skewness limit (the former allowance flagged
# 182, up to 2.8× its limit); outside it up to 2× (r 3 px 2:1, blur 0.3 px, contrast/σ 400). A disc of
# r ≥ 8 px, contrast/σ 75, with 30 % of its radius cut off by a straight edge exceeds the limit ≥ 4× (its
# noise allowance < 10⁻³: MAX_SKEWNESS decides); small faint blurred ones are flagged less often than with
# the former allowance (r 5 px, contrast 40, blur 1.5, σ 2, 30 % cut: 0 of 40, was 29), being within the
# noise. The outline limit (outline_check; holes inside the marker are not outline, markers_outline): over
# 35,668 whole markers rendered across the domain (frames 2·(2r + 4·blur + 12) px), edge RMS / limit has
# median 0.11, 99.9th percentile 0.37 and largest 0.70 (r 5 px, blur 2.4 px, contrast/σ 8.6).
# Found exactly once by detect_markers (default options) across the domain, when their peak and area are
# ≥ 1.5× min_contrast and min_area_px: all but 43 of 49,672 draws (on such frames and on 128 px ones),
# never twice, no centre beyond 5√2 σ_c of the truth; 37 of the 43 are ellipses of axis ratio < 0.52 at
# the min_roundness gate (see detect_markers), 6 discs of r < 4.5 px, blur ≥ 0.6 px whose measured
# contrast or area fell below the filters (the blur lowers the plateau, the 3σ floor drops the skirt).
MAX_SKEWNESS = 0.01
SKEW_NOISE_FACTOR = 25.0
MAX_EDGE_RMS_PX = 0.15
EDGE_NOISE_FACTOR = 3.0

_HALF_LADDER = np.array([6, 8, 10, 12, 14, 16, 20, 24, 28, 32, 40, 48, 56, 64, 80, 96, 112, 128,
                         160, 192, 224, 256])
_CENTRES = ("centroid", "ellipse")
_UINT8 = np.dtype(np.uint8)
_FLOAT64 = np.dtype(np.float64)
_POLARITIES = ("bright", "dark")


def check_gray(gray: object, name: str = "gray") -> np.ndarray:
    """Return ``gray`` if it is a non-empty 2-D uint8 array, else raise InputArrayError saying why."""
    if not isinstance(gray, np.ndarray):
        raise InputArrayError(f"{name} must be a numpy array (2-D uint8 grayscale frame), got {type(gray)!r}")
    if gray.dtype != _UINT8:
        raise InputArrayError(
            f"{name} has dtype {gray.dtype}; markers are found in 8-bit grayscale frames: convert with "
            f"e.g. cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY) or np.clip(x, 0, 255).astype(np.uint8)"
        )
    if gray.ndim != 2:
        raise InputArrayError(
            f"{name} has shape {gray.shape}; give one 2-D (rows, columns) grayscale frame (convert colour "
            f"frames with cv2.cvtColor)"
        )
    if gray.shape[0] < 8 or gray.shape[1] < 8:
        raise InputArrayError(f"{name} has shape {gray.shape}; a frame must be at least 8×8 pixels")
    return gray


def _check_options(polarity: str, centre: str, *, min_area_px: float, max_area_px: float,
                   min_roundness: float, min_contrast: float) -> None:
    if polarity not in _POLARITIES:
        raise InputArrayError(f"polarity={polarity!r}; use 'bright' (light markers on dark) or 'dark'")
    if centre not in _CENTRES:
        raise InputArrayError(f"centre={centre!r}; use 'centroid' or 'ellipse'")
    if not (0 < min_area_px <= max_area_px):
        raise InputArrayError(
            f"min_area_px={min_area_px}, max_area_px={max_area_px}; need 0 < min_area_px <= max_area_px (px²)"
        )
    if not (0 <= min_roundness <= 1):
        raise InputArrayError(f"min_roundness={min_roundness}; must be in [0, 1] (1 = perfect disc)")
    if not (min_contrast > 0):
        raise InputArrayError(f"min_contrast={min_contrast}; must be > 0 DN")


def _ladder(half_px: np.ndarray) -> np.ndarray:
    idx = np.minimum(np.searchsorted(_HALF_LADDER, half_px), len(_HALF_LADDER) - 1)
    return _HALF_LADDER[idx]


# windows per thread at least: handing a part to another thread costs about as much as measuring this many
WINDOWS_PER_THREAD = 4
MERGE_PIXELS = 40_000  # extra window pixels that cost about as much as one more batch call


def _merge_sizes(sizes: np.ndarray) -> np.ndarray:
    """Grow small windows to the next size in use when that is cheaper than a separate batch."""
    every = np.bincount(sizes)  # sizes ≤ 256 (the ladder): one pass, no sort
    values = np.flatnonzero(every).tolist()
    if len(values) <= 1:  # the usual case: one size (or none)
        return sizes
    counts = every[values].tolist()
    target = list(values)  # the size each size grows to (Python ints: a few windows, a few sizes)
    for i in range(len(values) - 1):
        small, large = values[i], values[i + 1]
        if counts[i] * ((2 * large + 1) ** 2 - (2 * small + 1) ** 2) < MERGE_PIXELS:
            counts[i + 1] += counts[i]
            for k in range(i + 1):  # every size grown to this one grows on with it
                if target[k] == small:
                    target[k] = large
    lookup = np.zeros(len(every), dtype=sizes.dtype)
    lookup[values] = target
    merged: np.ndarray = lookup[sizes]
    return merged


def _measure(gray: np.ndarray, rows: np.ndarray, cols: np.ndarray, half: np.ndarray, *, dark: bool,
             fit_ellipse: bool = False, retries: int = 2, exact: bool = False) -> Measured:
    """Measure windows of several sizes (grouped on the size ladder); Measured for all, in input order.

    A window whose marker reaches the background ring is measured again one ladder step larger (up to
    ``retries`` times), so a first size guess that is too small costs time, not accuracy. ``exact``:
    use the given half sizes for the first attempt instead of rounding them up to the ladder.
    """
    sizes = np.asarray(half, dtype=np.int64).copy() if exact else _merge_sizes(_ladder(half))
    if len(sizes) == 0:
        return Measured.empty()
    groups = sizes[:1] if sizes.min() == sizes.max() else np.unique(sizes)
    if len(groups) == 1:  # the usual case: one batch
        result = measure_windows(gray, rows, cols, int(groups[0]), dark=dark, fit_ellipse=fit_ellipse)
    else:
        parts: Measured | None = None
        for size in groups:
            sel = np.nonzero(sizes == size)[0]
            part = measure_windows(gray, rows[sel], cols[sel], int(size), dark=dark, fit_ellipse=fit_ellipse)
            parts = _scatter(parts, len(rows), sel, part)
        assert parts is not None  # len(groups) > 1
        result = parts
    return _retry_cramped(gray, rows, cols, sizes, result, dark=dark, fit_ellipse=fit_ellipse,
                          retries=retries)


def _retry_cramped(gray: np.ndarray, rows: np.ndarray, cols: np.ndarray, sizes: np.ndarray,
                   result: Measured, *, dark: bool, fit_ellipse: bool, retries: int) -> Measured:
    """Measure the windows of ``result`` that are too small for their marker again, one ladder step larger:
    the marker reaches the ring, or the ring lies on its edge (markers_kernel.MIN_RING_CONTRAST)."""
    if retries > 0 and len(rows):
        from rig.stereo.markers_kernel import MIN_RING_CONTRAST  # loaded by the measurement already

        with np.errstate(invalid="ignore"):  # NaN contrast (no marker): not too small
            small = result.cramped | (result.contrast < MIN_RING_CONTRAST * result.sigma)
        again = np.nonzero(small & (sizes < _HALF_LADDER[-1]))[0]
        if len(again):
            bigger = _HALF_LADDER[np.minimum(np.searchsorted(_HALF_LADDER, sizes[again], side="right"),
                                             len(_HALF_LADDER) - 1)]
            part = _measure(gray, rows[again], cols[again], bigger, dark=dark, fit_ellipse=fit_ellipse,
                            retries=retries - 1, exact=True)
            result = _scatter(result, len(rows), again, part)
    return result


def _scatter(dst: Measured | None, n: int, sel: np.ndarray, src: Measured) -> Measured:
    """Write the rows ``sel`` of ``dst`` from ``src``; a new ``dst`` of length n (uninitialized) if None."""
    if dst is None:
        dst = Measured(**{key: np.empty(n, dtype=value.dtype) for key, value in vars(src).items()})
    for key, value in vars(src).items():
        getattr(dst, key)[sel] = value
    return dst


def _rows_from(m: Measured, centre: str, max_edge_rms_px: float, max_skewness: float,
               fitted: bool) -> np.ndarray:
    """Output rows from measurements; ``fitted``: the outline was fitted (else its fields are all NaN).

    Called under np.errstate(invalid="ignore") (NaN measurements compare False)."""
    out = np.empty(len(m.u_px), dtype=MARKER_DTYPE)
    if centre == "ellipse" and fitted:
        use_ellipse = np.isfinite(m.u_ellipse_px)
        out["u_px"] = np.where(use_ellipse, m.u_ellipse_px, m.u_px)
        out["v_px"] = np.where(use_ellipse, m.v_ellipse_px, m.v_px)
    else:
        out["u_px"] = m.u_px
        out["v_px"] = m.v_px
    out["area_px"] = m.area_px
    out["roundness"] = m.roundness
    out["contrast"] = m.contrast
    occluded = m.skewness > max_skewness + SKEW_NOISE_FACTOR * m.skewness_noise
    if fitted:
        edge_limit2 = max_edge_rms_px**2 + (EDGE_NOISE_FACTOR * m.edge_noise_px) ** 2
        occluded |= m.edge_rms_px**2 > edge_limit2
    # bits 0, 1, 2 in one call: FLAG_BORDER, FLAG_OCCLUDED, FLAG_SATURATED
    out["flags"] = np.packbits(np.stack([m.border, occluded, m.saturated], axis=1), axis=1,
                               bitorder="little")[:, 0]
    return out


def _rows_passed(m: Measured, centre: str, max_edge_rms_px: float, max_skewness: float, *, fitted: bool,
                 limits: tuple[float, float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Output rows (:func:`_rows_from`) and the filters (:func:`_passes`); ``limits``: min_area_px,
    max_area_px, min_roundness, min_contrast. Without an outline fit, one compiled call."""
    if fitted:
        with np.errstate(invalid="ignore"):
            rec = _rows_from(m, centre, max_edge_rms_px, max_skewness, fitted)
            return rec, _passes(rec, *limits)
    from rig.stereo.markers_kernel import finish_rows  # numba: loaded by the first measurement

    rec = np.empty(len(m.u_px), dtype=MARKER_DTYPE)
    passed = np.empty(len(m.u_px), dtype=bool)
    finish_rows((m.u_px, m.v_px), (m.area_px, m.roundness, m.contrast), (m.skewness, m.skewness_noise),
                (m.border, m.saturated), np.array([max_skewness, SKEW_NOISE_FACTOR, *limits]), rec, passed)
    return rec, passed


def _passes(rec: np.ndarray, min_area_px: float, max_area_px: float, min_roundness: float,
            min_contrast: float) -> np.ndarray:
    """Rows with a finite centre whose area, roundness and contrast pass the filters (bool mask)."""
    ok: np.ndarray = (np.isfinite(rec["u_px"] + rec["v_px"])
            & (rec["area_px"] >= min_area_px) & (rec["area_px"] <= max_area_px)
            & (rec["roundness"] >= min_roundness) & (rec["contrast"] >= min_contrast))
    return ok


def detect_markers(
    gray: np.ndarray,
    *,
    polarity: str = "bright",
    threshold: float | str | None = None,
    min_area_px: float = 20.0,
    max_area_px: float = 20000.0,
    min_roundness: float = 0.5,
    min_contrast: float = 20.0,
    roi: Sequence[object] | np.ndarray | None = None,
    centre: str = "centroid",
    downsample: int | None = None,
    max_skewness: float = MAX_SKEWNESS,
    outline_check: bool = False,
    max_edge_rms_px: float = MAX_EDGE_RMS_PX,
    require: bool = False,
    threads: int = 1,
) -> np.ndarray:
    """Find circular markers in a uint8 frame; one :data:`MARKER_DTYPE` row per marker, sorted by (v, u).

    polarity: "bright" (light markers on a dark background) or "dark" (the inverse).
    threshold: binarization level. None (default): local — a pixel is foreground when it exceeds the mean
        of its neighbourhood (3 marker diameters wide) by max(min_contrast/2, 4σ of the noise); "otsu":
        Otsu's global level; a number: a fixed level in DN of the raw frame (foreground above it for
        bright markers, below it for dark ones).
    min_area_px, max_area_px: marker area limits in px² (area = integrated signal / contrast).
    min_roundness: minimum minor/major axis ratio (0..1); 0.5 accepts discs seen up to 60° off-axis, but
        a 2:1 ellipse (60°) measures 0.500 ± 0.001 when sharp: unblurred at r 10–30 px, or at blur 0.5 px
        and r 20–30 px, 6–19 of 20 were rejected, while an axis ratio of 0.52 (58°), or blur ≥ 1 px,
        passed in every draw (noise σ 2, contrast 100); pass 0.45 to keep every 2:1 ellipse.
    min_contrast: minimum marker contrast above the local background, DN.
    roi: regions of interest, a list of rectangles (x0, y0, x1, y1) and/or polygons [(x, y), ...]; a
        marker is kept when its centre lies in any of them. Only their bounding box is searched.
    centre: "centroid" (background-subtracted intensity-weighted centroid, default) or "ellipse" (centre of
        an ellipse fitted to the sub-pixel half-contrast outline; falls back to the centroid for markers
        with fewer than 6 edge points).
    downsample: 1, 2 or 4, the reduction of the frame for binarization; None picks the largest that keeps
        a marker of ``min_area_px`` at ≥ 5 reduced pixels.
    max_skewness, outline_check, max_edge_rms_px: the occlusion tests (module constants explain them):
        a marker is FLAG_OCCLUDED when its skewness exceeds max_skewness (plus a noise allowance) or,
        when its outline is fitted (centre="ellipse" or outline_check=True, slower), when the outline's
        RMS distance from the fitted ellipse exceeds max_edge_rms_px (plus a noise allowance).
    require: raise NoMarkersError instead of returning an empty array when nothing is found.
    threads: threads one frame's work is split over (1 … 64; the same result for any): 1 where each
        camera already has a core (two cameras reduced in parallel), more to cut one frame's wall time.

    Raises InputArrayError for a frame that is not a non-empty 2-D uint8 array or for invalid options.
    """
    gray = check_gray(gray)
    _check_options(polarity, centre, min_area_px=min_area_px, max_area_px=max_area_px,
                   min_roundness=min_roundness, min_contrast=min_contrast)
    factor = _binarize_factor(threshold, downsample, min_area_px)
    threads = check_threads(threads)
    dark = polarity == "dark"
    regions = None if roi is None else parse_roi(roi)
    area = _search_area(gray, regions, max_area_px)
    if area is None:
        return _none_found(require, "the regions of interest lie outside the frame")
    r_off, c_off, search = area
    rows, cols, half = find_candidates(search, dark=dark, threshold=threshold, factor=factor,
                                       min_area_px=min_area_px, max_area_px=max_area_px,
                                       min_contrast=min_contrast, min_roundness=min_roundness,
                                       threads=threads)
    fit = centre == "ellipse" or outline_check
    limits = (min_area_px, max_area_px, min_roundness, min_contrast)
    if fit:
        measured = _measure_candidates(gray, rows + r_off, cols + c_off, half, dark=dark, fit=fit)
        rec, passed = _rows_passed(measured, centre, max_edge_rms_px, max_skewness, fitted=fit, limits=limits)
    else:
        rec, passed = _detect_compiled(gray, rows + r_off, cols + c_off, half, dark=dark,
                                       limits=np.array([max_skewness, SKEW_NOISE_FACTOR, *limits]),
                                       threads=threads)
    rec = rec[passed]
    if regions is not None and len(rec):
        rec = rec[inside_any(rec["u_px"], rec["v_px"], regions)]
    if len(rec) == 0:
        return _none_found(require, "no blob passed the area, roundness and contrast filters")
    return _drop_duplicates(rec)


def _binarize_factor(threshold: float | str | None, downsample: int | None, min_area_px: float) -> int:
    """The reduction (1, 2, 4) of the frame for binarization; InputArrayError names a bad option."""
    if isinstance(threshold, str) and threshold != "otsu":
        raise InputArrayError(f"threshold={threshold!r}; use None (local), 'otsu' or a level in DN (0..255)")
    if threshold is not None and not isinstance(threshold, str) and not (0 <= float(threshold) <= 255):
        raise InputArrayError(f"threshold={threshold}; a fixed level must be within 0..255 DN")
    if downsample is None:  # the largest that keeps a marker of min_area_px at ≥ 5 reduced pixels
        return 4 if min_area_px / 16 >= 5 else 2 if min_area_px / 4 >= 5 else 1
    if downsample in (1, 2, 4):
        return int(downsample)
    raise InputArrayError(f"downsample={downsample!r}; use 1, 2, 4 or None (automatic)")


def _search_area(gray: np.ndarray, regions: list[np.ndarray] | None,
                 max_area_px: float) -> tuple[int, int, np.ndarray] | None:
    """(row offset, column offset, view) of the part of ``gray`` to binarize: the bounding box of the
    regions with a margin of a marker radius + 8 px (the whole frame without regions); None when the
    regions lie outside the frame."""
    if regions is None:
        return 0, 0, gray
    x0, y0, x1, y1 = roi_bounds(regions)
    margin = int(np.ceil(np.sqrt(max_area_px / np.pi))) + 8
    c_off, r_off = max(int(np.floor(x0)) - margin, 0), max(int(np.floor(y0)) - margin, 0)
    c_end = min(int(np.ceil(x1)) + margin + 1, gray.shape[1])
    r_end = min(int(np.ceil(y1)) + margin + 1, gray.shape[0])
    if c_end - c_off < 8 or r_end - r_off < 8:
        return None
    return r_off, c_off, gray[r_off:r_end, c_off:c_end]


def _measure_candidates(gray: np.ndarray, rows: np.ndarray, cols: np.ndarray, half: np.ndarray, *,
                        dark: bool, fit: bool) -> Measured:
    """Measure the candidate windows; a marker found off the centre of its window is measured again.

    Off-centre means the binarized blob held two markers that nearly touch, or an odd shape: the marker
    found is measured again in a window of its own, and the mirror image of its position about the
    blob's centre is searched for the other one (duplicates are dropped by :func:`_drop_duplicates`).
    Returns the first measurements followed by those of the off-centre ones (two per blob).
    """
    measured = _measure(gray, rows, cols, half, dark=dark, fit_ellipse=fit)
    with np.errstate(invalid="ignore"):
        off = np.hypot(measured.u_px - cols, measured.v_px - rows) > np.maximum(2.0, 0.25 * half)
        off &= np.isfinite(measured.area_px)
    if not off.any():
        return measured
    sel = np.nonzero(off)[0]
    u_found, v_found = measured.u_px[sel], measured.v_px[sel]
    size = np.ceil(np.sqrt(measured.area_px[sel] / np.pi)).astype(np.int64) + 6
    again = _measure(gray, np.rint(np.concatenate([v_found, 2 * rows[sel] - v_found])).astype(np.int64),
                     np.rint(np.concatenate([u_found, 2 * cols[sel] - u_found])).astype(np.int64),
                     np.concatenate([size, size]), dark=dark, fit_ellipse=fit)
    n_first, n_total = len(rows), len(rows) + len(sel)
    grown = _scatter(None, n_total, np.arange(n_first), measured)
    return _scatter(grown, n_total, np.concatenate([sel, n_first + np.arange(len(sel))]), again)


def _measure_compiled(gray: np.ndarray, rows: np.ndarray, cols: np.ndarray, halves: np.ndarray, *,
                      dark: bool, limits: np.ndarray, threads: int) -> tuple[np.ndarray, np.ndarray]:
    """Output rows and the filters of windows of half sizes ``halves``, one compiled call per thread
    (:func:`rig.stereo.markers_kernel.measure_rows`; a window too small for its marker is retried larger)."""
    from rig.stereo.markers_kernel import measure_rows  # numba: loaded by the first measurement

    rec = np.empty(len(rows), dtype=MARKER_DTYPE)
    passed = np.empty(len(rows), dtype=bool)
    rows, cols = np.ascontiguousarray(rows, dtype=np.int64), np.ascontiguousarray(cols, dtype=np.int64)
    halves = np.ascontiguousarray(halves, dtype=np.int64)
    parts = split(len(rows), threads, WINDOWS_PER_THREAD)
    run_parts(measure_rows, [(gray, rows[lo:hi], cols[lo:hi], halves[lo:hi], dark, limits, _HALF_LADDER, 2,
                              rec[lo:hi], passed[lo:hi]) for lo, hi in parts])
    return rec, passed


def _detect_compiled(gray: np.ndarray, rows: np.ndarray, cols: np.ndarray, half: np.ndarray, *, dark: bool,
                     limits: np.ndarray, threads: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_measure_candidates` + :func:`_rows_passed` without an outline fit: rows and the filters
    (``limits``: as :func:`rig.stereo.markers_kernel.finish_rows`), a compiled call per pass."""
    if len(rows) == 0:
        return np.empty(0, dtype=MARKER_DTYPE), np.zeros(0, dtype=bool)
    rec, passed = _measure_compiled(gray, rows, cols, _merge_sizes(_ladder(half)), dark=dark, limits=limits,
                                    threads=threads)
    with np.errstate(invalid="ignore"):
        off = np.hypot(rec["u_px"] - cols, rec["v_px"] - rows) > np.maximum(2.0, 0.25 * half)
        off &= np.isfinite(rec["area_px"])
    if not off.any():
        return rec, passed
    sel = np.nonzero(off)[0]  # off the window's centre: measured again, and its mirror image (see above)
    u_found, v_found = rec["u_px"][sel], rec["v_px"][sel]
    size = np.ceil(np.sqrt(rec["area_px"][sel] / np.pi)).astype(np.int64) + 6
    again, again_passed = _measure_compiled(
        gray, np.rint(np.concatenate([v_found, 2 * rows[sel] - v_found])).astype(np.int64),
        np.rint(np.concatenate([u_found, 2 * cols[sel] - u_found])).astype(np.int64),
        _merge_sizes(_ladder(np.concatenate([size, size]))), dark=dark, limits=limits, threads=threads)
    keep = np.ones(len(rec), dtype=bool)
    keep[sel] = False  # replaced by their second measurement
    return (np.concatenate([rec[keep], again]), np.concatenate([passed[keep], again_passed]))


def _drop_duplicates(rec: np.ndarray, reach: int = 8) -> np.ndarray:
    """Sort by (v, u) and keep one row of a marker found twice (centres closer than 1 px).

    A marker split into two blobs by the binarization is measured twice on the same support; the two
    rows are then within a pixel, and adjacent in the row-sorted order unless more than ``reach`` other
    markers lie within 1 px of the same image row.
    """
    rec = rec[np.lexsort((rec["u_px"], rec["v_px"]))]
    u, v = rec["u_px"], rec["v_px"]
    if len(rec) <= 128:  # usual case, all pairs at once: nothing to drop?
        du, dv = u[:, None] - u[None, :], v[:, None] - v[None, :]
        if np.count_nonzero(du * du + dv * dv < 1.0) == len(rec):  # only each row with itself
            return rec
    # of two rows of one marker keep the one with fewer flags (e.g. not measured across the border)
    score = rec["flags"].astype(np.int64)
    dup = np.zeros(len(rec), dtype=bool)
    for step in range(1, min(reach, len(rec) - 1) + 1):
        close = (u[step:] - u[:-step]) ** 2 + (v[step:] - v[:-step]) ** 2 < 1.0
        close &= ~dup[:-step] & ~dup[step:]
        later_worse = score[step:] >= score[:-step]
        dup[step:] |= close & later_worse
        dup[:-step] |= close & ~later_worse
    return rec[~dup]


def _none_found(require: bool, why: str) -> np.ndarray:
    if require:
        raise NoMarkersError(
            f"no marker found: {why}; check polarity, threshold, min_contrast, the area limits and the roi"
        )
    return np.empty(0, dtype=MARKER_DTYPE)


def track_markers(
    gray: np.ndarray,
    predicted_uv_px: np.ndarray,
    *,
    window_px: int = 41,
    polarity: str = "bright",
    min_area_px: float = 20.0,
    max_area_px: float = 20000.0,
    min_roundness: float = 0.5,
    min_contrast: float = 20.0,
    centre: str = "centroid",
    max_skewness: float = MAX_SKEWNESS,
    outline_check: bool = False,
    max_edge_rms_px: float = MAX_EDGE_RMS_PX,
    threads: int = 1,
) -> np.ndarray:
    """Measure markers near predicted positions only; one :data:`MARKER_DTYPE` row per prediction, in order.

    predicted_uv_px: (K, 2) predicted centres (u, v) in px, e.g. the previous frame's result.
    window_px: side of the square searched around each prediction (≥ 7 px; an even side is rounded up
        to the next odd one). The whole marker, with its blurred edge, must fit inside it with a few
        pixels of background around: make it the marker diameter + 8 px + twice the largest expected
        frame-to-frame motion. A marker that reaches the window's edge is measured again in a window
        one and then two steps larger (window_px 41: 49, then 57 px), as is one whose blurred edge covers
        the window's ring (its contrast then below markers_kernel.MIN_RING_CONTRAST ring σ). One that
        still reaches the edge is measured without its cut-off part, unflagged, and a ring on the edge is
        not always caught: with window_px 41, of 49,672 rendered markers across the domain (see the
        module's constants), 307 of r 25–30 px (mostly ellipses) were 0.10–0.86 px off and 10 of r
        18–23 px, blur ≥ 1.9 px, 0.29–2.2 px off. Size the window as above (no draw was then off beyond
        noise). The marker is the blob under the window's centre, else the strong blob nearest to it.
        Other options (``threads`` included) as in :func:`detect_markers`.
    A prediction that is NaN, outside the frame, or whose window holds no marker passing the filters gives
    a row with u_px = v_px = NaN and FLAG_LOST (area, roundness, contrast keep what was measured, or NaN).
    """
    # the usual call, as few Python operations as can be: after other work (e.g. a frame's decoding)
    # each one costs microseconds — checking the options afresh cost ~70 µs a call after an OpenCV detector
    if not (type(gray) is np.ndarray and gray.dtype is _UINT8 and gray.ndim == 2 and gray.shape[0] >= 8
            and gray.shape[1] >= 8):
        gray = check_gray(gray)
    try:  # keyed by the types of window_px and threads too: threads=True (== 1) is refused
        opt = _TRACK_OPTIONS[(window_px, type(window_px), polarity, min_area_px, max_area_px, min_roundness,
                              min_contrast, centre, max_skewness, outline_check, max_edge_rms_px, threads,
                              type(threads))]
    except (KeyError, TypeError):  # new options (checked and remembered), or unhashable ones (refused)
        opt = _track_options(window_px=window_px, polarity=polarity, min_area_px=min_area_px,
                             max_area_px=max_area_px, min_roundness=min_roundness, min_contrast=min_contrast,
                             centre=centre, max_skewness=max_skewness, outline_check=outline_check,
                             max_edge_rms_px=max_edge_rms_px, threads=threads)
    pred = predicted_uv_px
    if not (type(pred) is np.ndarray and pred.dtype is _FLOAT64 and pred.ndim == 2 and pred.shape[1] == 2
            and pred.flags.c_contiguous):
        pred = np.ascontiguousarray(predicted_uv_px, dtype=np.float64)
        if pred.ndim != 2 or pred.shape[1] != 2:
            raise InputArrayError(
                f"predicted_uv_px has shape {pred.shape}; give a (K, 2) array of (u, v) in px")
    if not opt.fit and len(pred) and opt.half_px <= _fitting_half(gray.shape):
        return _track_compiled(gray, pred, opt)
    return track_rows(gray, pred, opt)


_TRACK_OPTIONS: dict[tuple[Any, ...], TrackOptions] = {}  # checked options by track_markers' keywords
_MAX_REMEMBERED = 64


def _track_options(*, window_px: Any, polarity: Any, min_area_px: Any, max_area_px: Any, min_roundness: Any,
                   min_contrast: Any, centre: Any, max_skewness: Any, outline_check: Any,
                   max_edge_rms_px: Any, threads: Any) -> TrackOptions:
    """:meth:`TrackOptions.checked`, remembered (up to _MAX_REMEMBERED sets) for :func:`track_markers`."""
    opt = TrackOptions.checked(window_px=window_px, polarity=polarity, min_area_px=min_area_px,
                               max_area_px=max_area_px, min_roundness=min_roundness,
                               min_contrast=min_contrast, centre=centre, max_skewness=max_skewness,
                               outline_check=outline_check, max_edge_rms_px=max_edge_rms_px, threads=threads)
    key = (window_px, type(window_px), polarity, min_area_px, max_area_px, min_roundness, min_contrast,
           centre, max_skewness, outline_check, max_edge_rms_px, threads, type(threads))
    try:
        if len(_TRACK_OPTIONS) >= _MAX_REMEMBERED:
            _TRACK_OPTIONS.clear()
        _TRACK_OPTIONS[key] = opt
    except TypeError:  # an unhashable option that passed the checks: used, not remembered
        pass
    return opt


@dataclass(frozen=True)
class TrackOptions:
    """The checked options of :func:`track_markers` (see there), shared by the batched trackers."""

    half_px: int
    dark: bool
    fit: bool  # the outline is fitted (centre="ellipse" or outline_check)
    centre: str
    min_area_px: float
    max_area_px: float
    min_roundness: float
    min_contrast: float
    max_skewness: float
    max_edge_rms_px: float
    threads: int = 1  # threads one frame's windows are split over (without an outline fit)

    @functools.cached_property
    def track_args(self) -> tuple[int, bool, np.ndarray, np.ndarray, int]:
        """Half size, dark, limits, the size ladder and the retries, as track_frame takes them."""
        return self.half_px, self.dark, self.limits, _HALF_LADDER, 2

    @functools.cached_property
    def limits(self) -> np.ndarray:
        """The filters as :func:`rig.stereo.markers_kernel.finish_rows` takes them (read-only)."""
        limits = np.array([self.max_skewness, SKEW_NOISE_FACTOR, self.min_area_px, self.max_area_px,
                           self.min_roundness, self.min_contrast])
        limits.flags.writeable = False
        return limits

    @classmethod
    def checked(cls, *, window_px: int, polarity: str, min_area_px: float, max_area_px: float,
                min_roundness: float, min_contrast: float, centre: str, max_skewness: float,
                outline_check: bool, max_edge_rms_px: float, threads: int = 1) -> TrackOptions:
        """Options from :func:`track_markers`' keywords; InputArrayError names an invalid one."""
        _check_options(polarity, centre, min_area_px=min_area_px, max_area_px=max_area_px,
                       min_roundness=min_roundness, min_contrast=min_contrast)
        if (not isinstance(window_px, int | float | np.integer | np.floating) or not np.isfinite(window_px)
                or int(window_px) != window_px or window_px < 7):
            raise InputArrayError(f"window_px={window_px}; give an integer side of at least 7 px")
        return cls(half_px=int(window_px) // 2, dark=polarity == "dark",
                   fit=centre == "ellipse" or outline_check, centre=centre, min_area_px=min_area_px,
                   max_area_px=max_area_px, min_roundness=min_roundness, min_contrast=min_contrast,
                   max_skewness=max_skewness, max_edge_rms_px=max_edge_rms_px,
                   threads=check_threads(threads))


def _fitting_half(shape: tuple[int, ...]) -> int:
    """The largest tracking window's half size for a frame of ``shape``: a window much larger than the
    frame has its background ring outside it (at most one pixel larger)."""
    return max(3, min(shape[0], shape[1]) // 2)


def track_rows(gray: np.ndarray, pred: np.ndarray, opt: TrackOptions) -> np.ndarray:
    """:func:`track_markers` of the predictions ``pred`` (N, 2) float64 in the checked frame ``gray``: one
    row per prediction. Without an outline fit, one compiled call per thread
    (:func:`rig.stereo.markers_kernel.track_frame`, the predictions split over ``opt.threads``).
    """
    if len(pred) == 0:
        return np.empty(0, dtype=MARKER_DTYPE)
    height, width = gray.shape
    fitting = _fitting_half(gray.shape)
    if opt.half_px > fitting:
        opt = dataclasses.replace(opt, half_px=fitting)
    if not opt.fit:
        return _track_compiled(gray, np.ascontiguousarray(pred, dtype=np.float64), opt)
    # usable predictions: inside the frame (NaN compares False, so it is unusable too)
    limit = np.array([width - 0.5, height - 0.5])
    all_usable = bool((pred > -0.5).all() and (pred < limit).all())
    usable = None
    if not all_usable:
        usable = ((pred > -0.5) & (pred < limit)).all(axis=1)
    centre_px = np.rint(pred if all_usable else pred[usable]).astype(np.int64)
    cols, rows = centre_px[:, 0], centre_px[:, 1]
    if len(rows) == 0:
        measured = Measured.empty()
    else:
        measured = measure_windows(gray, rows, cols, opt.half_px, dark=opt.dark, fit_ellipse=opt.fit)
    # too small for its marker — cramped, or the ring on its blurred edge (low contrast): larger, as compiled
    measured = _retry_cramped(gray, rows, cols, np.full(len(rows), opt.half_px), measured, dark=opt.dark,
                              fit_ellipse=opt.fit, retries=2)
    rec, passed = _rows_passed(measured, opt.centre, opt.max_edge_rms_px, opt.max_skewness, fitted=opt.fit,
                               limits=(opt.min_area_px, opt.max_area_px, opt.min_roundness, opt.min_contrast))
    if not passed.all():
        lost = ~passed
        rec["u_px"][lost] = np.nan
        rec["v_px"][lost] = np.nan
        rec["flags"][lost] |= FLAG_LOST
    if all_usable:
        return rec
    out = np.zeros(len(pred), dtype=MARKER_DTYPE)
    for field in ("u_px", "v_px", "area_px", "roundness", "contrast"):
        out[field] = np.nan
    out["flags"] = FLAG_LOST
    out[usable] = rec
    return out


def _track_compiled(gray: np.ndarray, pred: np.ndarray, opt: TrackOptions) -> np.ndarray:
    """:func:`track_rows` without an outline fit: one compiled call per thread
    (:func:`rig.stereo.markers_kernel.track_frame`), each thread taking a part of the predictions."""
    track_frame = _kernel().track_frame
    rec = np.empty(len(pred), dtype=MARKER_DTYPE)
    image = gray if gray.flags.c_contiguous else np.ascontiguousarray(gray)
    args = opt.track_args
    if opt.threads == 1 or len(pred) < 2 * WINDOWS_PER_THREAD:  # the usual case, without the split's µs
        track_frame(image, pred, *args, rec)
    else:
        run_parts(track_frame, [(image, pred[lo:hi], *args, rec[lo:hi])
                                for lo, hi in split(len(pred), opt.threads, WINDOWS_PER_THREAD)])
    return rec


@functools.cache
def _kernel() -> ModuleType:
    """:mod:`rig.stereo.markers_kernel`, imported by the first measurement (numba and the compiled code)."""
    import rig.stereo.markers_kernel

    return rig.stereo.markers_kernel
