"""Regions of interest for marker detection: rectangles and polygons in pixel coordinates.

A region is either a rectangle ``(x0, y0, x1, y1)`` (four numbers, x = u = column, y = v = row, both
bounds inclusive) or a polygon given as a sequence of at least three ``(x, y)`` vertices. A marker is
kept when its centre lies inside (or on the edge of) any of the regions. The pixel-centre convention
of the stereo core applies: the centre of the top-left pixel is (0, 0).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from rig.stereo.errors import InputArrayError


def parse_roi(roi: Sequence[object] | np.ndarray) -> list[np.ndarray]:
    """Validate ``roi`` and return each region as a closed polygon, float64 (N, 2) of (x, y) vertices."""
    if isinstance(roi, np.ndarray) and roi.ndim == 1:
        roi = [roi]
    if not isinstance(roi, Sequence | np.ndarray) or len(roi) == 0:
        raise InputArrayError(
            f"roi must be a non-empty list of rectangles (x0, y0, x1, y1) and/or polygons [(x, y), ...], "
            f"got {roi!r}; pass roi=None to search the whole frame"
        )
    if len(roi) == 4 and all(np.isscalar(value) for value in roi):
        roi = [roi]  # a single bare rectangle
    regions = []
    for i, region in enumerate(roi):
        arr = np.asarray(region, dtype=np.float64)
        if not np.all(np.isfinite(arr)):
            raise InputArrayError(f"roi[{i}] holds NaN or inf: {region!r}; give finite pixel coordinates")
        if arr.shape == (4,):
            x0, y0, x1, y1 = arr
            if x1 < x0 or y1 < y0:
                raise InputArrayError(
                    f"roi[{i}] rectangle {tuple(arr)} has x1 < x0 or y1 < y0; give (x0, y0, x1, y1) with "
                    f"x0 <= x1 and y0 <= y1"
                )
            regions.append(np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]))
        elif arr.ndim == 2 and arr.shape[1] == 2 and arr.shape[0] >= 3:
            regions.append(arr)
        else:
            raise InputArrayError(
                f"roi[{i}] has shape {arr.shape}; a rectangle is 4 numbers (x0, y0, x1, y1) and a polygon "
                f"is at least 3 (x, y) vertices"
            )
    return regions


def roi_bounds(regions: list[np.ndarray]) -> tuple[float, float, float, float]:
    """Bounding box (x0, y0, x1, y1) of all regions."""
    stacked = np.concatenate(regions)
    return (float(stacked[:, 0].min()), float(stacked[:, 1].min()),
            float(stacked[:, 0].max()), float(stacked[:, 1].max()))


def _on_segment(x: np.ndarray, y: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Points (x, y) on the segment a–b (within rounding)."""
    (ax, ay), (bx, by) = a, b
    cross = (bx - ax) * (y - ay) - (by - ay) * (x - ax)
    scale = max(abs(bx - ax), abs(by - ay), 1.0)
    within = ((x >= min(ax, bx) - 1e-9) & (x <= max(ax, bx) + 1e-9)
              & (y >= min(ay, by) - 1e-9) & (y <= max(ay, by) + 1e-9))
    on: np.ndarray = within & (np.abs(cross) <= 1e-9 * scale * scale)
    return on


def inside_polygon(u_px: np.ndarray, v_px: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Boolean mask of the points inside or on the edge of ``polygon`` (even-odd ray casting)."""
    inside = np.zeros(np.shape(u_px), dtype=bool)
    edge = np.zeros(np.shape(u_px), dtype=bool)
    n = len(polygon)
    for i in range(n):
        ax, ay = polygon[i]
        bx, by = polygon[(i + 1) % n]
        edge |= _on_segment(u_px, v_px, polygon[i], polygon[(i + 1) % n])
        crosses = (ay > v_px) != (by > v_px)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_cross = ax + (v_px - ay) * (bx - ax) / (by - ay)
        inside ^= crosses & (u_px < x_cross)
    return inside | edge


def inside_any(u_px: np.ndarray, v_px: np.ndarray, regions: list[np.ndarray]) -> np.ndarray:
    """Boolean mask of the points inside any region."""
    keep = np.zeros(np.shape(u_px), dtype=bool)
    for polygon in regions:
        keep |= inside_polygon(u_px, v_px, polygon)
    return keep
