"""Approximate reach and joint-limit model of a DENSO VP-6242G (``../shared/notes/bcap.md`` §13).

The mock controller refuses poses this model cannot reach. It is deliberately coarse — a planar
two-link arm behind a base rotation — and is **not** the arm's kinematics:

* base: J1 axis vertical through the origin; J2 axis 280 mm above the base plane (shoulder height);
* upper arm 210 mm; forearm 210 mm with a 75 mm elbow offset, i.e. an effective elbow→wrist link of
  √(210² + 75²) ≈ 223.2 mm; wrist centre to flange 70 mm along the tool's approach (z) axis;
* J1 = atan2(y, x) of the wrist centre, limit ±160°; only the configuration facing the wrist is modelled
  (no reaching over the shoulder);
* J3 (Denso convention, 19..160°) from the elbow angle: J3 = 180° − γ + atan(75/210), so full stretch
  (433 mm from J2 to the wrist centre) is J3 ≈ 19.7° and J3 = 160° folds the wrist to ≈ 147 mm;
* J2 (±120°) is the upper arm's tilt from vertical for the elbow-up solution;
* J5 (±120°) is approximated by the angle between the elbow→wrist line and the approach axis.

J4 and J6 (±160°, ±360°) are not checked: any orientation that passes the J5 test is accepted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivers.denso.pose import rotation_matrix

SHOULDER_HEIGHT_MM = 280.0
UPPER_ARM_MM = 210.0
FOREARM_MM = math.hypot(210.0, 75.0)
ELBOW_OFFSET_DEG = math.degrees(math.atan2(75.0, 210.0))
WRIST_TO_FLANGE_MM = 70.0
J1_LIMIT_DEG = 160.0
J2_LIMIT_DEG = 120.0
J3_RANGE_DEG = (19.0, 160.0)
J5_LIMIT_DEG = 120.0


@dataclass(frozen=True)
class Reach:
    """Approximate joint values of a pose (degrees) and the first limit it violates (None if reachable)."""

    j1_deg: float
    j2_deg: float
    j3_deg: float
    j5_deg: float
    wrist_distance_mm: float
    violation: str | None


def solve(pose: NDArray[np.float64] | list[float]) -> Reach:
    """Approximate J1, J2, J3, J5 for a P pose (x, y, z mm; rx, ry, rz deg) and check the limits."""
    x, y, z, rx, ry, rz = (float(v) for v in pose[:6])
    approach = rotation_matrix(rx, ry, rz)[:, 2]
    wrist = np.array([x, y, z]) - WRIST_TO_FLANGE_MM * approach
    r = math.hypot(wrist[0], wrist[1])
    h = wrist[2] - SHOULDER_HEIGHT_MM
    distance = math.hypot(r, h)
    j1 = math.degrees(math.atan2(wrist[1], wrist[0])) if r > 1e-9 else 0.0
    full = UPPER_ARM_MM + FOREARM_MM
    if distance > full:
        return Reach(j1, math.nan, math.nan, math.nan, distance,
                     f"wrist centre {distance:.1f} mm from the J2 axis exceeds the reach {full:.1f} mm")
    cos_gamma = (UPPER_ARM_MM**2 + FOREARM_MM**2 - distance**2) / (2 * UPPER_ARM_MM * FOREARM_MM)
    gamma = math.degrees(math.acos(max(-1.0, min(1.0, cos_gamma))))
    j3 = 180.0 - gamma + ELBOW_OFFSET_DEG
    if distance > 1e-9:
        cos_beta = (UPPER_ARM_MM**2 + distance**2 - FOREARM_MM**2) / (2 * UPPER_ARM_MM * distance)
        beta = math.degrees(math.acos(max(-1.0, min(1.0, cos_beta))))
        alpha = math.degrees(math.atan2(r, h))
    else:
        alpha, beta = 0.0, 0.0
    j2 = alpha - beta
    # elbow position (in the arm's vertical plane) and the elbow→wrist direction in base coordinates
    phi = math.radians(j1)
    elbow = np.array([UPPER_ARM_MM * math.sin(math.radians(j2)) * math.cos(phi),
                      UPPER_ARM_MM * math.sin(math.radians(j2)) * math.sin(phi),
                      SHOULDER_HEIGHT_MM + UPPER_ARM_MM * math.cos(math.radians(j2))])
    line = wrist - elbow
    norm = float(np.linalg.norm(line))
    j5 = math.degrees(math.acos(max(-1.0, min(1.0, float(line @ approach) / norm)))) if norm > 1e-9 else 0.0
    violation = None
    if abs(j1) > J1_LIMIT_DEG:
        violation = f"J1 {j1:.1f} deg outside ±{J1_LIMIT_DEG:g} deg"
    elif abs(j2) > J2_LIMIT_DEG:
        violation = f"J2 {j2:.1f} deg outside ±{J2_LIMIT_DEG:g} deg"
    elif not J3_RANGE_DEG[0] <= j3 <= J3_RANGE_DEG[1]:
        violation = f"J3 {j3:.1f} deg outside {J3_RANGE_DEG[0]:g}..{J3_RANGE_DEG[1]:g} deg"
    elif abs(j5) > J5_LIMIT_DEG:
        violation = f"J5 {j5:.1f} deg outside ±{J5_LIMIT_DEG:g} deg"
    return Reach(j1, j2, j3, j5, distance, violation)
