"""N-view triangulation: exactness, missing views, refinement, covariance, degenerate geometry."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from stereo_scene import TARGET, look_at_camera, noise_floor_mm, stereo_pair, volume_points

from rig.stereo import errors
from rig.stereo.dlt import DLTCamera
from rig.stereo.triangulate import triangulate

DISTORTION = (-0.2, 0.05, 5e-4, -3e-4)


def dlt_camera(true) -> DLTCamera:
    P = true.K @ np.hstack([cv2.Rodrigues(true.rvec)[0], true.tvec])
    return DLTCamera(P, distortion=tuple(true.dist), convention="external")


def test_our_projection_equals_opencv_including_distortion() -> None:
    true = look_at_camera(TARGET + np.array([300.0, -200.0, -1400.0]), TARGET, dist=DISTORTION)
    X = volume_points(200, np.random.default_rng(0))
    np.testing.assert_allclose(dlt_camera(true).project(X), true.project(X), atol=1e-9)
    # The analytic Jacobian agrees with central differences of OpenCV's projection.
    np.testing.assert_allclose(
        dlt_camera(true).project_with_jacobian(X)[1], true.jacobian(X), rtol=1e-6, atol=1e-9
    )


@settings(max_examples=30, deadline=None)
@given(
    n_cam=st.integers(2, 4),
    spread_mm=st.floats(200.0, 900.0),
    seed=st.integers(0, 2**31),
    refine=st.booleans(),
    distorted=st.booleans(),
)
def test_triangulate_of_projection_is_identity(n_cam, spread_mm, seed, refine, distorted) -> None:
    rng = np.random.default_rng(seed)
    dist = DISTORTION if distorted else (0, 0, 0, 0)
    centres = TARGET + np.c_[rng.uniform(-1, 1, (n_cam, 2)) * spread_mm, -rng.uniform(1200, 2500, n_cam)]
    true = [look_at_camera(c, TARGET, dist=dist) for c in centres]
    if min(np.linalg.norm(a.centre_mm - b.centre_mm) for i, a in enumerate(true) for b in true[:i]) < 50:
        return
    X = volume_points(64, rng)
    result = triangulate([dlt_camera(c) for c in true], [c.project(X) for c in true], refine=refine)
    np.testing.assert_allclose(result.xyz_mm, X, atol=1e-6)
    assert np.nanmax(np.abs(result.residuals_px)) < 1e-6
    assert (result.n_views == n_cam).all()


def test_missing_views_use_remaining_cameras() -> None:
    true = [
        look_at_camera(TARGET + off, TARGET) for off in ([-400, 0, -1500], [400, 0, -1500], [0, 300, -1500])
    ]
    cams = [dlt_camera(c) for c in true]
    X = volume_points(6, np.random.default_rng(1))
    uv = [c.project(X) for c in true]
    uv[0][1] = np.nan  # point 1: seen by cameras 1, 2
    uv[2][2] = np.nan  # point 2: seen by cameras 0, 1
    uv[0][3] = uv[1][3] = np.nan  # point 3: one camera only
    uv[1][4, 0] = np.nan  # a half-NaN row counts as not seen
    r = triangulate(cams, uv, refine=True, pixel_sigma_px=0.5)
    assert r.n_views.tolist() == [3, 2, 2, 1, 2, 3]
    good = r.n_views >= 2
    np.testing.assert_allclose(r.xyz_mm[good], X[good], atol=1e-6)
    assert np.isnan(r.xyz_mm[3]).all() and np.isnan(r.covariance_mm2[3]).all()
    assert np.isnan(r.residuals_px[1, 0]).all() and np.isfinite(r.residuals_px[1, 1]).all()
    # Fewer views → larger uncertainty.
    tr = np.trace(r.covariance_mm2, axis1=1, axis2=2)
    assert tr[1] > tr[0] and tr[2] > tr[0]


def test_refinement_lowers_reprojection_error_and_matches_floor() -> None:
    rng = np.random.default_rng(11)
    true = stereo_pair(dist=DISTORTION)
    cams = [dlt_camera(c) for c in true]
    X = volume_points(2000, rng)
    sigma = 0.5
    uv = [c.project(X) + rng.normal(0, sigma, (len(X), 2)) for c in true]
    linear = triangulate(cams, uv)
    refined = triangulate(cams, uv, refine=True, pixel_sigma_px=sigma)
    assert (refined.rms_px <= linear.rms_px + 1e-9).all()
    err = refined.xyz_mm - X
    floor = noise_floor_mm(list(true), X, sigma)
    assert np.sqrt(np.mean(np.sum(err**2, axis=1))) == pytest.approx(floor, rel=0.1)
    # Covariance check: the normalized squared error eᵀC⁻¹e is χ² with 3 degrees of freedom, mean 3,
    # standard error of the mean sqrt(6/N) ≈ 0.055 for N = 2000; allow 5 standard errors.
    chi2 = np.einsum("ni,nij,nj->n", err, np.linalg.inv(refined.covariance_mm2), err)
    assert abs(chi2.mean() - 3.0) < 5 * np.sqrt(6 / len(X))
    # The covariance agrees with the floor computed independently from OpenCV's projection.
    assert np.sqrt(np.mean(np.trace(refined.covariance_mm2, axis1=1, axis2=2))) == pytest.approx(
        floor, rel=0.01
    )


def test_plain_matrices_are_accepted() -> None:
    true = stereo_pair()
    X = volume_points(5, np.random.default_rng(2))
    r = triangulate([dlt_camera(c).P for c in true], [c.project(X) for c in true])
    np.testing.assert_allclose(r.xyz_mm, X, atol=1e-6)
    assert r.covariance_mm2 is None


def test_cameras_sharing_a_centre() -> None:
    a, b = (dlt_camera(c) for c in stereo_pair())
    rotated = DLTCamera(np.diag([1.0, 1.2, 1.0]) @ a.P)  # same centre, other intrinsics
    X = volume_points(4, np.random.default_rng(3))
    with pytest.raises(errors.DegenerateGeometryError, match="share a centre"):
        triangulate([a, rotated], [a.project(X), rotated.project(X)])
    # With a third camera that has a baseline, points seen by it are fine; points seen only by the
    # co-centred pair are refused.
    uv = [a.project(X), rotated.project(X), b.project(X)]
    np.testing.assert_allclose(triangulate([a, rotated, b], uv).xyz_mm, X, atol=1e-6)
    uv[2][0] = np.nan
    with pytest.raises(errors.DegenerateGeometryError, match="1 points"):
        triangulate([a, rotated, b], uv)


@pytest.mark.parametrize(
    ("cameras", "uvs", "kw", "match"),
    [
        ("one", None, {}, "at least 2"),
        ("two", [np.zeros((3, 2))], {}, "one \\(N, 2\\)"),
        ("two", [np.zeros((3, 2)), np.zeros((4, 2))], {}, "different lengths"),
        ("two", [np.zeros((3, 2)), np.full((3, 2), np.inf)], {}, "inf"),
        ("two", [np.zeros((3, 2)), np.zeros((2, 3))], {}, "shape"),
        ("two", [np.zeros((0, 2)), np.zeros((0, 2))], {}, "empty"),
        ("two", [np.zeros((3, 2)), np.zeros((3, 2))], {"pixel_sigma_px": 0.0}, "pixel_sigma_px"),
        ("bad", [np.zeros((3, 2)), np.zeros((3, 2))], {}, r"cameras\[1\]"),
    ],
)
def test_bad_input(cameras, uvs, kw, match) -> None:
    a, b = (dlt_camera(c) for c in stereo_pair())
    cams = {"one": [a], "two": [a, b], "bad": [a, np.zeros((3, 4))]}[cameras]
    with pytest.raises(errors.InputArrayError, match=match):
        triangulate(cams, uvs if uvs is not None else [np.zeros((3, 2))], **kw)


def test_linear_step_is_the_normalized_svd_solution() -> None:
    """The vectorized inverse iteration returns the SVD's smallest right singular vector."""
    from rig.stereo.normalize import similarity_2d
    from rig.stereo.triangulate import linear_triangulation

    rng = np.random.default_rng(4)
    true = [
        look_at_camera(TARGET + off, TARGET) for off in ([-400, 0, -1500], [400, 50, -1400], [0, 300, -1600])
    ]
    P = [dlt_camera(c).P for c in true]
    X = volume_points(50, rng)
    uv = np.stack([c.project(X) + rng.normal(0, 2.0, (50, 2)) for c in true], axis=1)
    ours = linear_triangulation(P, uv)
    centres = np.array([dlt_camera(c).centre_mm for c in true])
    c0 = centres.mean(axis=0)
    s = np.mean(np.linalg.norm(centres - c0, axis=1))
    H = np.diag([s, s, s, 1.0])
    H[:3, 3] = c0
    for k in range(50):
        rows = []
        for c in range(3):
            T = similarity_2d(uv[:, c])
            Pn = T @ P[c] @ H
            Pn /= np.linalg.norm(Pn)
            u, v, _ = T @ np.r_[uv[k, c], 1.0]
            rows += [u * Pn[2] - Pn[0], v * Pn[2] - Pn[1]]
        Xh = H @ np.linalg.svd(np.array(rows))[2][-1]
        np.testing.assert_allclose(ours[k], Xh[:3] / Xh[3], atol=1e-8)


