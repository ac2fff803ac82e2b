"""Reference markers: remove camera shake and drift from measured tracks (Kabsch / Umeyama).

Fixed reference markers should not move. If they appear to, the cameras moved: the rigid transform
(optionally with scale) that maps the reference markers at time t back onto their positions at a
reference time is applied to the target markers measured at time t, so the apparent motion common to
the whole scene does not show up as target motion. Coordinates in mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig.stereo._arrays import BoolArray, FloatArray
from rig.stereo.errors import DegenerateReferenceError, InputArrayError
from rig.stereo.normalize import as_points

MIN_MARKERS = 3
#: Smallest allowed ratio of the 2nd to the 1st principal standard deviation of the reference markers;
#: below it they are collinear and the rotation about their line is undetermined.
MIN_SPREAD_RATIO = 1e-3


@dataclass(frozen=True)
class RigidTransform:
    """x ↦ scale·R·x + t_mm. ``rms_mm`` is the RMS residual of the markers that defined it."""

    R: FloatArray
    t_mm: FloatArray
    scale: float = 1.0
    rms_mm: float = 0.0
    n_markers: int = 0

    def apply(self, xyz_mm: object) -> FloatArray:
        """Transform points (N, 3) mm; NaN rows stay NaN."""
        xyz = as_points(xyz_mm, "xyz_mm", 3, allow_nan=True, allow_empty=True)
        return self.scale * xyz @ self.R.T + self.t_mm

    def inverse(self) -> RigidTransform:
        R_inv = self.R.T
        return RigidTransform(
            R_inv, -(R_inv @ self.t_mm) / self.scale, 1.0 / self.scale, self.rms_mm, self.n_markers
        )


def _umeyama(
    src: FloatArray, dst: FloatArray, w: FloatArray, with_scale: bool
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Batched weighted Umeyama: src, dst (T, K, 3), w (T, K) ≥ 0. Returns R, t, s, spread ratio, rms."""
    wsum = w.sum(axis=1)
    safe = np.where(wsum > 0, wsum, 1.0)
    src0, dst0 = np.where(w[..., None] > 0, src, 0.0), np.where(w[..., None] > 0, dst, 0.0)
    mu_s = np.einsum("tk,tki->ti", w, src0) / safe[:, None]
    mu_d = np.einsum("tk,tki->ti", w, dst0) / safe[:, None]
    ds, dd = src0 - mu_s[:, None], dst0 - mu_d[:, None]
    cov = np.einsum("tk,tki,tkj->tij", w, dd, ds) / safe[:, None, None]
    scatter = np.einsum("tk,tki,tkj->tij", w, ds, ds) / safe[:, None, None]
    eig = np.linalg.eigvalsh(scatter)  # ascending
    with np.errstate(invalid="ignore", divide="ignore"):
        spread = np.sqrt(np.clip(eig[:, 1], 0, None) / eig[:, 2])
    U, S, Vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(U) * np.linalg.det(Vt))
    d[d == 0] = 1.0
    D = np.ones((len(d), 3))
    D[:, 2] = d
    R = np.einsum("tij,tj,tjk->tik", U, D, Vt)
    var_s = np.trace(scatter, axis1=1, axis2=2)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.sum(S * D, axis=1) / var_s if with_scale else np.ones(len(d))
    t = mu_d - s[:, None] * np.einsum("tij,tj->ti", R, mu_s)
    pred = s[:, None, None] * np.einsum("tij,tkj->tki", R, src0) + t[:, None]
    sq = np.sum((pred - dst0) ** 2, axis=2) * (w > 0)
    rms = np.sqrt(sq.sum(axis=1) / np.maximum((w > 0).sum(axis=1), 1))
    return R, t, s, spread, rms


