"""Rendering kernel of the simulated rolling-shutter camera: anti-aliased perspective discs, per-row time.

How a frame is made (see :meth:`drivers.sim.camera.SimCamera.render`):

1. **Shape once per marker per frame.** The image of a 3-D disc through a pinhole is an exact conic
   C = H⁻ᵀ·diag(1, 1, −1)·H⁻¹ with H = [r·e1, r·e2, c] in camera coordinates (normalised image plane).
   Lens distortion is applied to it as the local affine map (Jacobian) at the disc centre, and the conic is
   expressed in pixel offsets from the exactly projected 3-D centre, so the perspective shift of an
   ellipse's centre is kept. (The neglected second-order distortion across a 20-px disc is < 0.01 px.)
2. **Centre per row and per exposure sample.** Row y is exposed over [t_frame + y·line_time,
   + exposure]; the disc centre is projected (``cv2.projectPoints``, with distortion) at K instants inside
   each row's exposure (midpoint rule; K grows with the image motion during the exposure so that samples are
   ≤ 0.2 px apart). Between rows the disc therefore moves: a moving disc is drawn skewed, as the rows saw it.
3. **Coverage.** Each row is cut into 4 horizontal sub-scanlines; on each, the conic's chord [x_l, x_r] is
   solved in closed form and the exact covered length of every pixel is taken. Coverage is averaged over
   the sub-scanlines and the K samples (area anti-aliasing + time integration), blurred by a Gaussian PSF.
4. **Noise** (see ``NoiseModel``): the background with its read and shot noise comes from a pool of
   pre-generated noisy frames (2 × ~2 MB), picked per frame at a random row/column offset; the extra shot
   noise of the marker signal is drawn from a pool of 2²⁰ standard normals at a random offset. Honest
   caveat: the pools are finite, so noise is not independent over many thousands of frames (two frames
   may share shifted noise), and marker pixels carry the quantisation of the background once more
   (+1/12 DN² variance). Within a frame, and between the few frames any estimate combines, it behaves as
   fresh Gaussian read + shot noise; that is what makes rendering fast (no per-frame full-frame RNG).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from drivers.sim.render_kernel import chord_coverage

__all__ = [
    "NoiseModel", "conic_extents", "coverage_patches", "disc_conics", "exposure_samples", "project_points",
]

SUBSCANLINES = 4
MAX_EXPOSURE_SAMPLES = 64
SAMPLE_SPACING_PX = 0.2
_SUBSCANLINE_OFFSETS_PX = ((np.arange(SUBSCANLINES) + 0.5) / SUBSCANLINES - 0.5).astype(np.float32)


@dataclass(frozen=True)
class NoiseModel:
    """Sensor levels and noise in digital numbers (8-bit DN).

    Pixel value = level + N(0, read_noise_dn² + shot_noise_dn2_per_dn·level), rounded, clipped to 0..255.
    ``marker_level_dn`` < ``background_level_dn`` gives dark markers on a bright background.
    """

    background_level_dn: float = 30.0
    marker_level_dn: float = 220.0
    read_noise_dn: float = 2.0
    shot_noise_dn2_per_dn: float = 0.05
    pool_frames: int = 2
    pool_margin_px: int = 128

    def __post_init__(self) -> None:
        for name in ("background_level_dn", "marker_level_dn"):
            v = getattr(self, name)
            if not (0.0 <= v <= 255.0):
                raise ValueError(f"{name} must be within 0..255 DN, got {v!r}")
        for name in ("read_noise_dn", "shot_noise_dn2_per_dn"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0.0):
                raise ValueError(f"{name} must be a finite number ≥ 0, got {v!r}")
        if self.pool_frames < 1 or self.pool_margin_px < 1:
            raise ValueError(f"pool_frames and pool_margin_px must be ≥ 1, got {self.pool_frames}, "
                             f"{self.pool_margin_px}")

    def sigma_dn(self, level_dn: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Standard deviation of a pixel of mean ``level_dn`` (before quantisation)."""
        lv = np.maximum(np.asarray(level_dn, float), 0.0)
        sigma: NDArray[np.float64] = np.sqrt(self.read_noise_dn**2 + self.shot_noise_dn2_per_dn * lv)
        return sigma

    def background_pool(self, height_px: int, width_px: int, seed: int) -> NDArray[np.uint8]:
        """(pool_frames, height + margin, width + margin) uint8 noisy background frames."""
        rng = np.random.default_rng(seed)
        m = self.pool_margin_px
        shape = (self.pool_frames, height_px + m, width_px + m)
        noise = rng.standard_normal(shape, dtype=np.float32)
        noise *= np.float32(self.sigma_dn(self.background_level_dn))
        noise += np.float32(self.background_level_dn + 0.5)  # +0.5 then floor = round
        np.clip(noise, 0.0, 255.0, out=noise)
        return noise.astype(np.uint8)


