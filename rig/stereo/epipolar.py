"""Epipolar geometry of two calibrated cameras and one-to-one marker correspondence between them.

Convention: ``F`` maps a pixel of camera A to its epipolar line in camera B, ``x_bᵀ·F·x_a = 0`` with
homogeneous pixels ``x = [u, v, 1]``. Distances are in pixels of the ideal (undistorted) pinhole image;
:func:`match_epipolar` undistorts observed pixels with each camera's lens model first.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np
import scipy.optimize

from rig.stereo._arrays import BoolArray, FloatArray, IntArray
from rig.stereo.dlt import DLTCamera
from rig.stereo.errors import DegenerateGeometryError, InputArrayError
from rig.stereo.normalize import Camera, as_points, homogeneous, projection_matrix


@dataclass(frozen=True)
class Matches:
    """Correspondences found by :func:`match_epipolar`.

    ``pairs`` (K, 2) int: row indices into ``uv_a`` and ``uv_b``; ``distance_px`` (K,) their symmetric
    epipolar distance; ``ambiguous`` (K,) True where another candidate within the gate was nearly as
    close, so the pair may be wrong (flagged, not guessed). ``unmatched_a``/``unmatched_b``: indices
    of points without a partner within the gate.
    """

    pairs: IntArray
    distance_px: FloatArray
    ambiguous: BoolArray
    unmatched_a: IntArray
    unmatched_b: IntArray

    def __len__(self) -> int:
        return int(self.pairs.shape[0])


def fundamental_from_projections(P_a: Camera, P_b: Camera) -> FloatArray:
    """F = [e_b]× · P_b · P_a⁺ (unit Frobenius norm), e_b = P_b·C_a the epipole of A's centre in B.

    Accepts (3, 4) matrices or cameras with ``.P`` (:class:`DLTCamera`). Raises
    :class:`DegenerateGeometryError` when the two cameras share a centre (no baseline: no epipolar geometry).
    """
    Pa, Pb = projection_matrix(P_a, "P_a"), projection_matrix(P_b, "P_b")
    centre_a = -np.linalg.solve(Pa[:, :3], Pa[:, 3])
    centre_b = -np.linalg.solve(Pb[:, :3], Pb[:, 3])
    baseline_mm = float(np.linalg.norm(centre_a - centre_b))
    if baseline_mm <= 1e-9 * max(float(np.linalg.norm(centre_a)), float(np.linalg.norm(centre_b)), 1.0):
        raise DegenerateGeometryError(
            f"the two cameras share a centre (baseline {baseline_mm:.3g} mm): "
            "epipolar geometry needs a baseline; check that two different calibrations were passed"
        )
    e_b = Pb @ np.append(centre_a, 1.0)
    cross = np.array([[0.0, -e_b[2], e_b[1]], [e_b[2], 0.0, -e_b[0]], [-e_b[1], e_b[0], 0.0]])
    F: FloatArray = cross @ Pb @ np.linalg.pinv(Pa)
    return F / np.linalg.norm(F)


def epipolar_distance_px(F: object, uv_a: object, uv_b: object, *, pairwise: bool = True) -> FloatArray:
    """Symmetric point-to-epipolar-line distance in px: sqrt((d_a² + d_b²) / 2).

    d_b is the distance of ``uv_b`` from the epipolar line of ``uv_a`` in image B, d_a the converse.
    ``pairwise=True``: every point of A against every point of B, (Na, Nb); ``pairwise=False``: row k
    against row k, (N,). NaN rows give NaN distances.
    """
    F = np.asarray(F, dtype=np.float64)
    if F.shape != (3, 3) or not np.isfinite(F).all():
        raise InputArrayError(f"F: expected a finite (3, 3) fundamental matrix, got shape {F.shape}")
    xa = homogeneous(as_points(uv_a, "uv_a", 2, allow_nan=True, allow_empty=True))
    xb = homogeneous(as_points(uv_b, "uv_b", 2, allow_nan=True, allow_empty=True))
    lines_b = xa @ F.T  # epipolar lines in B of A's points, (Na, 3)
    lines_a = xb @ F  # epipolar lines in A of B's points, (Nb, 3)
    norm_b = np.hypot(lines_b[:, 0], lines_b[:, 1])
    norm_a = np.hypot(lines_a[:, 0], lines_a[:, 1])
    if pairwise:
        algebraic = np.abs(lines_b @ xb.T)  # x_bᵀ F x_a, (Na, Nb)
        d_b = algebraic / norm_b[:, None]
        d_a = algebraic / norm_a[None, :]
    else:
        if xa.shape[0] != xb.shape[0]:
            raise InputArrayError(
                f"pairwise=False needs as many points in uv_a ({xa.shape[0]}) as in uv_b ({xb.shape[0]})"
            )
        algebraic = np.abs(np.sum(lines_b * xb, axis=1))
        d_b, d_a = algebraic / norm_b, algebraic / norm_a
    with np.errstate(invalid="ignore"):
        return np.sqrt((d_a**2 + d_b**2) / 2.0)


def match_epipolar(
    cam_a: object,
    cam_b: object,
    uv_a: object,
    uv_b: object,
    *,
    gate_px: float,
    ambiguity_margin_px: float | None = None,
) -> Matches:
    """One-to-one correspondence of markers seen by cameras A and B.

    The assignment (scipy ``linear_sum_assignment``) first maximises the number of pairs whose symmetric
    epipolar distance is ≤ ``gate_px``, then minimises the sum of squared distances. A pair (i, j) is
    ``ambiguous`` when another candidate of i or of j lies within the gate and within
    ``ambiguity_margin_px`` (default ``gate_px / 2``) of the pair's own distance: a marker on nearly the
    same epipolar line. NaN rows (lost markers) and pixels outside the field where a camera's lens model
    is invertible are never matched.
    """
    if isinstance(gate_px, bool) or not (
        isinstance(gate_px, numbers.Real) and math.isfinite(gate_px) and gate_px > 0
    ):
        raise InputArrayError(
            f"gate_px={gate_px!r}: pass a positive number of pixels (typically 3–5× the noise)"
        )
    margin = gate_px / 2.0 if ambiguity_margin_px is None else ambiguity_margin_px
    if not (math.isfinite(margin) and margin >= 0):
        raise InputArrayError(
            f"ambiguity_margin_px={ambiguity_margin_px!r}: pass a non-negative number of pixels"
        )
    a = uv_a if not isinstance(cam_a, DLTCamera) else cam_a.undistort_px(uv_a, strict=False)
    b = uv_b if not isinstance(cam_b, DLTCamera) else cam_b.undistort_px(uv_b, strict=False)
    D = epipolar_distance_px(fundamental_from_projections(cam_a, cam_b), a, b)
    n_a, n_b = D.shape
    feasible = np.isfinite(D) & (gate_px >= D)
    empty = np.zeros(0, dtype=np.int64)
    if not feasible.any():
        return Matches(
            np.zeros((0, 2), np.int64), np.zeros(0), np.zeros(0, bool), np.arange(n_a), np.arange(n_b)
        )
    big = gate_px**2 * (min(n_a, n_b) + 1.0)  # any feasible pair beats every infeasible one
    cost = np.where(feasible, np.where(feasible, D, 0.0) ** 2, big)
    rows, cols = scipy.optimize.linear_sum_assignment(cost)
    keep = feasible[rows, cols]
    rows, cols = rows[keep], cols[keep]
    dist = D[rows, cols]
    near_row = feasible[rows] & (D[rows] <= dist[:, None] + margin)  # candidates of i, (K, Nb)
    near_col = feasible[:, cols].T & (dist[:, None] + margin >= D[:, cols].T)  # candidates of j, (K, Na)
    ambiguous = (near_row.sum(axis=1) > 1) | (near_col.sum(axis=1) > 1)
    order = np.argsort(rows, kind="stable")
    rows, cols, dist, ambiguous = rows[order], cols[order], dist[order], ambiguous[order]
    unmatched_a = np.setdiff1d(np.arange(n_a), rows) if n_a else empty
    unmatched_b = np.setdiff1d(np.arange(n_b), cols) if n_b else empty
    return Matches(np.stack([rows, cols], axis=1).astype(np.int64), dist, ambiguous, unmatched_a, unmatched_b)
