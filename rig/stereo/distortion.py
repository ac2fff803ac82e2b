"""Brown–Conrady lens distortion (k1, k2, p1, p2) in normalized camera coordinates, as OpenCV defines it.

Normalized coordinates are ``x = K⁻¹·[u, v, 1]`` of the ideal pinhole projection (dimensionless, x/z
and y/z in the camera frame). With ``r² = x² + y²``::

    x_d = x·(1 + k1·r² + k2·r⁴) + 2·p1·x·y + p2·(r² + 2·x²)
    y_d = y·(1 + k1·r² + k2·r⁴) + p1·(r² + 2·y²) + 2·p2·x·y

All functions are vectorized over points: ``xy`` is ``(N, 2)``.
"""

from __future__ import annotations

import numpy as np

from rig.stereo._arrays import BoolArray, FloatArray
from rig.stereo.errors import DistortionError


def distort(xy: FloatArray, coeffs: FloatArray) -> FloatArray:
    """Apply the distortion to normalized points ``xy`` (N, 2); returns distorted normalized points."""
    k1, k2, p1, p2 = coeffs
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + k2 * r2)
    out = np.empty((xy.shape[0], 2))  # filled column by column: np.stack costs more than the arithmetic
    out[:, 0] = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    out[:, 1] = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return out


def distort_jacobian(xy: FloatArray, coeffs: FloatArray) -> FloatArray:
    """∂(x_d, y_d)/∂(x, y) at normalized points ``xy`` (N, 2); returns (N, 2, 2)."""
    k1, k2, p1, p2 = coeffs
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + k2 * r2)
    dradial = 2.0 * (k1 + 2.0 * k2 * r2)  # ∂radial/∂x = x·dradial, ∂radial/∂y = y·dradial
    J = np.empty((xy.shape[0], 2, 2))
    J[:, 0, 0] = radial + x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    J[:, 0, 1] = x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    J[:, 1, 0] = x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    J[:, 1, 1] = radial + y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    return J


def undistort(
    xy_d: FloatArray, coeffs: FloatArray, *, strict: bool = True, tol: float = 1e-12, max_iter: int = 50
) -> FloatArray:
    """Invert :func:`distort` by Newton's method, vectorized; NaN rows stay NaN.

    A point fails when Newton does not reproduce it or lands where the model folds over (det ∂x_d/∂x ≤ 0:
    far outside the calibrated field, where several or no undistorted points map to it). ``strict=True``
    raises :class:`DistortionError` for any failed point; ``strict=False`` returns NaN for those rows.
    """
    xy = xy_d.copy()
    active: BoolArray = np.all(np.isfinite(xy_d), axis=1)
    finite = active.copy()
    for _ in range(max_iter):
        if not active.any():
            break
        pts = xy[active]
        resid = distort(pts, coeffs) - xy_d[active]
        J = distort_jacobian(pts, coeffs)
        det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
        step = np.empty_like(resid)
        with np.errstate(invalid="ignore", divide="ignore"):
            step[:, 0] = (J[:, 1, 1] * resid[:, 0] - J[:, 0, 1] * resid[:, 1]) / det
            step[:, 1] = (J[:, 0, 0] * resid[:, 1] - J[:, 1, 0] * resid[:, 0]) / det
        idx = np.nonzero(active)[0]
        moving = np.isfinite(step).all(axis=1)
        xy[idx[moving]] = pts[moving] - step[moving]
        active[idx[~moving | (np.abs(step).max(axis=1) < tol)]] = False
    with np.errstate(invalid="ignore"):
        reproduced = np.abs(distort(xy, coeffs) - xy_d).max(axis=1) < 1e-9
        J = distort_jacobian(xy, coeffs)
        unfolded = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0] > 0
    failed = finite & ~(reproduced & unfolded)
    if failed.any():
        if strict:
            raise DistortionError(
                f"{int(failed.sum())} points cannot be undistorted with coefficients "
                f"{[round(float(c), 6) for c in coeffs]}: they lie outside the field where the lens model is "
                "invertible; drop them, or recalibrate with points covering that part of the image "
                "(or fit fewer terms, e.g. distortion='k1')"
            )
        xy[failed] = np.nan
    return xy
