"""Epipolar geometry from two projection matrices and one-to-one marker matching."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from stereo_scene import TARGET, look_at_camera, stereo_pair, volume_points

from rig.stereo import errors
from rig.stereo.dlt import DLTCamera
from rig.stereo.epipolar import epipolar_distance_px, fundamental_from_projections, match_epipolar


def dlt_camera(true) -> DLTCamera:
    """Our camera object from the true OpenCV parameters: P = K[R | t] plus the same distortion."""
    import cv2

    P = true.K @ np.hstack([cv2.Rodrigues(true.rvec)[0], true.tvec])
    return DLTCamera(P, distortion=tuple(true.dist), convention="external")


@settings(max_examples=40, deadline=None)
@given(
    offset_a=st.lists(st.floats(-800, 800), min_size=3, max_size=3),
    offset_b=st.lists(st.floats(-800, 800), min_size=3, max_size=3),
    seed=st.integers(0, 2**31),
)
def test_fundamental_satisfies_epipolar_constraint(offset_a, offset_b, seed) -> None:
    ca = TARGET + np.array([0.0, 0.0, -1500.0]) + offset_a
    cb = TARGET + np.array([0.0, 0.0, -1500.0]) + offset_b
    if np.linalg.norm(ca - cb) < 10.0:
        return
    cams = [dlt_camera(look_at_camera(c, TARGET)) for c in (ca, cb)]
    X = volume_points(30, np.random.default_rng(seed))
    xa, xb = cams[0].project(X), cams[1].project(X)
    F = fundamental_from_projections(cams[0].P, cams[1].P)
    algebraic = np.einsum("ni,ij,nj->n", np.c_[xb, np.ones(30)], F, np.c_[xa, np.ones(30)])
    assert np.abs(algebraic).max() < 1e-9 * np.abs(F).sum() * 2000**2
    assert epipolar_distance_px(F, xa, xb, pairwise=False).max() < 1e-6
    assert abs(np.linalg.det(F)) < 1e-12  # rank 2
    # Swapping the cameras transposes F (up to sign and scale).
    Fba = fundamental_from_projections(cams[1], cams[0])
    assert min(np.abs(Fba - F.T).max(), np.abs(Fba + F.T).max()) < 1e-9


def test_distance_is_geometric_in_pixels() -> None:
    a, b = (dlt_camera(c) for c in stereo_pair())
    F = fundamental_from_projections(a, b)
    X = volume_points(1, np.random.default_rng(0))
    xa, xb = a.project(X), b.project(X)
    line = np.r_[xa[0], 1.0] @ F.T
    normal = line[:2] / np.linalg.norm(line[:2])
    moved = xb + 2.0 * normal  # 2 px off the epipolar line in B
    d = epipolar_distance_px(F, xa, moved, pairwise=False)[0]
    # d_b = 2 px exactly; d_a differs only by the line-normalization ratio of the two images.
    line_a = np.r_[moved[0], 1.0] @ F
    d_a = abs(np.r_[xa[0], 1.0] @ line_a) / np.linalg.norm(line_a[:2])
    assert d == pytest.approx(np.sqrt((4.0 + d_a**2) / 2))
    assert epipolar_distance_px(F, xa, moved).shape == (1, 1)


def scene_markers(n: int, seed: int):
    rng = np.random.default_rng(seed)
    true = stereo_pair(dist=(-0.2, 0.05, 5e-4, -3e-4))
    cams = [dlt_camera(c) for c in true]
    X = volume_points(n, rng)
    return cams, X, [c.project(X) + rng.normal(0, 0.2, (n, 2)) for c in true], rng


def test_matching_recovers_shuffled_correspondences_with_distortion() -> None:
    cams, _, (ua, ub), rng = scene_markers(25, 3)
    perm = rng.permutation(25)
    extra = np.array([[100.0, 100.0], [1800.0, 50.0]])  # clutter only B sees
    m = match_epipolar(cams[0], cams[1], ua, np.vstack([ub[perm], extra]), gate_px=2.0)
    truth = np.argsort(perm)  # ub[perm][truth[i]] == ub[i]
    by_a = dict(zip(m.pairs[:, 0].tolist(), m.pairs[:, 1].tolist(), strict=True))
    clean = [i for i in range(25) if not m.ambiguous[m.pairs[:, 0] == i].any()]
    assert all(by_a[i] == truth[i] for i in clean)  # every unflagged pair is right
    assert len(clean) >= 15
    assert set(m.unmatched_b.tolist()) >= {25, 26}
    assert (m.distance_px <= 2.0).all()


def test_markers_on_one_epipolar_line_are_flagged_not_guessed() -> None:
    a, b = (dlt_camera(c) for c in stereo_pair())
    # Two points on the same ray of camera A: identical in A (up to 0.05 px), apart along B's epipolar line.
    centre = a.centre_mm
    p = np.array([240.0, 180.0, 100.0])
    X = np.array([p, centre + 1.1 * (p - centre)])
    ua, ub = a.project(X), b.project(X)
    ua[1] += 0.05
    m = match_epipolar(a, b, ua, ub, gate_px=1.0)
    assert len(m) == 2 and m.ambiguous.all()
    # A third, unrelated marker far from the line is matched cleanly.
    Y = np.array([[20.0, 30.0, 180.0]])
    m = match_epipolar(a, b, np.vstack([ua, a.project(Y)]), np.vstack([ub, b.project(Y)]), gate_px=1.0)
    assert m.pairs[~m.ambiguous].tolist() == [[2, 2]]


def test_gate_and_lost_markers() -> None:
    cams, _, (ua, ub), _ = scene_markers(10, 4)
    ua[3] = np.nan
    m = match_epipolar(cams[0], cams[1], ua, ub, gate_px=3.0)
    assert 3 in m.unmatched_a and 3 in m.unmatched_b and len(m) == 9
    none = match_epipolar(cams[0], cams[1], ua, ub + np.array([0.0, 200.0]), gate_px=3.0)
    assert len(none) == 0 and none.unmatched_a.size == 10
    empty = match_epipolar(cams[0], cams[1], np.zeros((0, 2)), ub, gate_px=3.0)
    assert len(empty) == 0 and empty.pairs.shape == (0, 2)


def test_bad_input() -> None:
    a, b = (dlt_camera(c) for c in stereo_pair())
    uv = np.zeros((3, 2))
    for gate in (0, -1.0, np.nan, True, "3"):
        with pytest.raises(errors.InputArrayError, match="gate_px"):
            match_epipolar(a, b, uv, uv, gate_px=gate)
    with pytest.raises(errors.DegenerateGeometryError, match="share a centre"):
        fundamental_from_projections(a.P, 2.0 * a.P)
    same_centre = DLTCamera(np.diag([1.0, 1.1, 1.0]) @ a.P)
    with pytest.raises(errors.DegenerateGeometryError, match="baseline"):
        match_epipolar(a, same_centre, uv, uv, gate_px=3.0)
    with pytest.raises(errors.InputArrayError, match="shape"):
        epipolar_distance_px(np.eye(3), np.zeros((3, 3)), uv)
    with pytest.raises(errors.InputArrayError, match="F"):
        epipolar_distance_px(np.eye(4), uv, uv)
    with pytest.raises(errors.InputArrayError, match="as many"):
        epipolar_distance_px(np.eye(3), uv, uv[:2], pairwise=False)


def test_every_entry_point_takes_a_camera_by_its_projection_matrix() -> None:
    """One conversion camera → P (rig.stereo.normalize.projection_matrix): an object with ``.P`` that is
    not a DLTCamera is accepted by triangulation as by the fundamental matrix, with the same result as
    its matrix."""
    from timing_synth import stereo_pair as synth_pair

    from rig.stereo.triangulate import triangulate

    cam_a, cam_b = synth_pair()
    X = volume_points(20, np.random.default_rng(3))
    uv = [cam_a.project(X), cam_b.project(X)]
    by_object = triangulate([cam_a, cam_b], uv).xyz_mm
    by_matrix = triangulate([cam_a.P, cam_b.P], uv).xyz_mm
    assert np.abs(by_object - by_matrix).max() <= 1e-12 * np.abs(by_matrix).max()
    assert np.abs(by_object - X).max() < 1e-6
    assert np.array_equal(fundamental_from_projections(cam_a, cam_b),
                          fundamental_from_projections(cam_a.P, cam_b.P))


def test_the_joint_timing_fit_refuses_two_cameras_sharing_a_centre() -> None:
    """The joint timing fit takes its F from fundamental_from_projections, which refuses a zero baseline
    by name instead of fitting a NaN fundamental matrix."""
    from timing_synth import observe, rotor
    from timing_synth import stereo_pair as synth_pair

    from rig.stereo.timing import estimate_offset

    cam_a, _ = synth_pair()
    traj, _, _ = rotor(frequency_hz=3.0)
    tau = np.arange(300) / 60.0
    rng = np.random.default_rng(0)
    a = observe(cam_a, traj, tau, sigma_px=0.05, rng=rng)[:2]
    b = observe(cam_a, traj, tau, offset_s=0.004, sigma_px=0.05, rng=rng)[:2]
    with pytest.raises(errors.DegenerateGeometryError, match="share a centre"):
        estimate_offset(cam_a, cam_a, a, b, method="joint")
