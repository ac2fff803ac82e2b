"""Binarization of a frame into marker candidates (the paper's first step), on a reduced copy for speed.

The frame is reduced ×2 or ×4 — subsampled when its noise is low, else averaged (see reduce_frame) —
then binarized — by default against the local mean (a box three marker diameters wide) plus an offset of
max(min_contrast/2, 4σ of the noise), so uneven lighting does not matter; or at Otsu's level; or at a
fixed level — and the blobs' bounding boxes give candidate windows at full resolution. The usual case
(local threshold, subsampled frame) is one compiled pass (:mod:`rig.stereo.markers_label`); the others use
OpenCV (outer contours). The exact
measurement (area, contrast, centre) is made later at full resolution (:mod:`rig.stereo.markers_refine`),
so the filters here are deliberately loose.
"""

from __future__ import annotations

import cv2
import numpy as np


def noise_sigma(low: np.ndarray) -> float:
    """Robust pixel noise σ (DN) of ``low`` from horizontal differences of every 32nd row."""
    diff = np.abs(low[::32, 1:].astype(np.int16) - low[::32, :-1]).ravel()
    hist = np.bincount(diff, minlength=256)
    median = np.searchsorted(np.cumsum(hist), diff.size / 2.0)
    return max(1.4826 * float(median) / float(np.sqrt(2.0)), 0.5)