def test_undistort_outside_invertible_field_raises() -> None:
    """With k1 = −0.5 the distorted radius never exceeds 0.544 (normalized): beyond, no inverse exists."""
    from rig.stereo.distortion import distort, undistort

    coeffs = np.array([-0.5, 0.0, 0.0, 0.0])
    xy = np.array([[0.3, 0.2], [0.1, -0.4]])
    np.testing.assert_allclose(undistort(distort(xy, coeffs), coeffs), xy, atol=1e-12)
    with pytest.raises(errors.DistortionError, match="outside the field"):
        undistort(np.array([[0.7, 0.0]]), coeffs)
    assert np.isnan(undistort(np.array([[np.nan, np.nan]]), coeffs)).all()


def test_observation_outside_lens_model_is_dropped_and_flagged() -> None:
    true = [
        look_at_camera(TARGET + off, TARGET) for off in ([-400, 0, -1500], [400, 0, -1500], [0, 300, -1500])
    ]
    cams = [dlt_camera(c) for c in true]
    strong = DLTCamera(cams[2].P, distortion=(-0.5, 0.0, 0.0, 0.0))  # invertible only for r_d < 0.544
    X = volume_points(3, np.random.default_rng(5))
    uv = [cams[0].project(X), cams[1].project(X), strong.project(X)]
    K = strong.decompose()[0]
    uv[2][1] = K[:2, 2] + 0.7 * K[0, 0] * np.array([1.0, 0.0])  # r_d = 0.7: no undistorted point maps there
    r = triangulate([cams[0], cams[1], strong], uv, refine=True)
    assert r.outside_lens_model.tolist() == [[False, False, False], [False, False, True], [False] * 3]
    assert r.n_views.tolist() == [3, 2, 3]
    np.testing.assert_allclose(r.xyz_mm, X, atol=1e-6)
    with pytest.raises(errors.DistortionError, match="distortion='k1'"):
        strong.undistort_px(uv[2])
