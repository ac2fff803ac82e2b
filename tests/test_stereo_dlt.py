"""DLT calibration on synthetic scenes projected with OpenCV (never with our own model).

Accuracy bounds are derived from the injected pixel noise σ: the 3D floor is sqrt(mean trace σ²(JᵀJ)⁻¹)
through the TRUE cameras; a calibrated camera's prediction error on new points is compared with
σ·sqrt(n_parameters / n_points), the RMS error of a least-squares fit of that many parameters.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from stereo_scene import look_at_camera, noise_floor_mm, plate_points, stereo_pair, volume_points

from rig.stereo import DLTCamera, P_from_dlt11, calibrate_dlt, dlt11_from_P, errors

SIGMA_PX = 0.3
DISTORTION = (-0.25, 0.1, 1e-3, -5e-4)


def observe(cams, xyz, rng, sigma=SIGMA_PX):
    return [c.project(xyz) + rng.normal(0.0, sigma, (len(xyz), 2)) for c in cams]


def prediction_rms_px(calibrated, true_cams, xyz):
    sq = [
        np.sum((d.project(xyz) - c.project(xyz)) ** 2, axis=1)
        for d, c in zip(calibrated, true_cams, strict=True)
    ]
    return float(np.sqrt(np.mean(sq)))


def triangulation_rms_mm(calibrated, obs, xyz):
    from rig.stereo.triangulate import triangulate

    return float(np.sqrt(np.mean(np.sum((triangulate(calibrated, obs).xyz_mm - xyz) ** 2, axis=1))))


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(20261122)
    cams = stereo_pair()
    cal = plate_points()
    test = volume_points(300, rng)
    return cams, cal, test, observe(cams, cal, rng), observe(cams, test, rng)


def test_noise_free_calibration_recovers_true_camera(scene) -> None:
    cams, cal, test, _, _ = scene
    for true in cams:
        cam = calibrate_dlt(cal, true.project(cal))
        assert cam.rms_px < 1e-6
        np.testing.assert_allclose(cam.project(test), true.project(test), atol=1e-6)
        K, R, centre = cam.decompose()
        np.testing.assert_allclose(K, true.K, rtol=1e-7, atol=1e-6)
        import cv2

        np.testing.assert_allclose(R, cv2.Rodrigues(true.rvec)[0], atol=1e-9)
        np.testing.assert_allclose(centre, true.centre_mm, atol=1e-5)


def test_linear_and_refined_reach_noise_floor(scene) -> None:
    cams, cal, test, obs_cal, obs_test = scene
    floor = noise_floor_mm(list(cams), test, SIGMA_PX)
    n = len(cal)
    linear = [calibrate_dlt(cal, o) for o in obs_cal]
    refined = [calibrate_dlt(cal, o, refine=True) for o in obs_cal]
    with_dist = [calibrate_dlt(cal, o, distortion=True) for o in obs_cal]
    for cal_set, n_par in ((linear, 11), (refined, 11), (with_dist, 15)):
        assert prediction_rms_px(cal_set, cams, test) <= 1.5 * SIGMA_PX * np.sqrt(n_par / n)
        assert triangulation_rms_mm(cal_set, obs_test, test) <= 1.5 * floor
    # "No worse than plain DLT" on distortion-free data, on the same noisy observations.
    e_lin = triangulation_rms_mm(linear, obs_test, test)
    assert triangulation_rms_mm(refined, obs_test, test) <= 1.05 * e_lin
    assert triangulation_rms_mm(with_dist, obs_test, test) <= 1.05 * e_lin
    for lin, ref in zip(linear, refined, strict=True):
        assert ref.rms_px <= lin.rms_px and ref.refined and ref.convention == "refined"
        # Residual RMS of a least-squares fit: σ·sqrt(2(N − p/2)/N) per point (Euclidean, 2 coordinates).
        assert ref.rms_px == pytest.approx(SIGMA_PX * np.sqrt(2 * (n - 5.5) / n), rel=0.15)


def test_distortion_refinement_clearly_better_with_lens_distortion() -> None:
    rng = np.random.default_rng(7)
    cams = stereo_pair(dist=DISTORTION)
    cal, test = plate_points(), volume_points(300, rng)
    obs_cal, obs_test = observe(cams, cal, rng), observe(cams, test, rng)
    floor = noise_floor_mm(list(cams), test, SIGMA_PX)
    linear = [calibrate_dlt(cal, o) for o in obs_cal]
    fitted = [calibrate_dlt(cal, o, distortion=True) for o in obs_cal]
    assert triangulation_rms_mm(linear, obs_test, test) > 2.0 * floor  # the plain DLT cannot model the lens
    assert triangulation_rms_mm(fitted, obs_test, test) <= 1.5 * floor
    assert prediction_rms_px(fitted, cams, test) <= 1.5 * SIGMA_PX * np.sqrt(15 / len(cal))
    n = len(cal)
    for f, lin in zip(fitted, linear, strict=True):
        expected = SIGMA_PX * np.sqrt(2 * (n - 7.5) / n)  # 15 parameters fitted to 2N coordinates
        assert f.rms_px == pytest.approx(expected, rel=0.15)
        assert lin.rms_px > 1.5 * expected
    assert fitted[0].distortion is not None and fitted[0].distortion[0] < 0  # barrel, as injected


def test_distortion_noise_free_matches_opencv_model() -> None:
    true = look_at_camera([100.0, 50.0, -1400.0], [240, 180, 100], dist=DISTORTION)
    cal = plate_points()
    cam = calibrate_dlt(cal, true.project(cal), distortion=True)
    test = volume_points(100, np.random.default_rng(3))
    np.testing.assert_allclose(cam.project(test), true.project(test), atol=1e-4)
    x = np.hstack([test, np.ones((len(test), 1))]) @ cam.P.T
    pinhole_px = x[:, :2] / x[:, 2:]
    np.testing.assert_allclose(cam.undistort_px(cam.project(test)), pinhole_px, atol=1e-6)
    np.testing.assert_allclose(cam.distortion, DISTORTION, rtol=0.05, atol=2e-4)


def test_to_dict_round_trip_is_exact(scene) -> None:
    _, cal, _, obs_cal, _ = scene
    for kw in ({}, {"distortion": True}):
        cam = calibrate_dlt(cal, obs_cal[0], **kw)
        text = json.dumps({"cameras": {"a": cam.to_dict()}})
        back = DLTCamera.from_dict(json.loads(text)["cameras"]["a"])
        assert np.array_equal(back.P, cam.P)
        assert np.array_equal(back.residuals_px, cam.residuals_px)
        assert back.distortion == cam.distortion and back.image_size == cam.image_size
        assert back.convention == cam.convention and back.refined == cam.refined
        assert back.to_dict() == cam.to_dict()
    d = cam.to_dict()
    assert d["n_points"] == len(cal) and d["residuals_rms_px"] == cam.rms_px
    true_k = stereo_pair()[0].K
    assert d["intrinsics_px"]["fx_px"] == pytest.approx(true_k[0, 0], rel=0.01)
    np.testing.assert_allclose(d["centre_mm"], stereo_pair()[0].centre_mm, atol=5.0)


@pytest.mark.parametrize(
    ("entry", "match"),
    [
        ([1, 2], "JSON object"),
        ({"image_size": [1920, 1080]}, "lacks"),
        ({"P": [[1, 2, 3]], "image_size": [1920, 1080]}, "shape"),
        ({"P": np.eye(3, 4).tolist(), "image_size": [0, 1080]}, "image_size"),
        ({"P": np.eye(3, 4).tolist(), "image_size": [1920, 1080], "distortion": [1, 2]}, "four"),
        (
            {"P": np.eye(3, 4).tolist(), "image_size": [1920, 1080], "residuals_px": [], "n_points": 3},
            "n_points",
        ),
    ],
)
def test_from_dict_rejects_malformed_entries(entry, match) -> None:
    with pytest.raises(errors.CalibrationFormatError, match=match):
        DLTCamera.from_dict(entry)


def test_dlt11_round_trip_and_units() -> None:
    true = look_at_camera([0.0, 0.0, -1500.0], [240, 180, 100])
    cam = calibrate_dlt(plate_points(), true.project(plate_points()))
    L_mm = cam.dlt11()
    np.testing.assert_allclose(dlt11_from_P(P_from_dlt11(L_mm)), L_mm, rtol=1e-12)
    L_m = cam.dlt11(length_unit_mm=1000.0)
    back = DLTCamera.from_dlt11(L_m, length_unit_mm=1000.0)
    np.testing.assert_allclose(back.P, cam.P, rtol=1e-10, atol=1e-12)
    with pytest.raises(errors.InputArrayError, match="11"):
        P_from_dlt11(np.ones(12))


# ----------------------------------------------------------------------------- degenerate input
def _good():
    true = look_at_camera([0.0, 0.0, -1500.0], [240, 180, 100])
    cal = plate_points()
    return cal, true.project(cal), true


def test_fewer_than_six_points() -> None:
    cal, uv, _ = _good()
    with pytest.raises(errors.DegenerateCalibrationError, match="at least 6"):
        calibrate_dlt(cal[[0, 10, 70, 80, 140]], uv[[0, 10, 70, 80, 140]])


def test_duplicated_points_do_not_count() -> None:
    cal, uv, _ = _good()
    idx = [0, 70, 150, 0, 70, 150, 0]
    with pytest.raises(errors.DegenerateCalibrationError, match="Duplicated"):
        calibrate_dlt(cal[idx], uv[idx])


def test_coplanar_points_refused() -> None:
    cal, uv, _ = _good()
    one_plane = cal[:, 2] == 0
    with pytest.raises(errors.DegenerateCalibrationError, match=r"coplanar.*slide the plate"):
        calibrate_dlt(cal[one_plane], uv[one_plane])


def test_nearly_coplanar_points_refused_scale_free() -> None:
    _, _, true = _good()
    thin = plate_points(positions_mm=(0.0, 1.0))  # 1 mm of depth over a 480 mm plate
    for scale in (1.0, 1e-3, 1e3):  # the test is independent of units
        with pytest.raises(errors.DegenerateCalibrationError, match="coplanar"):
            calibrate_dlt(thin * scale, true.project(thin))


def test_collinear_points_refused() -> None:
    xyz = np.column_stack([np.arange(10.0), 2 * np.arange(10.0), 3 * np.arange(10.0)])
    with pytest.raises(errors.DegenerateCalibrationError, match="collinear"):
        calibrate_dlt(xyz, np.random.default_rng(0).random((10, 2)))


@pytest.mark.parametrize(
    ("xyz", "uv", "match"),
    [
        (np.zeros((0, 3)), np.zeros((0, 2)), "empty"),
        ("abc", np.zeros((8, 2)), "dtype"),
        (np.zeros((8, 3), dtype=bool), np.zeros((8, 2)), "dtype"),
        (np.zeros((3, 8)), np.zeros((8, 2)), "transposed"),
        (np.zeros(24), np.zeros((8, 2)), "shape"),
        (np.zeros((8, 3)), np.zeros((7, 2)), "one pixel per point"),
    ],
)
def test_bad_arrays(xyz, uv, match) -> None:
    with pytest.raises(errors.InputArrayError, match=match):
        calibrate_dlt(xyz, uv)


def test_nan_in_calibration_input_names_rows() -> None:
    cal, uv, _ = _good()
    uv = uv.copy()
    uv[[3, 17]] = np.nan
    with pytest.raises(errors.InputArrayError, match=r"uv_px: rows \[3, 17\]"):
        calibrate_dlt(cal, uv)


def test_bad_image_size() -> None:
    cal, uv, _ = _good()
    with pytest.raises(errors.InputArrayError, match="image_size"):
        calibrate_dlt(cal, uv, image_size=(1920.5, 1080))


# ----------------------------------------------------------------------------- properties
@settings(max_examples=25, deadline=None)
@given(
    azimuth=st.floats(-0.6, 0.6),
    elevation=st.floats(-0.5, 0.5),
    distance=st.floats(900.0, 3000.0),
    f_px=st.floats(800.0, 4000.0),
    noise_seed=st.integers(0, 2**31),
)
def test_calibrate_project_round_trip(azimuth, elevation, distance, f_px, noise_seed) -> None:
    """Any camera in front of the plate: calibrate on its exact projections, then project reproduces it."""
    target = np.array([240.0, 180.0, 100.0])
    direction = np.array(
        [np.sin(azimuth) * np.cos(elevation), np.sin(elevation), -np.cos(azimuth) * np.cos(elevation)]
    )
    true = look_at_camera(target + distance * direction, target, f_px=f_px)
    cal = plate_points()
    cam = calibrate_dlt(cal, true.project(cal))
    test = volume_points(50, np.random.default_rng(noise_seed))
    scale_px = f_px / distance  # px per mm: tolerance relative to the image scale
    np.testing.assert_allclose(cam.project(test), true.project(test), atol=1e-6 * max(1.0, scale_px * 100))
    np.testing.assert_allclose(cam.residuals_px, 0.0, atol=1e-6)


def test_radial_only_distortion_extrapolates_beyond_a_small_plate() -> None:
    """A 240 × 160 mm plate slid over 200 mm, test points in twice its extent (as on the default rig):
    the 4-term model's k2 is unconstrained there, the k1-only model stays near the noise floor."""
    rng = np.random.default_rng(0)
    cams = stereo_pair(dist=(-0.08, 0.06, 4e-4, -3e-4))
    cal = plate_points(7, 5, 40.0) + np.array([120.0, 100.0, 0.0])
    centre, half = np.array([240.0, 180.0, 100.0]), np.array([240.0, 160.0, 200.0])
    test = centre - half + rng.random((300, 3)) * 2 * half
    sigma = 0.1
    obs_cal, obs_test = observe(cams, cal, rng, sigma), observe(cams, test, rng, sigma)
    floor = noise_floor_mm(list(cams), test, sigma)
    from rig.stereo.triangulate import triangulate

    def err(**kw):
        fitted = [calibrate_dlt(cal, o, **kw) for o in obs_cal]
        xyz = triangulate(fitted, obs_test, refine=True).xyz_mm
        return float(np.sqrt(np.nanmean(np.sum((xyz - test) ** 2, axis=1))))

    assert err(distortion="k1") <= 1.5 * floor
    assert err() > 2.0 * floor
    assert err(distortion="k1") < err(distortion=True)


def test_distortion_argument_is_checked() -> None:
    cal, uv, _ = _good()
    with pytest.raises(errors.InputArrayError, match="k1k2p1p2"):
        calibrate_dlt(cal, uv, distortion="radial")
    cam = calibrate_dlt(cal, uv, distortion="k1k2")
    assert cam.distortion is None or cam.distortion[2:] == (0.0, 0.0)
    with pytest.raises(errors.DegenerateCalibrationError, match="15 unknowns"):
        calibrate_dlt(cal[[0, 6, 30, 70, 76, 100, 140]], uv[[0, 6, 30, 70, 76, 100, 140]], distortion=True)