def reduce_frame(gray: np.ndarray, factor: int, min_contrast: float) -> tuple[np.ndarray, float]:
    """The frame reduced ``factor`` times, and the pixel noise σ (DN) of the reduced frame.

    Subsampling (one pixel of each factor×factor block, near its centre) reads a quarter or a sixteenth
    of the frame's memory and keeps the markers' full contrast; it is used when the noise is small
    against the contrast sought (4σ ≤ min_contrast/2, so the noise does not set the binarization level).
    Otherwise the blocks are averaged (area interpolation, two halvings), which divides σ by the factor.
    """
    if factor == 1:
        return gray, noise_sigma(gray)
    start = factor // 2
    low = np.ascontiguousarray(gray[start::factor, start::factor])
    sigma = noise_sigma(low)
    if 4.0 * sigma <= 0.5 * min_contrast:
        return low, sigma
    low = gray
    for _ in range({2: 1, 4: 2}[factor]):
        h, w = low.shape
        low = cv2.resize(low[: h - h % 2, : w - w % 2], (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    return low, noise_sigma(low)


def _local_level(shape: tuple[int, ...], max_area_px: float, factor: int, min_contrast: float,
                 sigma: float) -> tuple[int, int]:
    """The local threshold's box side (odd, reduced px: three marker diameters) and offset (DN)."""
    radius_low = np.sqrt(max_area_px / np.pi) / factor
    block = int(2 * np.ceil(3.0 * radius_low) + 1)
    block = max(3, min(block, 2 * ((min(shape) - 1) // 2) + 1))
    return block, int(np.ceil(max(0.5 * min_contrast, 4.0 * sigma)))


def _blobs_opencv(gray: np.ndarray, *, dark: bool, threshold: float | str | None, factor: int,
                  max_area_px: float, min_contrast: float) -> np.ndarray:
    """Bounding boxes (B, 4) int64 (x0, y0, width, height; reduced px) of the binarized frame's blobs,
    by OpenCV: every threshold mode and reduction."""
    low, sigma = reduce_frame(gray, factor, min_contrast)
    if dark:
        low = cv2.bitwise_not(low)
    if threshold is None:
        block, offset = _local_level(low.shape, max_area_px, factor, min_contrast, sigma)
        # foreground: brighter than the local mean (box of `block` reduced pixels) by more than `offset`
        level = cv2.add(cv2.blur(low, (block, block), borderType=cv2.BORDER_REPLICATE),
                        np.array([min(offset, 255)], dtype=np.float64))  # a 1-element array: a scalar
        binary = cv2.compare(low, level, cv2.CMP_GT)
    elif threshold == "otsu":
        _, binary = cv2.threshold(low, 0, 1, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    else:
        level_dn = 255.0 - float(threshold) if dark else float(threshold)
        _, binary = cv2.threshold(low, level_dn, 1, cv2.THRESH_BINARY)
    # outer contours of the blobs (faster than connectedComponentsWithStats on a mostly empty frame)
    contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    return np.array([cv2.boundingRect(c) for c in contours], dtype=np.int64).reshape(-1, 4)


BAND_ROWS = 32  # reduced rows per band at least: a thinner band costs more than it saves


def _blobs_compiled(gray: np.ndarray, *, dark: bool, factor: int, max_area_px: float, min_contrast: float,
                    threads: int) -> np.ndarray | None:
    """Boxes as :func:`_blobs_opencv` of the local threshold on the subsampled frame (``gray``
    C-contiguous), in row bands on ``threads`` threads; None when the noise calls for the averaged
    reduction instead (:func:`reduce_frame`)."""
    from rig.stereo.markers_label import band_runs, join_boxes, reduced_shape, subsample_sigma
    from rig.stereo.markers_threads import run_parts, split

    sigma = subsample_sigma(gray, factor)
    if 4.0 * sigma > 0.5 * min_contrast:
        return None
    shape = reduced_shape(gray.shape, factor)
    block, offset = _local_level(shape, max_area_px, factor, min_contrast, sigma)
    bands = split(shape[0], threads, BAND_ROWS)
    runs = run_parts(band_runs, [(gray, factor, dark, y0, y1, block, offset) for y0, y1 in bands])
    return join_boxes(runs, [y0 for y0, _ in bands])


def find_candidates(gray: np.ndarray, *, dark: bool, threshold: float | str | None, factor: int,
                    min_area_px: float, max_area_px: float, min_contrast: float,
                    min_roundness: float, threads: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Blobs of the binarized frame reduced ``factor`` (1, 2, 4) times.

    ``threads``: the usual case (compiled) is labelled in that many row bands at once (the same blobs).
    Returns full-resolution integer window centres (rows, cols) and window half sizes, int64 arrays.
    """
    boxes = None
    if threshold is None and factor > 1:  # the usual case: compiled (rig.stereo.markers_label)
        boxes = _blobs_compiled(np.ascontiguousarray(gray), dark=dark, factor=factor, max_area_px=max_area_px,
                                min_contrast=min_contrast, threads=threads)
    if boxes is None:
        boxes = _blobs_opencv(gray, dark=dark, threshold=threshold, factor=factor, max_area_px=max_area_px,
                              min_contrast=min_contrast)
    if len(boxes) == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, empty
    x0, y0, width, height = boxes.T
    # loose size and shape filters on the bounding box (the exact area and roundness are measured at
    # full resolution): an ellipse of area ≤ max_area_px and axis ratio ≥ min_roundness is at most
    # 2·sqrt(max_area_px / (π·min_roundness)) long; allow 1.5× that and the reduction's rounding
    box_area = width * height * factor * factor
    long_side, short_side = np.maximum(width, height), np.minimum(width, height)
    ratio = max(min_roundness, 0.05)
    max_long_px = 3.0 * np.sqrt(max_area_px / (np.pi * ratio)) + 2 * factor
    keep = ((box_area >= 0.25 * min_area_px) & (long_side * factor <= max_long_px)
            & (long_side <= 2.0 / ratio * short_side + 2))
    x0, y0, width, height = x0[keep], y0[keep], width[keep], height[keep]
    half_f = 0.5 * (factor - 1)
    cols = np.rint((x0 + 0.5 * (width - 1)) * factor + half_f).astype(np.int64)
    rows = np.rint((y0 + 0.5 * (height - 1)) * factor + half_f).astype(np.int64)
    half = np.ceil(0.5 * np.maximum(width, height) * factor).astype(np.int64) + 4
    return rows, cols, half
