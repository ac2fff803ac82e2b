"""Synthetic stereo scenes for the stereo-core tests, projected with OpenCV (never with our own DLT).

A calibration plate of circular-marker centres (a grid in the plane z = const) is slid along its normal
(world z) to several known positions, as in the paper; two 1920×1080 cameras about 1.5 m away view it.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

IMAGE_SIZE = (1920, 1080)


@dataclass(frozen=True)
class TrueCamera:
    """A ground-truth OpenCV camera: K, distortion (k1, k2, p1, p2), world → camera rvec/tvec."""

    K: np.ndarray
    dist: np.ndarray
    rvec: np.ndarray
    tvec: np.ndarray

    def project(self, xyz_mm: np.ndarray) -> np.ndarray:
        uv, _ = cv2.projectPoints(
            np.asarray(xyz_mm, np.float64).reshape(-1, 1, 3), self.rvec, self.tvec, self.K, self.dist
        )
        return uv.reshape(-1, 2)

    def jacobian(self, xyz_mm: np.ndarray, h_mm: float = 1e-3) -> np.ndarray:
        """∂(u, v)/∂(x, y, z) (N, 2, 3) by central differences of cv2.projectPoints."""
        xyz = np.asarray(xyz_mm, np.float64)
        J = np.empty((xyz.shape[0], 2, 3))
        for k in range(3):
            dx = np.zeros(3)
            dx[k] = h_mm
            J[:, :, k] = (self.project(xyz + dx) - self.project(xyz - dx)) / (2 * h_mm)
        return J

    @property
    def centre_mm(self) -> np.ndarray:
        R = cv2.Rodrigues(self.rvec)[0]
        return -R.T @ self.tvec.ravel()


def look_at_camera(
    centre_mm: np.ndarray, target_mm: np.ndarray, *, f_px: float = 2400.0, dist: tuple = (0, 0, 0, 0)
) -> TrueCamera:
    """A camera at ``centre_mm`` looking at ``target_mm``; principal point at the image centre."""
    z = np.asarray(target_mm, float) - np.asarray(centre_mm, float)
    z /= np.linalg.norm(z)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    K = np.array(
        [[f_px, 0.0, (IMAGE_SIZE[0] - 1) / 2], [0.0, f_px * 1.001, (IMAGE_SIZE[1] - 1) / 2 + 7.0], [0, 0, 1]]
    )
    return TrueCamera(
        K, np.asarray(dist, float), cv2.Rodrigues(R)[0], (-R @ np.asarray(centre_mm, float)).reshape(3, 1)
    )


def plate_points(
    n_cols: int = 9, n_rows: int = 7, pitch_mm: float = 60.0, positions_mm=(0, 50, 100, 150, 200)
):
    """Marker centres of the plate (plane z = position) at each slid position; (n_cols·n_rows·P, 3) mm."""
    gx, gy = np.meshgrid(np.arange(n_cols) * pitch_mm, np.arange(n_rows) * pitch_mm)
    grid = np.stack([gx.ravel(), gy.ravel()], axis=1)
    return np.concatenate([np.column_stack([grid, np.full(len(grid), z)]) for z in positions_mm])


VOLUME_MIN = np.array([0.0, 0.0, 0.0])
VOLUME_MAX = np.array([480.0, 360.0, 200.0])
TARGET = (VOLUME_MIN + VOLUME_MAX) / 2


def stereo_pair(baseline_mm: float = 600.0, distance_mm: float = 1500.0, dist: tuple = (0, 0, 0, 0)):
    """Two convergent cameras ``distance_mm`` in front of the plate (−z side), ``baseline_mm`` apart."""
    half = baseline_mm / 2
    back = np.sqrt(distance_mm**2 - half**2)
    a = look_at_camera(TARGET + np.array([-half, -80.0, -back]), TARGET, dist=dist)
    b = look_at_camera(
        TARGET + np.array([half, 60.0, -back]), TARGET, f_px=2300.0, dist=tuple(-np.asarray(dist) * 0.8)
    )
    return a, b


def volume_points(n: int, rng: np.random.Generator) -> np.ndarray:
    """Independent points uniformly inside the calibrated volume, mm."""
    return VOLUME_MIN + rng.random((n, 3)) * (VOLUME_MAX - VOLUME_MIN)


def point_covariances_mm2(cameras: list[TrueCamera], xyz_mm: np.ndarray, sigma_px: float) -> np.ndarray:
    """Covariance (N, 3, 3) of a point triangulated from pixel noise σ through the TRUE cameras: σ²(JᵀJ)⁻¹."""
    H = sum(np.einsum("nki,nkj->nij", J, J) for J in (c.jacobian(xyz_mm) for c in cameras))
    return sigma_px**2 * np.linalg.inv(H)


def noise_floor_mm(cameras: list[TrueCamera], xyz_mm: np.ndarray, sigma_px: float) -> float:
    """RMS 3D error that pixel noise σ alone implies with the TRUE cameras: sqrt(mean trace σ²(JᵀJ)⁻¹)."""
    cov = point_covariances_mm2(cameras, xyz_mm, sigma_px)
    return float(np.sqrt(np.mean(np.trace(cov, axis1=1, axis2=2))))
