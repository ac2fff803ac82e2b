"""Identify a calibration plate's markers in one camera's image: which blobs, and which grid node each is.

Pure functions on point sets (pixels), no I/O; used by the ``calibrate`` procedure (the arm slides the
plate) and by the on-site calibration from videos (an operator slides the plate).

* :func:`moving_points` — the plate's markers are the blobs that move between slid positions while the
  fixed reference markers stay: given each position's (averaged) detections, return the indices of the
  blobs of each position that are *not* at a place occupied by a blob in every other position.
* :func:`order_grid` — order ``rows × cols`` points on their grid: the four corners of the convex hull give
  an initial homography grid → image, which is refined with all points (a plane's perspective image is a
  homography, so a wrong assignment shows as a large residual).

Grid convention: node ``(r, c)`` has index ``r·cols + c``; row 0 is the top row and column 0 the left
column *as the camera sees the plate* (a plate facing the camera, upright). The long side of a non-square
grid carries the columns when ``cols > rows``.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

__all__ = ["GridError", "GridFit", "moving_points", "order_grid"]


class GridError(ValueError):
    """The points cannot be identified as the plate's grid (wrong count, not a grid, ambiguous)."""


@dataclass(frozen=True)
class GridFit:
    """Result of :func:`order_grid`.

    ``order``: (rows·cols,) indices into the input points, node ``r·cols + c`` first;
    ``uv_px``: the ordered points (rows·cols, 2); ``homography``: 3×3 grid (c, r) → image (u, v);
    ``residual_rms_px`` / ``residual_max_px``: distance of the points from the fitted homography.
    """

    order: np.ndarray
    uv_px: np.ndarray
    homography: np.ndarray
    residual_rms_px: float
    residual_max_px: float


def _points(uv_px: object, name: str = "uv_px") -> np.ndarray:
    uv = np.asarray(uv_px, dtype=float)
    if uv.ndim != 2 or uv.shape[1] != 2 or not np.all(np.isfinite(uv)):
        raise GridError(f"{name} must be a finite (N, 2) array of pixel coordinates, got shape {uv.shape}")
    return uv


def moving_points(uv_per_position: Sequence[np.ndarray], *, still_px: float = 2.0) -> list[np.ndarray]:
    """Indices of the moving blobs of each position.

    ``uv_per_position``: one (N_i, 2) array per slid position (blob centres, px, e.g. averaged over the
    still frames). A blob is *static* when every other position has a blob within ``still_px`` of it
    (the reference markers); the rest moved with the plate. Needs ≥ 2 positions.
    """
    sets = [_points(uv, f"uv_per_position[{i}]") for i, uv in enumerate(uv_per_position)]
    if len(sets) < 2:
        raise GridError(f"{len(sets)} position(s) given; telling the plate from fixed markers needs ≥ 2")
    out = []
    for i, pts in enumerate(sets):
        static = np.ones(len(pts), dtype=bool)
        for j, other in enumerate(sets):
            if j == i:
                continue
            if len(other) == 0:
                static[:] = False
                break
            d = np.linalg.norm(pts[:, None, :] - other[None, :, :], axis=2).min(axis=1)
            static &= d <= still_px
        out.append(np.nonzero(~static)[0])
    return out


def _hull_corners(uv: np.ndarray) -> np.ndarray:
    """Indices of the four hull vertices with the sharpest turns, in hull (counter-clockwise) order."""
    hull = cv2.convexHull(uv.astype(np.float32), returnPoints=False).ravel()
    if len(hull) < 4:
        raise GridError(f"the points' convex hull has only {len(hull)} vertices; they are not a 2-D grid")
    p = uv[hull]
    prev, nxt = np.roll(p, 1, axis=0), np.roll(p, -1, axis=0)
    a, b = p - prev, nxt - p
    cos = np.sum(a * b, axis=1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1) + 1e-12)
    turn = np.arccos(np.clip(cos, -1.0, 1.0))
    keep = np.sort(np.argsort(turn)[-4:])
    return hull[keep]


