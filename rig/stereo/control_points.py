"""Calibration control points: the DLT's linear system (the paper's equation 1) and the checks that make it
determined.

Both DLT conventions (:mod:`rig.stereo.dlt`'s homogeneous A·b = 0 and :mod:`rig.stereo.dlt11`'s L12 = 1)
solve the design matrix of :func:`design_rows`, from points that passed :func:`check_calibration_input`.
"""

from __future__ import annotations

import numpy as np

from rig.stereo._arrays import FloatArray
from rig.stereo.errors import DegenerateCalibrationError, InputArrayError
from rig.stereo.normalize import as_points, homogeneous, principal_spread

MIN_POINTS = 6
#: Smallest allowed ratio of the 3rd (2nd) to the 1st singular value of the centred control points.
#: Below it the points are treated as coplanar (collinear): the DLT is then undetermined or unstable.
MIN_SPREAD_RATIO = 0.01


def design_rows(xyz: FloatArray, uv: FloatArray) -> FloatArray:
    """The paper's A (2N × 12): rows [X Y Z 1 0 0 0 0 −uX −uY −uZ −u] and the v counterpart."""
    Xh = homogeneous(xyz)
    A = np.zeros((2 * len(xyz), 12))
    A[0::2, 0:4] = Xh
    A[1::2, 4:8] = Xh
    A[0::2, 8:12] = -uv[:, :1] * Xh
    A[1::2, 8:12] = -uv[:, 1:2] * Xh
    return A


def check_calibration_input(xyz_mm: object, uv_px: object) -> tuple[FloatArray, FloatArray]:
    """Control points as (N, 3) mm and (N, 2) px; DegenerateCalibrationError when they cannot determine a
    DLT (fewer than MIN_POINTS distinct, collinear or coplanar)."""
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
