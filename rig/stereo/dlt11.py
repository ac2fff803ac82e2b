"""The DLT's 11-coefficient convention (Convention A, L12 = 1) of stored coefficient files.

Convention A (L12 = 1, 11 coefficients L1…L11, ordinary least squares) is what stored coefficient files
of vaila, Argus and DLTdv hold; the paper's Convention B is the homogeneous A·b = 0 of
:mod:`rig.stereo.dlt`. Both use the design matrix of :func:`rig.stereo.control_points.design_rows` (the
paper's equation 1).
"""

from __future__ import annotations

import numpy as np

from rig.stereo._arrays import FloatArray
from rig.stereo.control_points import check_calibration_input, design_rows
from rig.stereo.errors import DegenerateCalibrationError, InputArrayError
from rig.stereo.normalize import as_projection


def dlt11_from_P(P: object, *, length_unit_mm: float = 1.0) -> FloatArray:  # noqa: N802
    """L1…L11 = P(row-major)[:11] / P[2,3] for world units of ``length_unit_mm`` (1000 for metres)."""
    P = as_projection(P).copy()
    P[:, :3] *= length_unit_mm
    if abs(P[2, 3]) < 1e-12 * np.abs(P).max():
        raise DegenerateCalibrationError(
            "P[2,3] ≈ 0: the world origin lies in the camera's principal plane, so the L12 = 1 form does not "
            "exist; move the world origin (e.g. to the centroid of the control points) or keep P"
        )
    L: FloatArray = (P / P[2, 3]).ravel()[:11]
    return L


def P_from_dlt11(coefficients: object, *, length_unit_mm: float = 1.0) -> FloatArray:  # noqa: N802
    """The 3×4 P in mm → px from L1…L11 whose world unit is ``length_unit_mm``."""
    L = np.asarray(coefficients, dtype=np.float64).ravel()
    if L.shape != (11,) or not np.isfinite(L).all():
        raise InputArrayError(
            f"DLT coefficients: expected 11 finite numbers L1…L11, got shape {np.asarray(coefficients).shape}"
        )
    P = np.append(L, 1.0).reshape(3, 4)
    P[:, :3] /= length_unit_mm
    return P


def solve_dlt11(xyz: object, uv_px: object) -> FloatArray:
    """Convention A: L1…L11 by ordinary least squares with L12 = 1 (as vaila, Argus and DLTdv do).

    Units of the coefficients follow those of ``xyz``; no normalization is applied because it would
    change this convention's solution (column scaling only, for conditioning).
    """
    xyz_a, uv = check_calibration_input(xyz, uv_px)
    A = design_rows(xyz_a, uv)
    rhs = -A[:, 11]
    M = A[:, :11]
    scale = np.linalg.norm(M, axis=0)
    scale[scale == 0] = 1.0
    sol = np.linalg.lstsq(M / scale, rhs, rcond=None)[0]
    L: FloatArray = sol / scale
    return L
