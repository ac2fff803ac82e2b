"""The whole stereo core on one synthetic scene, images made with cv2.projectPoints:

plate calibration (slid to 5 positions) → per-frame epipolar matching of shuffled detections →
triangulation → reference-marker stabilization against camera shake. The 3D error bound is the floor
that the injected pixel noise implies, propagated through the TRUE cameras and through the rigid fit
(numerical Jacobian of the stabilization), times 1.5.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation
from stereo_scene import TARGET, plate_points, point_covariances_mm2, stereo_pair

from rig.stereo.dlt import calibrate_dlt
from rig.stereo.epipolar import match_epipolar
from rig.stereo.reference import rigid_transform, stabilize
from rig.stereo.triangulate import triangulate

SIGMA_PX = 0.3
REFS = np.array([[-40.0, -40.0, 0.0], [520.0, -30.0, 60.0], [-30.0, 400.0, 140.0], [510.0, 390.0, 200.0]])
TARGETS = np.array([[150.0, 120.0, 100.0], [330.0, 120.0, 100.0], [240.0, 260.0, 100.0]])


def stabilized_floor_mm(true, refs, targets) -> float:
    """RMS error of a stabilized target implied by pixel noise alone (linear propagation)."""
    cov_r = point_covariances_mm2(list(true), refs, SIGMA_PX)
    cov_t = point_covariances_mm2(list(true), targets, SIGMA_PX)
    total = 0.0
    h = 1e-4
    for m, target in enumerate(targets):
        cov = cov_t[m].copy()  # the transform is near identity: ∂y/∂target ≈ I
        for k in range(len(refs)):
            G = np.empty((3, 3))
            for a in range(3):
                plus, minus = refs.copy(), refs.copy()
                plus[k, a] += h
                minus[k, a] -= h
                G[:, a] = (
                    rigid_transform(plus, refs).apply(target[None])[0]
                    - rigid_transform(minus, refs).apply(target[None])[0]
                ) / (2 * h)
            cov += G @ cov_r[k] @ G.T
        total += np.trace(cov)
    return float(np.sqrt(total / len(targets)))


def test_pipeline_with_camera_shake() -> None:
    rng = np.random.default_rng(2026)
    true = stereo_pair()
    cal = plate_points()
    cams = [calibrate_dlt(cal, c.project(cal) + rng.normal(0, SIGMA_PX, (len(cal), 2))) for c in true]

    n_frames = 120
    t_s = np.arange(n_frames) / 60.0
    motion = np.zeros((n_frames, len(TARGETS), 3))
    motion[:, :, 2] = 5.0 * np.sin(2 * np.pi * 7.0 * t_s)[:, None] * np.array([1.0, 0.6, 0.3])
    targets_true = TARGETS + motion  # (T, M, 3)
    shake_R = Rotation.from_rotvec(rng.normal(0, np.deg2rad(0.15), (n_frames, 3))).as_matrix()
    shake_t = rng.normal(0, 1.5, (n_frames, 3))

    def shaken(points):  # the cameras shake: equivalently the scene moves rigidly about the volume centre
        return np.einsum("ij,kj->ki", shake_R[f], points - TARGET) + TARGET + shake_t[f]

    n_refs = len(REFS)
    ref_tracks = np.full((n_frames, n_refs, 3), np.nan)
    tgt_tracks = np.full((n_frames, len(TARGETS), 3), np.nan)
    n_ambiguous = 0
    for f in range(n_frames):
        world = shaken(np.vstack([REFS, targets_true[f]]))
        uv_a = true[0].project(world) + rng.normal(0, SIGMA_PX, (len(world), 2))
        perm = rng.permutation(len(world))
        uv_b = (true[1].project(world) + rng.normal(0, SIGMA_PX, (len(world), 2)))[perm]
        m = match_epipolar(cams[0], cams[1], uv_a, uv_b, gate_px=5 * SIGMA_PX)
        good = m.pairs[~m.ambiguous]
        n_ambiguous += int(m.ambiguous.sum())
        assert (perm[good[:, 1]] == good[:, 0]).all(), "an unflagged pair is wrong"
        xyz = np.full((len(world), 3), np.nan)
        xyz[good[:, 0]] = triangulate(cams, [uv_a[good[:, 0]], uv_b[good[:, 1]]], refine=True).xyz_mm
        ref_tracks[f], tgt_tracks[f] = xyz[:n_refs], xyz[n_refs:]
    assert n_ambiguous <= 0.05 * n_frames * (n_refs + len(TARGETS))

    out = stabilize(ref_tracks, REFS, tgt_tracks)
    assert out.valid.all()
    err = (out.targets_mm - targets_true).reshape(-1, 3)
    err = err[np.isfinite(err).all(axis=1)]
    rms_mm = np.sqrt(np.mean(np.sum(err**2, axis=1)))
    floor_mm = stabilized_floor_mm(true, REFS, TARGETS)
    assert rms_mm <= 1.5 * floor_mm, (rms_mm, floor_mm)
    # Without the reference markers the shake shows up as motion far above the floor.
    raw = (tgt_tracks - targets_true).reshape(-1, 3)
    raw = raw[np.isfinite(raw).all(axis=1)]
    assert np.sqrt(np.mean(np.sum(raw**2, axis=1))) > 3 * floor_mm
    # The oscillation amplitude of target 0 is recovered (least-squares sine at the known 7 Hz).
    basis = np.c_[np.sin(2 * np.pi * 7.0 * t_s), np.cos(2 * np.pi * 7.0 * t_s), np.ones(n_frames)]
    ok = np.isfinite(out.targets_mm[:, 0, 2])
    coef = np.linalg.lstsq(basis[ok], out.targets_mm[ok, 0, 2], rcond=None)[0]
    amplitude_floor = floor_mm * np.sqrt(
        2 / ok.sum()
    )  # noise on a fitted amplitude, (per-axis σ ≤ the 3D floor)
    assert abs(np.hypot(coef[0], coef[1]) - 5.0) <= 3 * amplitude_floor
