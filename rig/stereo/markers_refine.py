"""Sub-pixel measurement of markers, batched over square windows of one size.

Every candidate is measured in a square window of ``W = 2·half_px + 1`` pixels around an integer pixel
centre; all windows of one call share one size and are measured by one call of the compiled kernel
(:mod:`rig.stereo.markers_kernel`, one per frame when the windows lie in several frames) — no per-marker
Python except the optional ellipse fit.

Per window, in "polarity space" (bright markers as they are, dark markers as 255 − I):

* background ``bg`` = a plane fitted to the outer 2-pixel ring (pixels more than 4 robust spreads from
  its median left out), noise ``σ`` = RMS residual of that fit (:mod:`rig.stereo.markers_kernel`);
* signal ``d = I − bg``; support = the 8-connected region of ``d > 3σ`` holding the marker (the centre
  pixel's region, else the strong region nearest the centre), so a neighbouring marker is ignored;
* centroid weights ``w = d − 3σ`` on the support (background-subtracted intensity with a noise floor:
  an unclipped ``max(d, 0)`` over the window would add ≈ 0.4 σ of mass per background pixel and pull
  the centre towards the window's centre);
* contrast = the plateau of ``d``: its mean over the pixels above 85 % of the peak (DN);
  area = Σ w / (contrast − 3σ) (px², exact for a flat disc, and nearly so for a blurred one: only the
  skirt below 3σ is missed);
  roundness = √(λmin/λmax) of the weighted second moments (1 for a disc, minor/major axis ratio for
  an ellipse);
* skewness = squared third central moments over det(Σ)^(3/2) (Mardia's b1 for a round blob): 0 for any
  centrally symmetric blob — a disc, an ellipse, a disc seen obliquely — and large for a disc with a
  piece missing;
* optionally, sub-pixel edge points where ``d`` crosses contrast/2 (linear interpolation between pixel
  centres) fitted with an ellipse (``cv2.fitEllipseDirect``): its centre, and the RMS distance of the
  points from it (a few hundredths of a pixel for a whole disc) (:mod:`rig.stereo.markers_outline`).

Coordinates: pixel centres are integers, the centre of the top-left pixel is (0, 0); u = column, v = row.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig.stereo.markers_outline import edge_points, fit_ellipses


@dataclass
class Measured:
    """Per-window measurements (arrays of length K); NaN where a window held no marker."""

    u_px: np.ndarray
    v_px: np.ndarray
    area_px: np.ndarray
    roundness: np.ndarray
    contrast: np.ndarray
    background: np.ndarray  # DN at the window's centre pixel, polarity space
    sigma: np.ndarray  # background noise, DN
    skewness: np.ndarray  # third-moment asymmetry of the weights (0 for a centrally symmetric blob)
    u_ellipse_px: np.ndarray  # centre of the ellipse fitted to the outline (NaN unless fitted)
    v_ellipse_px: np.ndarray
    edge_rms_px: np.ndarray  # RMS distance of the outline points from that ellipse
    edge_noise_px: np.ndarray  # the part of edge_rms_px that the background noise σ explains
    skewness_noise: np.ndarray  # skewness a whole marker gets from its noise σ (first order; see markers.py)
    border: np.ndarray  # bool: the window reaches outside the image
    saturated: np.ndarray  # bool: a support pixel is clipped (255 bright / 0 dark)
    cramped: np.ndarray  # bool: the support reaches the background ring (the window is too small)

    @classmethod
    def empty(cls) -> Measured:
        """Measurements of no window (all arrays of length 0)."""
        flags = ("border", "saturated", "cramped")
        return cls(**{key: np.zeros(0, dtype=bool if key in flags else float)
                      for key in cls.__dataclass_fields__})


def measure_windows(image: np.ndarray, rows: np.ndarray, cols: np.ndarray, half_px: int, *,
                    dark: bool, fit_ellipse: bool = False) -> Measured:
    """Measure the marker in each window centred on the integer pixel ``(rows[i], cols[i])``.

    ``image``: uint8 frame; ``dark``: dark markers on a bright background;
    ``fit_ellipse``: also fit the outline (``u_ellipse_px``, ``v_ellipse_px``, ``edge_rms_px``; NaN
    otherwise). Windows without any support above the noise floor give NaN measurements.
    """
    n = len(rows)
    if n == 0:
        return Measured.empty()
    import rig.stereo.markers_kernel as kernel  # numba: loaded by the first measurement, not at import

    w = 2 * half_px + 1
    out = np.empty((kernel.N_OUT, n))
    flags = np.empty((3, n), dtype=bool)
    signal = np.empty((n if fit_ellipse else 0, w, w), dtype=np.float32)
    rows, cols = np.ascontiguousarray(rows, dtype=np.int64), np.ascontiguousarray(cols, dtype=np.int64)
    kernel.measure_range(_frame(image), rows, cols, 0, n, half_px, dark, out, flags, signal)
    u_e, v_e, edge_rms, edge_noise = np.full((4, n), np.nan)
    contrast = out[kernel.OUT_CONTRAST]
    if fit_ellipse:
        level = np.where(np.isfinite(contrast), 0.5 * contrast, np.inf).astype(np.float32)
        centre, edge_rms, edge_noise = fit_ellipses(*edge_points(signal, level), n)
        edge_noise *= out[kernel.OUT_SIGMA]
        u_e = cols + centre[:, 0] - half_px
        v_e = rows + centre[:, 1] - half_px
    return Measured(
        u_px=out[kernel.OUT_U], v_px=out[kernel.OUT_V], area_px=out[kernel.OUT_AREA],
        roundness=out[kernel.OUT_ROUND], contrast=contrast, background=out[kernel.OUT_BACKGROUND],
        sigma=out[kernel.OUT_SIGMA], skewness=out[kernel.OUT_SKEW], u_ellipse_px=u_e, v_ellipse_px=v_e,
        edge_rms_px=edge_rms, edge_noise_px=edge_noise, skewness_noise=out[kernel.OUT_SKEW_NOISE],
        border=flags[kernel.FLAG_ROW_BORDER], saturated=flags[kernel.FLAG_ROW_SATURATED],
        cramped=flags[kernel.FLAG_ROW_CRAMPED],
    )


def _frame(image: object) -> np.ndarray:
    """A frame as the kernel takes it: 2-D uint8, C-contiguous (a copy only for a strided view)."""
    return np.ascontiguousarray(image, dtype=np.uint8)
