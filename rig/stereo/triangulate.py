"""N-view triangulation: linear (normalized homogeneous SVD, vectorized over points) with optional
Levenberg–Marquardt refinement of the pixel reprojection error and a covariance from the pixel noise.

Units: xyz in mm, image coordinates in pixels. A NaN row in a camera's ``uv`` means "not seen by that
camera"; a point seen by fewer than two cameras gets NaN coordinates (``n_views`` says why).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rig.stereo._arrays import BoolArray, FloatArray, IntArray
from rig.stereo.dlt import DLTCamera
from rig.stereo.errors import DegenerateGeometryError, InputArrayError
from rig.stereo.normalize import as_points, projection_matrix, similarity_2d

#: Two camera centres closer than this fraction of their distance from the origin (or 1 mm) coincide.
SAME_CENTRE_REL = 1e-9


@dataclass(frozen=True)
class Triangulation:
    """Result of :func:`triangulate` for N points and n cameras.

    ``xyz_mm`` (N, 3); ``residuals_px`` (N, n, 2) projected − observed, NaN where a camera did not see
    the point; ``covariance_mm2`` (N, 3, 3) = σ²(JᵀJ)⁻¹ when a pixel σ was given, else None;
    ``n_views`` (N,) cameras used per point; ``outside_lens_model`` (N, n) True where an observation
    could not be undistorted (outside the field where the camera's lens model is invertible) and was
    therefore not used.
    """

    xyz_mm: FloatArray
    residuals_px: FloatArray
    covariance_mm2: FloatArray | None
    n_views: IntArray
    outside_lens_model: BoolArray

    @property
    def rms_px(self) -> FloatArray:
        """Per-point RMS reprojection error over the cameras that saw it (Euclidean per camera), px."""
        sq = np.sum(self.residuals_px**2, axis=2)
        with np.errstate(invalid="ignore", divide="ignore"):
            rms: FloatArray = np.sqrt(np.nansum(sq, axis=1) / np.sum(np.isfinite(sq), axis=1))
        return rms


def as_camera(camera: object, index: int) -> DLTCamera:
    """A :class:`DLTCamera`, or a projection matrix (or object with ``.P``) as a distortion-free camera."""
    if isinstance(camera, DLTCamera):
        return camera
    return DLTCamera(projection_matrix(camera, f"cameras[{index}]"), convention="external")


def _centre_groups(cams: Sequence[DLTCamera]) -> IntArray:
    """Label cameras so that cameras with the same centre share a label."""
    centres = np.array([c.centre_mm for c in cams])
    labels = np.arange(len(cams), dtype=np.int64)
    for i in range(len(cams)):
        for j in range(i):
            size_mm = max(float(np.linalg.norm(centres[i])), float(np.linalg.norm(centres[j])), 1.0)
            tol = SAME_CENTRE_REL * size_mm
            if np.linalg.norm(centres[i] - centres[j]) <= tol:
                labels[i] = labels[j]
                break
    return labels


def _check_inputs(
    cameras: Sequence[object], uv_per_camera: Sequence[object]
) -> tuple[list[DLTCamera], FloatArray]:
    if isinstance(cameras, np.ndarray) and cameras.ndim == 2:
        raise InputArrayError("cameras: pass a sequence of cameras (one per view), not a single matrix")
    cams = [as_camera(c, i) for i, c in enumerate(cameras)]
    if len(cams) < 2:
        raise InputArrayError(f"cameras: {len(cams)} given; triangulation needs at least 2")
    if len(uv_per_camera) != len(cams):
        raise InputArrayError(
            f"uv_per_camera has {len(uv_per_camera)} arrays for {len(cams)} cameras; pass one (N, 2) each"
        )
    uvs = [as_points(uv, f"uv_per_camera[{i}]", 2, allow_nan=True) for i, uv in enumerate(uv_per_camera)]
    sizes = {uv.shape[0] for uv in uvs}
    if len(sizes) != 1:
        raise InputArrayError(
            f"uv_per_camera arrays have different lengths {[uv.shape[0] for uv in uvs]}; row k of each "
            "array must be the same point (use NaN rows for 'not seen')"
        )
    uv = np.stack(uvs, axis=1)  # (N, n, 2)
    uv[~np.isfinite(uv).all(axis=2)] = np.nan
    return cams, uv


def linear_triangulation(P_list: Sequence[FloatArray], uv_ideal: FloatArray) -> FloatArray:
    """Homogeneous least squares per point (rows u·p3 − p1, v·p3 − p2), vectorized over points.

    ``uv_ideal`` (N, n, 2) are undistorted pixels (NaN = not seen). Image coordinates are Hartley-
    normalized per camera and the world per call (from the camera centres). The solution is the right
    singular vector of the smallest singular value of A, obtained as the eigenvector of the smallest
    eigenvalue of the 4×4 AᵀA by inverse iteration started at the X₄ = 1 solution: the same vector as
    an SVD, without a LAPACK call per point. Returns (N, 3) mm; NaN with fewer than 2 views or at infinity.
    """
    n_pts = uv_ideal.shape[0]
    centres = np.array([-np.linalg.solve(P[:, :3], P[:, 3]) for P in P_list])
    c0 = centres.mean(axis=0)
    spread = float(np.mean(np.linalg.norm(centres - c0, axis=1))) or 1.0
    Hw_inv = np.diag([spread, spread, spread, 1.0])
    Hw_inv[:3, 3] = c0
    seen: BoolArray = np.all(np.isfinite(uv_ideal), axis=2)
    M = np.zeros((n_pts, 4, 4))
    for c, P in enumerate(P_list):
        Ti = similarity_2d(uv_ideal[seen[:, c], c]) if seen[:, c].any() else np.eye(3)
        Pn = Ti @ P @ Hw_inv
        Pn /= np.linalg.norm(Pn)
        uvn = np.where(seen[:, c, None], uv_ideal[:, c] * Ti[0, 0] + Ti[:2, 2], 0.0)
        w = seen[:, c, None].astype(np.float64)
        for row in (uvn[:, :1] * Pn[2] - Pn[0], uvn[:, 1:2] * Pn[2] - Pn[1]):
            weighted = row * w
            M += np.einsum("ni,nj->nij", weighted, weighted)
    ok = seen.sum(axis=1) >= 2
    M[~ok] = np.eye(4)
    # Start: minimise ‖A·[X, 1]‖² (3×3 normal equations), then refine toward the smallest eigenvector.
    y = np.ones((n_pts, 4))
    y[:, :3] = _solve3(M[:, :3, :3], -M[:, :3, 3])
    shift = 1e-13 * np.trace(M, axis1=1, axis2=2)[:, None, None] * np.eye(4)
    for _ in range(2):  # the start is within O(σ²) of the answer; each step shrinks the gap by λ₁/λ₂ ≪ 1
        y = np.linalg.solve(M + shift, y[:, :, None])[:, :, 0]
        y /= np.linalg.norm(y, axis=1, keepdims=True)
    Xh = y @ Hw_inv.T
    with np.errstate(invalid="ignore", divide="ignore"):
        xyz = Xh[:, :3] / Xh[:, 3:4]
    at_infinity = ~(np.abs(Xh[:, 3]) > 1e-12 * np.linalg.norm(Xh[:, :3], axis=1))
    xyz[~ok | at_infinity] = np.nan
    return xyz


def _solve3(A: FloatArray, b: FloatArray) -> FloatArray:
    """Batched 3×3 solve by the adjugate (no LAPACK call per system); singular systems give inf/NaN."""
    c0 = np.cross(A[:, 1], A[:, 2])
    c1 = np.cross(A[:, 2], A[:, 0])
    c2 = np.cross(A[:, 0], A[:, 1])
    det = np.sum(A[:, 0] * c0, axis=1)
    adj_t = np.stack([c0, c1, c2], axis=2)  # A⁻¹ = adj_t / det, adj_t[:, :, j] = c_j
    with np.errstate(invalid="ignore", divide="ignore"):
        x: FloatArray = np.einsum("nij,nj->ni", adj_t, b) / det[:, None]
    return x


def _predicted_px(cams: Sequence[DLTCamera], xyz: FloatArray) -> FloatArray:
    """Projections (N, n, 2) of every point in every camera."""
    return np.stack([c.project(xyz) for c in cams], axis=1)


def _predicted_px_jacobian(cams: Sequence[DLTCamera], xyz: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Projections (N, n, 2) and their Jacobians (N, n, 2, 3) in px/mm."""
    out = [c.project_with_jacobian(xyz) for c in cams]
    return np.stack([o[0] for o in out], axis=1), np.stack([o[1] for o in out], axis=1)


def _cost(cams: Sequence[DLTCamera], xyz: FloatArray, uv: FloatArray) -> FloatArray:
    r = _predicted_px(cams, xyz) - uv
    cost: FloatArray = np.nansum(r**2, axis=(1, 2))
    return cost


def _normal_equations(
    cams: Sequence[DLTCamera], xyz: FloatArray, uv: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Per point: cost (N,), Gauss–Newton matrix JᵀJ (N, 3, 3), gradient Jᵀr (N, 3), residuals (N, n, 2)."""
    pred, J = _predicted_px_jacobian(cams, xyz)
    r = pred - uv
    seen = np.all(np.isfinite(r), axis=2)
    r = np.where(seen[..., None], r, 0.0)
    J = np.where(seen[..., None, None], J, 0.0)
    n = J.shape[0]
    Jf = J.reshape(n, -1, 3)  # (N, 2n_cam, 3)
    rf = r.reshape(n, -1)
    H = np.empty((n, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            H[:, i, j] = H[:, j, i] = np.sum(Jf[:, :, i] * Jf[:, :, j], axis=1)
    g = np.stack([np.sum(Jf[:, :, i] * rf, axis=1) for i in range(3)], axis=1)
    return np.sum(r**2, axis=(1, 2)), H, g, pred - uv


def _refine(cams: Sequence[DLTCamera], xyz0: FloatArray, uv: FloatArray, max_iter: int) -> FloatArray:
    """Per-point Levenberg–Marquardt (3 unknowns each), all points advanced together."""
    xyz = xyz0.copy()
    ok: BoolArray = np.all(np.isfinite(xyz), axis=1)
    lam = np.full(xyz.shape[0], 1e-4)
    for _ in range(max_iter):
        if not ok.any():
            break
        idx = np.nonzero(ok)[0]
        cost, H, g, _ = _normal_equations(cams, xyz[idx], uv[idx])
        damped = H.copy()
        diag = np.einsum("nii->ni", damped)
        diag += lam[idx, None] * diag + 1e-12
        step = _solve3(damped, g)
        trial = xyz[idx] - step
        new_cost = _cost(cams, trial, uv[idx])
        better = new_cost <= cost
        xyz[idx[better]] = trial[better]
        lam[idx] = np.where(better, lam[idx] * 0.1, lam[idx] * 10.0)
        small = np.linalg.norm(step, axis=1) <= 1e-9 * (1.0 + np.linalg.norm(xyz[idx], axis=1))
        stalled = np.abs(cost - new_cost) <= 1e-12 * (cost + 1e-20)  # gain below rounding of the cost
        ok[idx[small | stalled | (lam[idx] > 1e8) | ~np.isfinite(step).all(axis=1)]] = False
    return xyz


def triangulate(
    cameras: Sequence[object],
    uv_per_camera: Sequence[object],
    *,
    refine: bool = False,
    pixel_sigma_px: float | None = None,
    max_iter: int = 20,
) -> Triangulation:
    """Triangulate N points seen by n ≥ 2 cameras.

    ``cameras``: :class:`DLTCamera` objects (or (3, 4) matrices); ``uv_per_camera``: one (N, 2) array of
    observed pixels per camera, row k being the same point in all of them, NaN where not seen. Observed
    pixels are undistorted with each camera's lens model for the linear step (observations outside the
    field where it is invertible are dropped and flagged in ``outside_lens_model``); ``refine=True`` then
    minimises the reprojection error in observed pixels. ``pixel_sigma_px`` (> 0): isotropic pixel noise
    of the observations, giving ``covariance_mm2`` = σ²(JᵀJ)⁻¹. Raises
    :class:`DegenerateGeometryError` when the cameras seeing a point all share one centre.
    """
    cams, uv = _check_inputs(cameras, uv_per_camera)
    if pixel_sigma_px is not None and not (np.isfinite(pixel_sigma_px) and pixel_sigma_px > 0):
        raise InputArrayError(f"pixel_sigma_px={pixel_sigma_px!r}: pass a positive number of pixels, or None")
    uv_ideal = np.stack([c.undistort_px(uv[:, i], strict=False) for i, c in enumerate(cams)], axis=1)
    outside: BoolArray = np.all(np.isfinite(uv), axis=2) & ~np.all(np.isfinite(uv_ideal), axis=2)
    uv[outside] = np.nan
    seen: BoolArray = np.all(np.isfinite(uv), axis=2)
    labels = _centre_groups(cams)
    if len(set(labels.tolist())) < len(cams):
        distinct = np.zeros(uv.shape[0], dtype=int)
        for lab in set(labels.tolist()):
            distinct += seen[:, labels == lab].any(axis=1)
        bad = (seen.sum(axis=1) >= 2) & (distinct < 2)
        if bad.any():
            pairs = [(i, j) for i in range(len(cams)) for j in range(i) if labels[i] == labels[j]]
            raise DegenerateGeometryError(
                f"cameras {pairs} share a centre (no baseline), and {int(bad.sum())} points are seen only by "
                "them: no baseline, no triangulation; move one camera or check the calibration"
            )
    xyz = linear_triangulation([c.P for c in cams], uv_ideal)
    if refine:
        xyz = _refine(cams, xyz, uv, max_iter)
    cov = None
    if pixel_sigma_px is None:
        residuals = _predicted_px(cams, xyz) - uv
    else:
        _, H, _, residuals = _normal_equations(cams, xyz, uv)
        cov = np.full_like(H, np.nan)
        det = np.linalg.det(H)
        good = np.isfinite(xyz).all(axis=1) & (det > 1e-9 * np.trace(H, axis1=1, axis2=2) ** 3)
        cov[good] = pixel_sigma_px**2 * np.linalg.inv(H[good])
    residuals[~seen] = np.nan
    return Triangulation(xyz, residuals, cov, seen.sum(axis=1), outside)