def _cross(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Row-wise cross product of (M, 3) arrays (np.cross has a large per-call overhead)."""
    return np.column_stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]])


def disc_conics(centres_cam: NDArray[np.float64], normals_cam: NDArray[np.float64],
                radii_mm: NDArray[np.float64], jac_px: NDArray[np.float64]) -> NDArray[np.float64]:
    """Conics (M, 3, 3) of discs in pixel offsets from their projected centres, scaled so that C[2, 2] = −1.

    ``centres_cam`` (M, 3) and ``normals_cam`` (M, 3) in camera coordinates (mm), ``jac_px`` (M, 2, 2): the
    derivative of pixel position with respect to normalised undistorted image coordinates at each centre.
    """
    n = normals_cam / np.linalg.norm(normals_cam, axis=1, keepdims=True)
    helper = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    e1 = _cross(n, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = _cross(n, e1)
    hom = np.stack([radii_mm[:, None] * e1, radii_mm[:, None] * e2, centres_cam], axis=2)  # columns
    hinv = np.linalg.inv(hom)
    c_norm = np.einsum("mji,jk,mkl->mil", hinv, np.diag([1.0, 1.0, -1.0]), hinv)
    q0 = centres_cam[:, :2] / centres_cam[:, 2:3]
    t = np.zeros_like(c_norm)
    t[:, :2, :2] = np.linalg.inv(jac_px)
    t[:, :2, 2] = q0
    t[:, 2, 2] = 1.0
    c_pix: NDArray[np.float64] = np.einsum("mji,mjk,mkl->mil", t, c_norm, t)
    return c_pix / -c_pix[:, 2:3, 2:3]


def conic_extents(conics: NDArray[np.float64]) -> NDArray[np.float64]:
    """Bounding boxes (M, 4): x_min, x_max, y_min, y_max of the conics (pixel offsets)."""
    dual = np.linalg.inv(conics)
    out = np.empty((len(conics), 4))
    for axis in (0, 1):
        a, b, c = dual[:, axis, axis], dual[:, axis, 2], dual[:, 2, 2]
        root = np.sqrt(np.maximum(b * b - a * c, 0.0))
        lo, hi = (b - root) / c, (b + root) / c
        out[:, 2 * axis] = np.minimum(lo, hi)
        out[:, 2 * axis + 1] = np.maximum(lo, hi)
    return out


def exposure_samples(motion_px: NDArray[np.float64]) -> NDArray[np.int_]:
    """Number K of instants per row exposure for ``motion_px`` of image motion during it (powers of two,
    so that samples are ≤ 0.2 px apart; at most 64)."""
    need = np.maximum(1.0, np.asarray(motion_px, float) / SAMPLE_SPACING_PX)
    samples: NDArray[np.int_] = np.minimum(MAX_EXPOSURE_SAMPLES, 2 ** np.ceil(np.log2(need)).astype(int))
    return samples


def coverage_patches(conics: NDArray[np.float64], centres_px: NDArray[np.float64], row0: NDArray[np.int_],
                     col0: NDArray[np.int_], *, width_px: int, psf_sigma_px: float) -> NDArray[np.float32]:
    """Fraction of each pixel covered by the disc, averaged over exposure samples: (M, Hp, Wp) float32.

    ``centres_px`` (M, Hp, K, 2): projected disc centre for patch row r (image row row0 + r) at sample k.
    ``col0`` (M,): first image column of each patch.
    """
    m, hp = centres_px.shape[:2]
    # work relative to each patch's corner, in float32 (patch coordinates are small numbers)
    rel = (centres_px - np.stack([col0, row0], axis=1)[:, None, None, :]).astype(np.float32)
    cf = conics.astype(np.float32)
    coefficients = np.column_stack([cf[:, 0, 0], 2 * cf[:, 0, 1], 2 * cf[:, 0, 2], cf[:, 1, 1],
                                    2 * cf[:, 1, 2]])
    out = np.empty((m, hp, width_px), np.float32)
    chord_coverage(coefficients, rel, _SUBSCANLINE_OFFSETS_PX, out)
    if psf_sigma_px > 0:  # patches have ≥ 3σ of empty border, so one separable pass over the stack is exact
        flat = cv2.GaussianBlur(out.reshape(m * hp, width_px), (0, 0), sigmaX=psf_sigma_px,
                                sigmaY=psf_sigma_px, borderType=cv2.BORDER_CONSTANT)
        out = np.asarray(flat, dtype=np.float32).reshape(m, hp, width_px)  # (float32 in, float32 out)
    return out


def project_points(points: NDArray[np.float64], rvec: NDArray[np.float64], tvec: NDArray[np.float64],
                   camera_matrix: NDArray[np.float64], dist: NDArray[np.float64]) -> NDArray[np.float64]:
    """``cv2.projectPoints`` on (..., 3) points → (..., 2) pixels."""
    flat = np.ascontiguousarray(points.reshape(-1, 3), dtype=np.float64)
    if flat.shape[0] == 0:
        return np.zeros((*points.shape[:-1], 2))
    uv, _ = cv2.projectPoints(flat, rvec, tvec, camera_matrix, dist)
    return uv.reshape((*points.shape[:-1], 2))
