"""Input checks and Hartley normalization shared by the DLT, epipolar and triangulation modules.

Every public function of the stereo core validates its arrays here, so that bad input raises an
:class:`~rig.stereo.errors.InputArrayError` naming the argument, the offending value and what is allowed.
"""

from __future__ import annotations

from typing import Protocol, TypeAlias, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike

from rig.stereo._arrays import FloatArray
from rig.stereo.errors import InputArrayError


def as_points(
    array: object,
    name: str,
    dim: int,
    *,
    allow_nan: bool = False,
    allow_empty: bool = False,
) -> FloatArray:
    """Return ``array`` as a float64 ``(N, dim)`` array after checking dtype, shape and finiteness.

    ``allow_nan=True`` admits NaN (meaning "not observed") but still refuses ±inf. A single point of
    shape ``(dim,)`` is refused: pass ``(1, dim)`` so that a transposed array cannot slip through.
    """
    arr = np.asarray(array)
    if arr.dtype == object or not (
        np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)
    ):
        raise InputArrayError(
            f"{name}: dtype {arr.dtype} is not allowed; pass a real numeric array (float64 or integer) "
            f"of shape (N, {dim})"
        )
    if arr.ndim != 2 or arr.shape[1] != dim:
        hint = " (it looks transposed; pass .T)" if arr.ndim == 2 and arr.shape[0] == dim else ""
        raise InputArrayError(f"{name}: shape {arr.shape} is not allowed; expected (N, {dim}){hint}")
    if arr.shape[0] == 0 and not allow_empty:
        raise InputArrayError(f"{name}: the array is empty; pass at least one point of shape (N, {dim})")
    arr = arr.astype(np.float64, copy=False)
    bad = np.isinf(arr) if allow_nan else ~np.isfinite(arr)
    if bad.any():
        rows = np.unique(np.nonzero(bad)[0])
        what = "±inf" if allow_nan else "NaN or ±inf"
        raise InputArrayError(
            f"{name}: rows {rows[:10].tolist()}{' …' if rows.size > 10 else ''} hold {what}; "
            f"remove those points or fill them with measured values"
            + ("" if allow_nan else " (NaN is not allowed here)")
        )
    return arr


def as_projection(P: object, name: str = "P") -> FloatArray:
    """Return a finite float64 ``(3, 4)`` projection matrix with a non-singular left 3×3 block."""
    arr = np.asarray(P)
    if arr.dtype == object or not (
        np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)
    ):
        raise InputArrayError(f"{name}: dtype {arr.dtype} is not allowed; pass a float (3, 4) matrix")
    if arr.shape != (3, 4):
        raise InputArrayError(f"{name}: shape {arr.shape} is not allowed; a projection matrix is (3, 4)")
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all():
        raise InputArrayError(f"{name}: holds NaN or inf; recalibrate the camera")
    if abs(np.linalg.det(arr[:, :3])) <= 1e-12 * np.linalg.norm(arr[:, :3]) ** 3:
        raise InputArrayError(
            f"{name}: the left 3×3 block is singular (camera at infinity or not a camera); recalibrate"
        )
    return arr


@runtime_checkable
class HasProjection(Protocol):
    """A calibrated camera (e.g. :class:`rig.stereo.dlt.DLTCamera`): its 3×4 projection matrix, mm → px."""

    @property
    def P(self) -> FloatArray: ...  # noqa: N802


#: A camera as the estimators take it: an object with ``.P`` or the 3×4 matrix itself.
Camera: TypeAlias = HasProjection | ArrayLike


def projection_matrix(camera: object, name: str = "camera") -> FloatArray:
    """3×4 float64 projection matrix (mm → px) of ``camera``: an object with ``.P`` or the matrix itself,
    checked by :func:`as_projection` (``name`` is the argument named in its error)."""
    return as_projection(camera.P if isinstance(camera, HasProjection) else camera, name)


def similarity_2d(uv: FloatArray) -> FloatArray:
    """Hartley normalization of image points: 3×3 T with T·[u,v,1] centred and mean distance √2."""
    centre = np.nanmean(uv, axis=0)
    dist = np.sqrt(np.nansum((uv - centre) ** 2, axis=1))
    mean = float(np.nanmean(dist)) if dist.size else 0.0
    scale = np.sqrt(2.0) / mean if mean > 0 else 1.0
    return np.array([[scale, 0.0, -scale * centre[0]], [0.0, scale, -scale * centre[1]], [0.0, 0.0, 1.0]])


def similarity_3d(xyz: FloatArray) -> FloatArray:
    """Hartley normalization of world points: 4×4 T with T·[x,y,z,1] centred and mean distance √3."""
    centre = np.nanmean(xyz, axis=0)
    dist = np.sqrt(np.nansum((xyz - centre) ** 2, axis=1))
    mean = float(np.nanmean(dist)) if dist.size else 0.0
    scale = np.sqrt(3.0) / mean if mean > 0 else 1.0
    T = np.eye(4) * scale
    T[3, 3] = 1.0
    T[:3, 3] = -scale * centre
    return T


def homogeneous(points: FloatArray) -> FloatArray:
    """Append a column of ones: (N, d) → (N, d + 1)."""
    return np.concatenate([points, np.ones((points.shape[0], 1))], axis=1)


def principal_spread(points: FloatArray) -> FloatArray:
    """Singular values of the centred points divided by the largest one (scale-free, descending).

    For calibration points, ``[1, a, b]``: ``b ≈ 0`` means coplanar, ``a ≈ 0`` collinear.
    """
    centred = points - points.mean(axis=0)
    s: FloatArray = np.linalg.svd(centred, compute_uv=False)
    if s[0] == 0:
        return np.zeros_like(s)
    spread: FloatArray = s / s[0]
    return spread
