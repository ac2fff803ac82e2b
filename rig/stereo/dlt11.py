"""DLT coefficient conventions and the checks on calibration control points.

Convention A (L12 = 1, 11 coefficients L1…L11, ordinary least squares) is what stored coefficient files
of vaila, Argus and DLTdv hold; the paper's Convention B is the homogeneous A·b = 0 of
:mod:`rig.stereo.dlt`. Both use the design matrix of :func:`design_rows` (the paper's equation 1).
"""

from __future__ import annotations

import numpy as np

from rig.stereo._arrays import FloatArray
from rig.stereo.errors import DegenerateCalibrationError, InputArrayError
from rig.stereo.normalize import as_points, as_projection, homogeneous, principal_spread

MIN_POINTS = 6
#: Smallest allowed ratio of the 3rd (2nd) to the 1st singular value of the centred control points.
#: Below it the points are treated as coplanar (collinear): the DLT is then undetermined or unstable.
MIN_SPREAD_RATIO = 0.01


# --------------------------------------------------------------------- Convention A (L12 = 1)
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


def design_rows(xyz: FloatArray, uv: FloatArray) -> FloatArray:
    """The paper's A (2N × 12): rows [X Y Z 1 0 0 0 0 −uX −uY −uZ −u] and the v counterpart."""
    Xh = homogeneous(xyz)
    A = np.zeros((2 * len(xyz), 12))
    A[0::2, 0:4] = Xh
    A[1::2, 4:8] = Xh
    A[0::2, 8:12] = -uv[:, :1] * Xh
    A[1::2, 8:12] = -uv[:, 1:2] * Xh
    return A


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


def check_calibration_input(xyz_mm: object, uv_px: object) -> tuple[FloatArray, FloatArray]:
    xyz = as_points(xyz_mm, "xyz_mm", 3)
    uv = as_points(uv_px, "uv_px", 2)
    if xyz.shape[0] != uv.shape[0]:
        raise InputArrayError(
            f"xyz_mm has {xyz.shape[0]} points but uv_px has {uv.shape[0]}; pass one pixel per point"
        )
    n_distinct = np.unique(xyz, axis=0).shape[0]
    if n_distinct < MIN_POINTS:
        raise DegenerateCalibrationError(
            f"{n_distinct} distinct control points; the DLT needs at least {MIN_POINTS} non-coplanar ones "
            "(11 unknowns, 2 equations per point). Duplicated points do not help: add points at new positions"
        )
    spread = principal_spread(xyz)
    if spread[1] < MIN_SPREAD_RATIO:
        raise DegenerateCalibrationError(
            f"the control points are (nearly) collinear (spread ratio {spread[1]:.2g} < {MIN_SPREAD_RATIO}); "
            "add points off their line and off a common plane"
        )
    if spread[2] < MIN_SPREAD_RATIO:
        raise DegenerateCalibrationError(
            f"the control points are (nearly) coplanar: their thickness is {spread[2]:.2g} of their width "
            f"(< {MIN_SPREAD_RATIO}); slide the plate along its normal to more positions covering the "
            "measurement depth, or add points out of its plane"
        )
    return xyz, uv