def _fit(grid: np.ndarray, uv: np.ndarray) -> np.ndarray:
    H, _ = cv2.findHomography(grid.astype(np.float64), uv.astype(np.float64), 0)
    if H is None:
        raise GridError("no homography fits the corner assignment (degenerate point set)")
    return H


def _apply(H: np.ndarray, grid: np.ndarray) -> np.ndarray:
    g = np.c_[grid, np.ones(len(grid))] @ H.T
    return g[:, :2] / g[:, 2:3]


def order_grid(uv_px: object, rows: int, cols: int, *, max_residual_px: float | None = None) -> GridFit:
    """Order ``rows × cols`` image points on their grid (see the module docstring for the convention).

    ``max_residual_px``: largest allowed distance of a point from the refined homography (default 0.25 of
    the smallest image spacing between neighbouring nodes). Raises :class:`GridError` when the count is
    not ``rows·cols``, the points are no grid, or the result is ambiguous.
    """
    if rows < 2 or cols < 2:
        raise GridError(f"rows={rows}, cols={cols}: a grid needs at least 2 × 2 nodes")
    uv = _points(uv_px)
    n = rows * cols
    if len(uv) != n:
        raise GridError(f"found {len(uv)} plate markers; the plate has rows × cols = {rows} × {cols} = {n} "
                        "(check the detection settings, occlusions and the plate geometry of the rig)")
    corners = uv[_hull_corners(uv)]
    nodes = np.array([(c, r) for r in range(rows) for c in range(cols)], dtype=float)
    grid_corners = np.array([(0, 0), (cols - 1, 0), (cols - 1, rows - 1), (0, rows - 1)], dtype=float)
    best: tuple[float, np.ndarray, np.ndarray] | None = None
    for shift, flip in itertools.product(range(4), (False, True)):
        seq = np.roll(np.arange(4), shift)
        if flip:
            seq = seq[::-1]
        H = _fit(grid_corners, corners[seq])
        pred = _apply(H, nodes)
        if not np.all(np.isfinite(pred)):
            continue
        cost = np.linalg.norm(pred[:, None, :] - uv[None, :, :], axis=2)
        r_idx, c_idx = linear_sum_assignment(cost)
        order = np.empty(n, dtype=int)
        order[r_idx] = c_idx
        for _ in range(2):  # refine with all points, then re-assign
            H = _fit(nodes, uv[order])
            pred = _apply(H, nodes)
            cost = np.linalg.norm(pred[:, None, :] - uv[None, :, :], axis=2)
            r_idx, c_idx = linear_sum_assignment(cost)
            order[r_idx] = c_idx
        resid = np.linalg.norm(_apply(H, nodes) - uv[order], axis=1)
        # convention: row 0 on top (smallest v), column 0 on the left (smallest u)
        top_left = _apply(H, np.array([[0.0, 0.0], [cols - 1.0, 0.0], [0.0, rows - 1.0]]))
        if not (top_left[1, 0] > top_left[0, 0] and top_left[2, 1] > top_left[0, 1]):
            continue
        score = float(np.sqrt(np.mean(resid**2)))
        if best is None or score < best[0]:
            best = (score, order.copy(), H)
    if best is None:
        raise GridError(f"no assignment of the {n} points to a {rows} × {cols} grid keeps row 0 on top and "
                        "column 0 on the left; is the plate upright and facing the camera?")
    _, order, H = best
    pred = _apply(H, nodes)
    resid = np.linalg.norm(pred - uv[order], axis=1)
    spacing = min(np.linalg.norm(np.diff(pred.reshape(rows, cols, 2), axis=1), axis=2).min(),
                  np.linalg.norm(np.diff(pred.reshape(rows, cols, 2), axis=0), axis=2).min())
    limit = 0.25 * spacing if max_residual_px is None else float(max_residual_px)
    if resid.max() > limit:
        raise GridError(f"the points do not lie on a {rows} × {cols} grid: a point is {resid.max():.2f} px "
                        f"from the fitted homography (allowed {limit:.2f} px)")
    return GridFit(order=order, uv_px=uv[order], homography=H,
                   residual_rms_px=float(np.sqrt(np.mean(resid**2))), residual_max_px=float(resid.max()))
