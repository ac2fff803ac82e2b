"""Denso P poses: x, y, z in mm and rx, ry, rz in degrees, R = Rz(rz)·Ry(ry)·Rx(rx) about fixed base axes."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

AXES = ("x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg")


def check_pose(pose: Sequence[float] | NDArray[np.float64]) -> NDArray[np.float64]:
    """The pose as a float array (6,); raise ValueError naming the bad value."""
    values = np.asarray(pose, dtype=float).ravel()
    if values.shape != (6,):
        raise ValueError(f"pose has {values.size} values; expected 6 (x, y, z mm; rx, ry, rz deg)")
    for axis, value in zip(AXES, values, strict=True):
        if not math.isfinite(value):
            raise ValueError(f"pose {axis}={value!r}: must be finite")
    return values


def rotation_matrix(rx_deg: float, ry_deg: float, rz_deg: float) -> NDArray[np.float64]:
    """Rotation (tool → base) of Denso angles: R = Rz(rz)·Ry(ry)·Rx(rx)."""
    ax, ay, az = (math.radians(v) for v in (rx_deg, ry_deg, rz_deg))
    cx, sx, cy, sy = math.cos(ax), math.sin(ax), math.cos(ay), math.sin(ay)
    cz, sz = math.cos(az), math.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]], dtype=np.float64)
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]], dtype=np.float64)
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]], dtype=np.float64)
    return rz @ ry @ rx


def orientation_error_deg(a: Sequence[float] | NDArray[np.float64],
                          b: Sequence[float] | NDArray[np.float64]) -> float:
    """Angle (deg, 0..180) of the rotation between the orientations of poses ``a`` and ``b``.

    Euler angles are not unique (rx=180 and rx=-180 are the same); this compares the rotations.
    """
    ra = rotation_matrix(*a[3:6])
    rb = rotation_matrix(*b[3:6])
    r = ra.T @ rb
    sin_angle = 0.5 * math.hypot(r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1])
    cos_angle = 0.5 * (float(np.trace(r)) - 1.0)
    return math.degrees(math.atan2(sin_angle, cos_angle))  # accurate near 0 (acos is not)