def rigid_transform(
    src_mm: object, dst_mm: object, *, scale: bool = False, weights: object = None
) -> RigidTransform:
    """Least-squares transform mapping ``src_mm`` (K, 3) onto ``dst_mm`` (K, 3): dst ≈ s·R·src + t.

    Rows with NaN in either array are ignored (a lost marker). ``scale=True`` also fits a common scale
    (Umeyama); ``weights`` (K,) ≥ 0 optional. Raises :class:`DegenerateReferenceError` with fewer than
    3 usable markers or when they are collinear (the rotation about their line is then undetermined).
    """
    src = as_points(src_mm, "src_mm", 3, allow_nan=True)
    dst = as_points(dst_mm, "dst_mm", 3, allow_nan=True)
    if src.shape != dst.shape:
        raise InputArrayError(
            f"src_mm {src.shape} and dst_mm {dst.shape} must hold the same markers, row by row"
        )
    w = _weights(weights, src.shape[0]) * (np.isfinite(src).all(axis=1) & np.isfinite(dst).all(axis=1))
    n = int((w > 0).sum())
    if n < MIN_MARKERS:
        raise DegenerateReferenceError(
            f"{n} usable reference markers; a rigid transform needs ≥ {MIN_MARKERS} non-collinear ones "
            "(mount more reference markers or keep them in view)"
        )
    R, t, s, spread, rms = _umeyama(src[None], dst[None], w[None], scale)
    if not spread[0] >= MIN_SPREAD_RATIO:
        raise DegenerateReferenceError(
            f"the {n} reference markers are (nearly) collinear "
            f"(spread {spread[0]:.2g} < {MIN_SPREAD_RATIO}): "
            "mount at least one reference marker off their line"
        )
    return RigidTransform(R[0], t[0], float(s[0]), float(rms[0]), n)


def _weights(weights: object, n: int) -> FloatArray:
    if weights is None:
        return np.ones(n)
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != (n,) or not np.isfinite(w).all() or (w < 0).any():
        raise InputArrayError(f"weights: expected {n} finite non-negative numbers, got shape {w.shape}")
    return w


@dataclass(frozen=True)
class Stabilized:
    """Result of :func:`stabilize`: corrected targets (T, M, 3) mm and the per-frame transforms.

    ``valid`` (T,) is False for frames with fewer than 3 usable or collinear reference markers; their
    corrected targets, R, t and scale are NaN.
    """

    targets_mm: FloatArray
    R: FloatArray
    t_mm: FloatArray
    scale: FloatArray
    rms_mm: FloatArray
    valid: BoolArray


def stabilize(
    reference_tracks_mm: object, reference_home_mm: object, target_tracks_mm: object, *, scale: bool = False
) -> Stabilized:
    """Map every frame's reference markers back onto ``reference_home_mm`` and apply it to the targets.

    ``reference_tracks_mm`` (T, K, 3): the K reference markers measured in T frames (NaN = lost);
    ``reference_home_mm`` (K, 3): their positions at the reference time; ``target_tracks_mm`` (T, M, 3).
    Vectorized over frames. Raises :class:`DegenerateReferenceError` if the home positions themselves
    cannot fix a transform; frames that cannot are marked invalid instead.
    """
    ref = _tracks(reference_tracks_mm, "reference_tracks_mm")
    tgt = _tracks(target_tracks_mm, "target_tracks_mm")
    home = as_points(reference_home_mm, "reference_home_mm", 3)
    if ref.shape[1] != home.shape[0] or tgt.shape[0] != ref.shape[0]:
        raise InputArrayError(
            f"reference_tracks_mm {ref.shape}, reference_home_mm {home.shape}, target_tracks_mm {tgt.shape}: "
            "shapes must agree as (T, K, 3), (K, 3), (T, M, 3)"
        )
    rigid_transform(home, home)  # raises if the reference geometry itself is degenerate
    n_frames = ref.shape[0]
    w: FloatArray = np.all(np.isfinite(ref), axis=2).astype(np.float64)
    R, t, s, spread, rms = _umeyama(ref, np.broadcast_to(home, ref.shape), w, scale)
    valid = (w.sum(axis=1) >= MIN_MARKERS) & (spread >= MIN_SPREAD_RATIO) & np.isfinite(s)
    R[~valid], t[~valid], s[~valid], rms[~valid] = np.nan, np.nan, np.nan, np.nan
    out = s[:, None, None] * np.einsum("tij,tmj->tmi", R, tgt) + t[:, None]
    return Stabilized(out, R, t, s if scale else np.where(valid, 1.0, np.nan), rms, valid.reshape(n_frames))


def _tracks(array: object, name: str) -> FloatArray:
    arr = np.asarray(array)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] == 0:
        raise InputArrayError(f"{name}: shape {arr.shape} is not allowed; expected (T frames, markers, 3) mm")
    as_points(arr.reshape(-1, 3), name, 3, allow_nan=True, allow_empty=True)  # dtype and ±inf checks
    return arr.astype(np.float64)
