"""Test images of circular markers: anti-aliased discs/ellipses with blur and noise, exact truth.

A marker is rendered by supersampling its coverage (``supersample``² samples per pixel, analytic inside
test for an ellipse), scaled by its contrast, blurred by a Gaussian point-spread function and added to
a flat background; Gaussian noise is added to the whole frame and the result is rounded and clipped to
uint8. Pixel centres are integers and the centre of the top-left pixel is (0, 0), as in the stereo core.
This renderer is independent of the detector (no code shared) and of the camera twin in drivers/sim.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class Disc:
    """One marker: centre (u, v) px, semi-axes px, rotation deg of the first axis from +u, contrast DN."""

    u_px: float
    v_px: float
    a_px: float
    b_px: float | None = None  # None: a circle of radius a_px
    angle_deg: float = 0.0
    contrast_dn: float = 150.0


def coverage_patch(disc: Disc, *, top: int, left: int, height: int, width: int, supersample: int = 8):
    """Fraction (0..1) of each pixel of the patch [top:top+height, left:left+width] inside the ellipse."""
    s = supersample
    sub = (np.arange(s) + 0.5) / s - 0.5
    ys = (top + np.arange(height))[:, None] + sub[None, :]
    xs = (left + np.arange(width))[:, None] + sub[None, :]
    yy = ys.reshape(-1)[:, None] - disc.v_px
    xx = xs.reshape(-1)[None, :] - disc.u_px
    b = disc.a_px if disc.b_px is None else disc.b_px
    t = np.deg2rad(disc.angle_deg)
    xr = xx * np.cos(t) + yy * np.sin(t)
    yr = -xx * np.sin(t) + yy * np.cos(t)
    inside = (xr / disc.a_px) ** 2 + (yr / b) ** 2 <= 1.0
    return inside.reshape(height, s, width, s).mean(axis=(1, 3))


def render(
    shape: tuple[int, int],
    discs: list[Disc],
    *,
    background_dn: float = 20.0,
    blur_sigma_px: float = 0.8,
    noise_sigma_dn: float = 2.0,
    seed: int = 0,
    supersample: int = 8,
    occluders: list[tuple[float, float, float, float]] | None = None,
    dark: bool = False,
    return_float: bool = False,
):
    """Render ``discs`` on a (height, width) frame; returns uint8 (or the noiseless float image too).

    ``occluders``: rectangles (x0, y0, x1, y1) in px painted with the background level *before* the blur
    (an object in front of the marker). ``dark``: markers darker than the background (contrast is
    subtracted). With ``return_float`` the noise-free, unquantized image is returned as a second value.
    """
    height, width = shape
    clean = np.zeros(shape, dtype=np.float64)
    sign = -1.0 if dark else 1.0
    blur_margin = int(np.ceil(4 * blur_sigma_px)) + 2
    for disc in discs:
        r = max(disc.a_px, disc.b_px or disc.a_px) + blur_margin
        top, left = int(np.floor(disc.v_px - r)), int(np.floor(disc.u_px - r))
        bottom, right = int(np.ceil(disc.v_px + r)) + 1, int(np.ceil(disc.u_px + r)) + 1
        t0, l0 = max(top, 0), max(left, 0)
        b0, r0 = min(bottom, height), min(right, width)
        if b0 <= t0 or r0 <= l0:
            continue
        patch = coverage_patch(disc, top=top, left=left, height=bottom - top, width=right - left,
                               supersample=supersample)
        if occluders:
            for x0, y0, x1, y1 in occluders:
                ys = top + np.arange(bottom - top)[:, None]
                xs = left + np.arange(right - left)[None, :]
                patch = np.where((xs >= x0) & (xs <= x1) & (ys >= y0) & (ys <= y1), 0.0, patch)
        patch = patch * disc.contrast_dn * sign
        if blur_sigma_px > 0:
            patch = cv2.GaussianBlur(patch, (0, 0), blur_sigma_px, borderType=cv2.BORDER_CONSTANT)
        clean[t0:b0, l0:r0] += patch[t0 - top : b0 - top, l0 - left : r0 - left]
    clean += background_dn
    rng = np.random.default_rng(seed)
    noisy = clean + rng.normal(0.0, noise_sigma_dn, size=shape) if noise_sigma_dn > 0 else clean
    image = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
    return (image, clean) if return_float else image


def centroid_noise_px(clean: np.ndarray, background_dn: float, centre_uv: tuple[float, float], *,
                      noise_sigma_dn: float, floor_dn: float, half_px: int) -> float:
    """Predicted 1-σ noise of an intensity-weighted centroid (per axis, the larger of u and v).

    σ_c = σ_n·sqrt(Σ_support (x − x̄)²) / Σ w, with w = max(I − bg − floor, 0) on the noiseless image and
    the support {w > 0} in a (2·half_px+1)² window around the true centre; first-order propagation of
    independent pixel noise through x̄ = Σ w x / Σ w.
    """
    u, v = centre_uv
    r0, c0 = round(v), round(u)
    win = clean[r0 - half_px : r0 + half_px + 1, c0 - half_px : c0 + half_px + 1]
    w = np.maximum(win - background_dn - floor_dn, 0.0)
    ys, xs = np.mgrid[r0 - half_px : r0 + half_px + 1, c0 - half_px : c0 + half_px + 1]
    support = w > 0
    mass = w.sum()
    xbar = (w * xs).sum() / mass
    ybar = (w * ys).sum() / mass
    su = noise_sigma_dn * np.sqrt(((xs - xbar) ** 2)[support].sum()) / mass
    sv = noise_sigma_dn * np.sqrt(((ys - ybar) ** 2)[support].sum()) / mass
    return float(max(su, sv))
