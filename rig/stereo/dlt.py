"""DLT camera calibration (the paper's equation 1, A·b = 0) with optional nonlinear refinement.

World coordinates are in mm, image coordinates in pixels (origin at the centre of the top-left pixel).
The linear solution is the paper's homogeneous form ("Convention B", 12 unknowns, ‖b‖ = 1, right
singular vector of the smallest singular value) computed on Hartley-normalized coordinates. Stored
coefficient files of other tools (vaila, Argus, DLTdv) use the 11-parameter form with L12 = 1
("Convention A"): :func:`solve_dlt11`, :func:`dlt11_from_P` and :func:`P_from_dlt11` handle it.

The refinement (``refine=True``) minimises the reprojection error in pixels over P, and with
``distortion=True`` also over (k1, k2, p1, p2) of :mod:`rig.stereo.distortion`, applied in the
normalized camera coordinates of K from the RQ decomposition of P — the same model as OpenCV.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Literal, overload

import numpy as np
import scipy.linalg
import scipy.optimize

from rig.stereo._arrays import BoolArray, FloatArray
from rig.stereo.control_points import check_calibration_input, design_rows
from rig.stereo.distortion import distort, distort_jacobian, undistort
from rig.stereo.dlt11 import P_from_dlt11, dlt11_from_P
from rig.stereo.errors import CalibrationFormatError, DegenerateCalibrationError, InputArrayError
from rig.stereo.normalize import (
    as_points,
    as_projection,
    homogeneous,
    similarity_2d,
    similarity_3d,
)

CONVENTIONS = ("homogeneous-svd", "l12-lstsq", "refined", "external")


def _normalized_p(P: FloatArray) -> FloatArray:
    """Scale P so that ‖m3‖ = 1 and det(M) > 0: then P[2]·[X,1] is the depth in mm in front of the camera."""
    norm = np.linalg.norm(P[2, :3])
    if abs(norm - 1.0) > 4 * np.finfo(float).eps:  # idempotent, so from_dict(to_dict()) is bit-exact
        P = P / norm
    return -P if np.linalg.det(P[:, :3]) < 0 else P


@dataclass(frozen=True, eq=False)
class DLTCamera:
    """A calibrated camera: 3×4 projection matrix P (mm → px) and optional lens distortion.

    ``residuals_px`` (N, 2) are *projected − observed* on the calibration points; ``convention`` says
    how P was obtained (one of :data:`CONVENTIONS`).
    """

    P: FloatArray
    image_size: tuple[int, int] = (1920, 1080)
    distortion: tuple[float, float, float, float] | None = None
    residuals_px: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    convention: str = "homogeneous-svd"
    refined: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "P", _normalized_p(as_projection(self.P)))
        size = tuple(self.image_size)
        if len(size) != 2 or not all(isinstance(v, int | np.integer) and v > 0 for v in size):
            raise InputArrayError(
                f"image_size={self.image_size!r}: pass two positive integers (width_px, height_px)"
            )
        object.__setattr__(self, "image_size", (int(size[0]), int(size[1])))
        if self.distortion is not None:
            d = tuple(float(v) for v in self.distortion)
            if len(d) != 4 or not all(math.isfinite(v) for v in d):
                raise InputArrayError(
                    f"distortion={self.distortion!r}: pass four finite numbers (k1, k2, p1, p2)"
                )
            object.__setattr__(self, "distortion", None if not any(d) else d)
        res = as_points(self.residuals_px, "residuals_px", 2, allow_empty=True)
        object.__setattr__(self, "residuals_px", res)
        if self.convention not in CONVENTIONS:
            raise InputArrayError(f"convention={self.convention!r}: allowed are {CONVENTIONS}")

    # ----------------------------------------------------------------- figures
    @property
    def n_points(self) -> int:
        return int(self.residuals_px.shape[0])

    @property
    def residuals(self) -> FloatArray:
        """Alias of ``residuals_px`` (DESIGN.md's public surface)."""
        return self.residuals_px

    @property
    def rms_px(self) -> float:
        """RMS reprojection error per point (Euclidean) on the calibration points, px; NaN if none."""
        if self.n_points == 0:
            return math.nan
        return float(np.sqrt(np.mean(np.sum(self.residuals_px**2, axis=1))))

    @property
    def max_px(self) -> float:
        """Largest reprojection error of a calibration point, px; NaN if none."""
        if self.n_points == 0:
            return math.nan
        return float(np.sqrt(np.sum(self.residuals_px**2, axis=1)).max())

    # ----------------------------------------------------------------- geometry
    def decompose(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """RQ-decompose P = λ·K·[R | −R·C]: K upper-triangular with positive diagonal and K[2,2] = 1,
        R a proper rotation (world → camera), C the camera centre in mm."""
        M = self.P[:, :3]
        K, R = scipy.linalg.rq(M)
        D = np.diag(np.sign(np.diag(K)))
        K, R = K @ D, D @ R  # det(R) = det(M) / det(K) > 0 because P is normalized to det(M) > 0
        centre = np.asarray(-np.linalg.solve(M, self.P[:, 3]), dtype=np.float64)
        return K / K[2, 2], R, centre

    @property
    def centre_mm(self) -> FloatArray:
        return np.asarray(-np.linalg.solve(self.P[:, :3], self.P[:, 3]), dtype=np.float64)

    @cached_property
    def _k(self) -> FloatArray:
        return self.decompose()[0]

    def project(self, xyz_mm: object) -> FloatArray:
        """Project world points (N, 3) mm to pixels (N, 2), with distortion if any; NaN rows stay NaN."""
        return self.project_with_jacobian(xyz_mm, jacobian=False)[0]

    @overload
    def project_with_jacobian(
        self, xyz_mm: object, *, jacobian: Literal[True] = True
    ) -> tuple[FloatArray, FloatArray]: ...

    @overload
    def project_with_jacobian(
        self, xyz_mm: object, *, jacobian: Literal[False]
    ) -> tuple[FloatArray, None]: ...

    def project_with_jacobian(
        self, xyz_mm: object, *, jacobian: bool = True
    ) -> tuple[FloatArray, FloatArray | None]:
        """Pixels (N, 2) and, if asked, ∂(u, v)/∂(x, y, z) (N, 2, 3) in px/mm."""
        xyz = as_points(xyz_mm, "xyz_mm", 3, allow_nan=True, allow_empty=True)
        x = xyz @ self.P[:, :3].T + self.P[:, 3]
        uv = x[:, :2] / x[:, 2:3]
        J: FloatArray | None = None
        if jacobian:
            J = (self.P[None, :2, :3] - uv[:, :, None] * self.P[None, 2:3, :3]) / x[:, 2, None, None]
        if self.distortion is None:
            return uv, J
        K = self._k
        A, Ainv = K[:2, :2], np.linalg.inv(K[:2, :2])
        xy = (uv - K[:2, 2]) @ Ainv.T
        coeffs = np.asarray(self.distortion)
        uv_d = distort(xy, coeffs) @ A.T + K[:2, 2]
        if J is not None:
            Jn = np.einsum("ij,njk->nik", Ainv, J)  # ∂(x, y)/∂X
            Jd = distort_jacobian(xy, coeffs)
            Jn = Jd[:, :, :1] * Jn[:, None, 0, :] + Jd[:, :, 1:] * Jn[:, None, 1, :]
            J = np.einsum("ij,njk->nik", A, Jn)
        return uv_d, J

    def undistort_px(self, uv_px: object, *, strict: bool = True) -> FloatArray:
        """Observed pixels (N, 2) → ideal pinhole pixels of P (identity without distortion); NaN kept.

        Pixels outside the field where the lens model is invertible raise :class:`DistortionError`, or
        become NaN with ``strict=False``."""
        uv = as_points(uv_px, "uv_px", 2, allow_nan=True, allow_empty=True)
        if self.distortion is None:
            return uv
        K = self._k
        A = K[:2, :2]
        xy_d = (uv - K[:2, 2]) @ np.linalg.inv(A).T
        return undistort(xy_d, np.asarray(self.distortion), strict=strict) @ A.T + K[:2, 2]

    # ----------------------------------------------------------------- conventions and storage
    def dlt11(self, *, length_unit_mm: float = 1.0) -> FloatArray:
        """The 11 coefficients L1…L11 (Convention A, L12 = 1) for world units of ``length_unit_mm``."""
        return dlt11_from_P(self.P, length_unit_mm=length_unit_mm)

    @classmethod
    def from_dlt11(
        cls, coefficients: object, *, length_unit_mm: float = 1.0, image_size: tuple[int, int] = (1920, 1080)
    ) -> DLTCamera:
        """A camera from stored L1…L11 whose world unit is ``length_unit_mm`` (1000 for metres)."""
        return cls(
            P_from_dlt11(coefficients, length_unit_mm=length_unit_mm), image_size, convention="external"
        )

    def to_dict(self) -> dict[str, Any]:
        """The ``calibration.json`` entry (plain JSON types; :meth:`from_dict` inverts it exactly)."""
        return {
            "P": self.P.tolist(),
            "image_size": list(self.image_size),
            "distortion": None if self.distortion is None else list(self.distortion),
            "distortion_model": "opencv-k1k2p1p2-normalized",
            "residuals_rms_px": None if self.n_points == 0 else self.rms_px,
            "residuals_max_px": None if self.n_points == 0 else self.max_px,
            "residuals_px": self.residuals_px.tolist(),
            "n_points": self.n_points,
            "convention": self.convention,
            "refined": self.refined,
            "units": {"world": "mm", "image": "px"},
            # Informational (ignored by from_dict): check them against the lens and the rig, since a low
            # reprojection error alone does not prove a sound calibration.
            "intrinsics_px": self.intrinsics_px(),
            "centre_mm": self.centre_mm.tolist(),
        }

    def intrinsics_px(self) -> dict[str, float]:
        """fx, fy, skew, cx, cy of K in px (from :meth:`decompose`), for plausibility checks."""
        K = self._k
        return {
            "fx_px": float(K[0, 0]),
            "fy_px": float(K[1, 1]),
            "skew_px": float(K[0, 1]),
            "cx_px": float(K[0, 2]),
            "cy_px": float(K[1, 2]),
        }

    @classmethod
    def from_dict(cls, d: object) -> DLTCamera:
        """Rebuild a camera from :meth:`to_dict` output; :class:`CalibrationFormatError` if malformed."""
        if not isinstance(d, dict):
            raise CalibrationFormatError(f"a camera entry must be a JSON object, got {type(d).__name__}")
        missing = [k for k in ("P", "image_size") if k not in d]
        if missing:
            raise CalibrationFormatError(
                f"camera entry lacks {missing}; it needs at least 'P' (3×4) and 'image_size'"
            )
        try:
            res = np.asarray(d.get("residuals_px") or np.zeros((0, 2)), dtype=np.float64).reshape(-1, 2)
            cam = cls(
                P=np.asarray(d["P"], dtype=np.float64),
                image_size=tuple(d["image_size"]),
                distortion=d.get("distortion"),
                residuals_px=res,
                convention=d.get("convention", "external"),
                refined=bool(d.get("refined", False)),
            )
        except (InputArrayError, TypeError, ValueError) as exc:
            raise CalibrationFormatError(f"camera entry is malformed: {exc}") from exc
        if "n_points" in d and d["n_points"] != cam.n_points:
            raise CalibrationFormatError(
                f"n_points={d['n_points']} but residuals_px has {cam.n_points} rows; the entry was edited"
            )
        return cam


def _linear_p(xyz: FloatArray, uv: FloatArray, normalize: bool = True) -> FloatArray:
    Tw, Ti = (similarity_3d(xyz), similarity_2d(uv)) if normalize else (np.eye(4), np.eye(3))
    xyz_n = (homogeneous(xyz) @ Tw.T)[:, :3]
    uv_n = (homogeneous(uv) @ Ti.T)[:, :2]
    _, s, Vt = np.linalg.svd(design_rows(xyz_n, uv_n), full_matrices=False)
    if s[-2] <= 1e-9 * s[0]:
        raise DegenerateCalibrationError(
            "the calibration equations have no unique solution (several cameras fit the points): "
            "the control points are in a critical configuration; add points at other positions"
        )
    return np.linalg.solve(Ti, Vt[-1].reshape(3, 4)) @ Tw


def _camera(
    P: FloatArray,
    xyz: FloatArray,
    uv: FloatArray,
    image_size: tuple[int, int],
    *,
    convention: str,
    refined: bool,
    distortion: tuple[float, float, float, float] | None = None,
) -> DLTCamera:
    """The camera of ``P`` with its reprojection residuals on the control points (px)."""
    cam = DLTCamera(P, image_size, distortion=distortion, convention=convention, refined=refined)
    return DLTCamera(
        cam.P,
        cam.image_size,
        cam.distortion,
        cam.project(xyz) - uv,
        convention=cam.convention,
        refined=cam.refined,
    )


def calibrate_dlt(
    xyz_mm: object,
    uv_px: object,
    *,
    refine: bool = False,
    distortion: bool | str = False,
    image_size: tuple[int, int] = (1920, 1080),
    normalize: bool = True,
) -> DLTCamera:
    """Calibrate one camera from ≥ 6 non-coplanar control points.

    ``xyz_mm`` (N, 3) are known world positions in mm, ``uv_px`` (N, 2) their measured image positions.
    The linear step is the paper's A·b = 0 by SVD on Hartley-normalized coordinates. ``refine=True``
    then minimises the pixel reprojection error over P; ``distortion`` (implies refinement) also fits
    lens distortion: ``True`` or ``"k1k2p1p2"`` all four coefficients, ``"k1k2"`` or ``"k1"`` only radial
    terms (fewer terms extrapolate more safely outside the calibrated field). Raises
    :class:`DegenerateCalibrationError` for too few, collinear or coplanar
    points, :class:`InputArrayError` for empty, NaN or mis-shaped input. ``normalize=False`` skips the
    Hartley normalization (the paper's raw solve; worse conditioned, kept for comparison only).
    """
    free = _distortion_terms(distortion)
    xyz, uv = check_calibration_input(xyz_mm, uv_px)
    P = _linear_p(xyz, uv, normalize)
    linear = _camera(P, xyz, uv, image_size, convention="homogeneous-svd", refined=False)
    if not (refine or free.any()):
        return linear
    n_unknowns = 11 + int(free.sum())
    if 2 * xyz.shape[0] < n_unknowns + 1:
        raise DegenerateCalibrationError(
            f"{xyz.shape[0]} control points cannot fit P and {int(free.sum())} distortion coefficients "
            f"({n_unknowns} unknowns); use more points, better ≥ 30 spread over the image"
        )
    refined = _refine(linear.P, xyz, uv, image_size, free)
    # least_squares never returns a worse cost than its start; keep the guard for pathological starts.
    return refined if refined.rms_px <= linear.rms_px else linear


_DISTORTION_TERMS = {"k1": (1, 0, 0, 0), "k1k2": (1, 1, 0, 0), "k1k2p1p2": (1, 1, 1, 1)}


def _distortion_terms(distortion: object) -> BoolArray:
    """Mask of the fitted coefficients (k1, k2, p1, p2) for the ``distortion`` argument."""
    if distortion is False or distortion is None:
        return np.zeros(4, dtype=bool)
    if distortion is True:
        return np.ones(4, dtype=bool)
    if isinstance(distortion, str) and distortion in _DISTORTION_TERMS:
        return np.array(_DISTORTION_TERMS[distortion], dtype=bool)
    raise InputArrayError(
        f"distortion={distortion!r}: pass False, True, or one of {sorted(_DISTORTION_TERMS)}"
    )


def _refine(
    P0: FloatArray, xyz: FloatArray, uv: FloatArray, size: tuple[int, int], free: BoolArray
) -> DLTCamera:
    """Levenberg–Marquardt on the pixel residuals; P in normalized coordinates with P_n[2,3] = 1 as gauge."""
    Tw, Ti = similarity_3d(xyz), similarity_2d(uv)
    Pn = Ti @ P0 @ np.linalg.inv(Tw)
    Pn = Pn / Pn[2, 3]  # the centroid of the points is in front of the camera, so P_n[2,3] ≠ 0
    Ti_inv = np.linalg.inv(Ti)

    def unpack(p: FloatArray) -> tuple[FloatArray, FloatArray | None]:
        P = Ti_inv @ np.append(p[:11], 1.0).reshape(3, 4) @ Tw
        if not free.any():
            return P, None
        d = np.zeros(4)
        d[free] = p[11:]
        return P, d

    def residuals(p: FloatArray) -> FloatArray:
        P, d = unpack(p)
        try:
            cam = DLTCamera(P, size, distortion=None if d is None else tuple(d))
        except InputArrayError:
            return np.full(uv.size, 1e6)
        return (cam.project(xyz) - uv).ravel()

    p0 = np.concatenate([Pn.ravel()[:11], np.zeros(int(free.sum()))])
    sol = scipy.optimize.least_squares(residuals, p0, method="lm", x_scale="jac", xtol=1e-12, ftol=1e-12)
    P, d = unpack(sol.x)
    return _camera(
        P, xyz, uv, size, distortion=None if d is None else tuple(d), convention="refined", refined=True
    )
