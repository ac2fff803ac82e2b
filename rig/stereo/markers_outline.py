"""Outline of a measured marker: sub-pixel half-contrast edge points and the ellipse fitted to them.

Used by :mod:`rig.stereo.markers_refine` when the ellipse centre or the outline check is asked for.
Edge points are where the background-subtracted signal ``d`` (DN) crosses a level (half the marker's
contrast), interpolated linearly between pixel centres; coordinates are window px (column x, row y,
the window's top-left pixel at (0, 0)). Only the outer outline counts: a pixel inside the marker that
noise (or the support's noise floor) puts below the level is a hole, not outline — at contrast/σ 7 a
disc of r 16 px has a few, each adding four crossings up to a radius away from the ellipse. The ellipse
is ``cv2.fitEllipseDirect`` per window; the RMS distance of the points from it is a few hundredths of a
pixel for a whole disc.
"""

from __future__ import annotations

import cv2
import numpy as np


def _nonzero(mask: np.ndarray) -> tuple[np.ndarray, ...]:
    """``np.nonzero(mask)`` of an n-D ``mask`` through its flat indices: the same indices in the same
    (row-major) order; numpy 2.4's n-D ``nonzero`` is many times slower than ``flatnonzero``."""
    return np.unravel_index(np.flatnonzero(mask), mask.shape)


def outside(below: np.ndarray) -> np.ndarray:
    """The pixels of ``below`` (K, H, W) bool 4-connected to their window's edge (the holes left out).

    One flood fill over the windows stacked in a column, each framed by rows and columns that count as
    below: the frames join every window's outside into one region, and a hole stays apart from it."""
    k, h, w = below.shape
    tiled = np.ones((k * (h + 1) + 1, w + 2), dtype=np.uint8)
    windows = tiled[1:].reshape(k, h + 1, w + 2)[:, :h, 1:-1]  # a view into the stack
    windows[...] = below
    cv2.floodFill(tiled, None, (0, 0), 2, flags=4)
    reached: np.ndarray = windows == 2
    return reached


def edge_points(d: np.ndarray, level: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Sub-pixel crossings of ``d`` (K, W, W) through ``level`` (K,) between the outside (below the level,
    connected to the window's edge) and the marker: (window index, x, y) in window px, and the step (DN)."""
    a = d - level[:, None, None]
    below = outside(a < 0)
    kh, ih, jh = _nonzero(below[:, :, :-1] != below[:, :, 1:])
    a0, a1 = a[kh, ih, jh], a[kh, ih, jh + 1]
    kv, iv, jv = _nonzero(below[:, :-1, :] != below[:, 1:, :])
    b0, b1 = a[kv, iv, jv], a[kv, iv + 1, jv]
    k_all = np.concatenate([kh, kv])
    x_all = np.concatenate([jh + a0 / (a0 - a1), jv.astype(np.float32)])
    y_all = np.concatenate([ih.astype(np.float32), iv + b0 / (b0 - b1)])
    step = np.abs(np.concatenate([a0 - a1, b0 - b1]))  # intensity step across the crossing, DN
    order = np.argsort(k_all, kind="stable")
    return k_all[order], x_all[order], y_all[order], step[order]


def fit_ellipses(k_idx: np.ndarray, x: np.ndarray, y: np.ndarray, step: np.ndarray,
                 n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ellipse fitted to each window's edge points: centre (n, 2), RMS point distance (n,), NaN if < 6
    points, and the RMS distance that pixel noise of σ = 1 DN alone would give (n,).

    A crossing interpolated between two pixels whose values differ by ``step`` moves by ≈ σ·√2/step
    when both carry independent noise σ: mean(2/step²) is the noise term per DN² of σ.
    """
    centre = np.full((n, 2), np.nan)
    axes = np.full((n, 2), np.nan)
    angle = np.full(n, np.nan)
    bounds = np.searchsorted(k_idx, np.arange(n + 1))
    pts = np.stack([x, y], axis=1).astype(np.float32)
    for i in range(n):
        lo, hi = bounds[i], bounds[i + 1]
        if hi - lo < 6:
            continue
        (cx, cy), (full_w, full_h), ang_deg = cv2.fitEllipseDirect(pts[lo:hi])
        if np.isfinite(cx) and full_w > 0 and full_h > 0:
            centre[i] = cx, cy
            axes[i] = 0.5 * full_w, 0.5 * full_h
            angle[i] = np.deg2rad(ang_deg)
    # radial distance of every edge point from its window's ellipse, vectorized over all points
    ok = np.isfinite(angle[k_idx])
    kk = k_idx[ok]
    dx, dy = x[ok] - centre[kk, 0], y[ok] - centre[kk, 1]
    cos_a, sin_a = np.cos(angle[kk]), np.sin(angle[kk])
    rho = np.hypot((dx * cos_a + dy * sin_a) / axes[kk, 0], (-dx * sin_a + dy * cos_a) / axes[kk, 1])
    dist = (rho - 1.0) * np.hypot(dx, dy) / np.maximum(rho, 1e-9)
    counts = np.bincount(kk, minlength=n)
    sq = np.bincount(kk, weights=dist * dist, minlength=n)
    noise = np.bincount(kk, weights=2.0 / np.maximum(step[ok], 1e-3) ** 2, minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        fitted = np.isfinite(angle) & (counts > 0)
        rms = np.where(fitted, np.sqrt(sq / np.maximum(counts, 1)), np.nan)
        noise_rms = np.where(fitted, np.sqrt(noise / np.maximum(counts, 1)), np.nan)
    return centre, rms, noise_rms
