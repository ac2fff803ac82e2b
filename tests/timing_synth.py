"""Synthetic two-camera rolling-shutter observations with known truth (tests and benchmarks of timing).

Independent of the stereo core: projection by cv2.projectPoints of a known 3D trajectory; each observation's
exposure instant solved by fixed-point iteration of t = τ + offset + drift·1e-6·(τ − epoch) + v(t)·line_time.
World units mm, times s, image 1920×1080.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

WIDTH, HEIGHT = 1920, 1080
FOCAL_PX = 2200.0


@dataclass
class SynthCamera:
    rvec: np.ndarray
    tvec: np.ndarray
    K: np.ndarray

    @property
    def P(self) -> np.ndarray:  # noqa: N802 (P as in the literature and DLTCamera)
        R, _ = cv2.Rodrigues(self.rvec)
        return self.K @ np.column_stack([R, self.tvec])

    def project(self, xyz_mm: np.ndarray) -> np.ndarray:
        uv, _ = cv2.projectPoints(
            np.asarray(xyz_mm, float).reshape(-1, 1, 3), self.rvec, self.tvec, self.K, None
        )
        return uv.reshape(-1, 2)


def look_at(centre_mm, target_mm, up=(0.0, -1.0, 0.0)) -> SynthCamera:
    """Camera at ``centre_mm`` looking at ``target_mm`` (y down in the image, world y up → up=(0,-1,0))."""
    c, tgt = np.asarray(centre_mm, float), np.asarray(target_mm, float)
    z = tgt - c
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, float))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.vstack([x, y, z])
    rvec, _ = cv2.Rodrigues(R)
    K = np.array([[FOCAL_PX, 0, (WIDTH - 1) / 2], [0, FOCAL_PX, (HEIGHT - 1) / 2], [0, 0, 1.0]])
    return SynthCamera(rvec.ravel(), -R @ c, K)


def stereo_pair(baseline_mm: float = 600.0, height_b_mm: float = 120.0, distance_mm: float = 1500.0):
    """Two converging cameras; camera B is a little higher so the row difference v_B − v_A varies."""
    target = (0.0, 0.0, distance_mm)
    cam_a = look_at((-baseline_mm / 2, 0.0, 0.0), target)
    cam_b = look_at((baseline_mm / 2, height_b_mm, 0.0), target)
    return cam_a, cam_b


def observe(
    cam: SynthCamera,
    trajectory: Callable[[np.ndarray], np.ndarray],
    timestamps_s: np.ndarray,
    *,
    offset_s: float = 0.0,
    line_time_s: float = 0.0,
    drift_ppm: float = 0.0,
    epoch_s: float = 0.0,
    sigma_px: float = 0.0,
    rng: np.random.Generator | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(timestamps_s, uv_px with noise, t_true_s) of the marker at ``trajectory(t) -> (N, 3)`` mm."""
    tau = np.asarray(timestamps_s, float)
    t0 = tau + offset_s + drift_ppm * 1e-6 * (tau - epoch_s)
    t = t0.copy()
    for _ in range(30):
        uv = cam.project(trajectory(t))
        t_new = t0 + uv[:, 1] * line_time_s
        if np.max(np.abs(t_new - t)) < 1e-13:
            break
        t = t_new
    uv = cam.project(trajectory(t))
    if sigma_px > 0:
        uv = uv + (rng or np.random.default_rng(0)).normal(0.0, sigma_px, uv.shape)
    return tau, uv, t


def rotor(
    frequency_hz: float = 10.0, radius_mm: float = 80.0, centre_mm=(0.0, 0.0, 1500.0), tilt_deg: float = 20.0
):
    """Marker on a circle in a plane tilted about x by ``tilt_deg`` from facing the cameras; returns
    (trajectory, centre, axis)."""
    c = np.asarray(centre_mm, float)
    a = np.deg2rad(tilt_deg)
    e1 = np.array([1.0, 0.0, 0.0])
    e2 = np.array([0.0, np.cos(a), np.sin(a)])
    axis = np.cross(e1, e2)

    def traj(t: np.ndarray) -> np.ndarray:
        ph = 2 * np.pi * frequency_hz * np.asarray(t)[:, None]
        return c + radius_mm * (np.cos(ph) * e1 + np.sin(ph) * e2)

    return traj, c, axis


def oscillation(
    frequency_hz: float, amplitude_mm: float, direction, centre_mm=(0.0, 0.0, 1500.0), phase_rad=0.3
):
    """1-D sinusoid ``centre + amplitude·sin(2πft + phase)·direction``."""
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    c = np.asarray(centre_mm, float)

    def traj(t: np.ndarray) -> np.ndarray:
        return c + amplitude_mm * np.sin(2 * np.pi * frequency_hz * np.asarray(t)[:, None] + phase_rad) * d

    return traj
