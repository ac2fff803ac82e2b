"""Joint offset / line-time / drift estimate on the twin's rotor (known truth) and its error cases."""

from __future__ import annotations

import numpy as np
import pytest
from timing_synth import observe, oscillation, rotor, stereo_pair
from timing_twin import offset_floor_s, twin_record

from rig.stereo.errors import (
    AmbiguousOffsetError,
    DelayOutOfRangeError,
    InputArrayError,
    NoCommonMotionError,
    NonMonotonicTimestampsError,
    TooFewSamplesError,
)
from rig.stereo.resample import bandlimited
from rig.stereo.timing import estimate_offset
from rig.stereo.timing_joint import JointTiming, sampson_px

SIGMA_PX = 0.1
FS_HZ = 60.0


@pytest.fixture(scope="module")
def rotor_record():
    return twin_record("rotor", "rotor", sigma_px=SIGMA_PX, setup=lambda w: w.rotor.set_frequency(0.0, 10.0))


@pytest.fixture(scope="module")
def rotor_result(rotor_record):
    rec = rotor_record
    # A coarse guess as the camera start events would give it (a few ms off).
    guess = rec.truth_offset_s(float(np.mean(rec.t_right))) + 0.004
    return estimate_offset(
        rec.P_left,
        rec.P_right,
        (rec.t_left, rec.uv_left),
        (rec.t_right, rec.uv_right),
        names=("left", "right"),
        offset_guess_s=guess,
    )


@pytest.mark.slow
def test_offset_from_a_10_s_rotor_record_is_within_the_target_and_the_noise_floor(rotor_record, rotor_result):
    rec, res = rotor_record, rotor_result
    err_s = res.offset_s["right"] - rec.truth_offset_s(res.epoch_s["right"])
    floor_s = offset_floor_s(rec, SIGMA_PX)
    assert abs(err_s) <= 0.05e-3  # the target: 0.05 ms
    assert abs(err_s) <= 5 * floor_s
    # The reported uncertainty matches the floor (the same quantity, from the fit's Jacobian and residuals).
    assert 0.7 * floor_s <= res.uncertainty["offset_s"]["right"] <= 1.5 * floor_s
    assert res.details["sigma_px"] == pytest.approx(SIGMA_PX, rel=0.15)


@pytest.mark.slow
def test_drift_and_line_time_agree_with_the_twin_within_their_uncertainty(rotor_record, rotor_result):
    rec, res = rotor_record, rotor_result
    u = res.uncertainty
    assert abs(res.drift_ppm["right"] - rec.truth_drift_ppm()) <= 5 * u["drift_ppm"]["right"]
    assert u["drift_ppm"]["right"] < 2.0
    assert abs(res.line_time_s["right"] - rec.right.line_time_s) <= 5 * u["line_time_s"]["right"]
    assert res.line_time_s["left"] == res.line_time_s["right"]
    # Row-corrected times of every observation of both cameras on the left clock: right within 0.05 ms up to
    # one constant common to both cameras (a clock origin, which no observation can reveal).
    err = np.concatenate(
        [
            res.times("left", rec.t_left, rec.uv_left[:, 1]) - rec.left_clock_of_world(rec.true_left),
            res.times("right", rec.t_right, rec.uv_right[:, 1]) - rec.left_clock_of_world(rec.true_right),
        ]
    )
    assert np.max(np.abs(err - err.mean())) < 0.05e-3
    assert res.method == "joint" and res.reference_camera == "left"


def _synthetic(traj, *, offset_s=0.0043, n=420, line_time_s=12e-6, height_b_mm=120.0, seed=0):
    cam_a, cam_b = stereo_pair(height_b_mm=height_b_mm)
    rng = np.random.default_rng(seed)
    tau = np.arange(n) / FS_HZ
    ta, ua, _ = observe(cam_a, traj, tau, line_time_s=line_time_s, sigma_px=SIGMA_PX, rng=rng)
    tb, ub, _ = observe(
        cam_b, traj, tau, offset_s=offset_s, line_time_s=line_time_s, sigma_px=SIGMA_PX, rng=rng
    )
    return cam_a, cam_b, (ta, ua), (tb, ub)


@pytest.mark.slow
def test_fixed_line_time_and_several_tracks():
    traj1, _, _ = rotor(frequency_hz=6.0, radius_mm=50.0)
    traj2 = oscillation(4.0, 6.0, (0.2, 1.0, 0.1), centre_mm=(100.0, 50.0, 1400.0))
    ca, cb, a1, b1 = _synthetic(traj1, seed=1)
    _, _, a2, b2 = _synthetic(traj2, seed=2)
    res = estimate_offset(ca, cb, [a1, a2], [b1, b2], line_time_s=12e-6, estimate_drift=False)
    assert res.line_time_s == {"a": 12e-6, "b": 12e-6}
    assert res.uncertainty["line_time_s"]["b"] == 0.0
    assert abs(res.offset_s["b"] - 0.0043) <= 5 * res.uncertainty["offset_s"]["b"]
    assert res.details["parameters"] == ["offset"]


def test_motion_only_in_the_epipolar_plane_raises_no_common_motion():
    # Cameras at the same height, marker moving along the baseline: every epipolar plane contains it.
    traj = oscillation(3.0, 30.0, (1.0, 0.0, 0.0), centre_mm=(0.0, 0.0, 1500.0))
    ca, cb, a, b = _synthetic(traj, height_b_mm=0.0)
    with pytest.raises(NoCommonMotionError, match="epipolar plane"):
        estimate_offset(ca, cb, a, b)


def test_static_marker_raises_no_common_motion():
    def still(t):
        return np.tile([10.0, 20.0, 1500.0], (len(t), 1))

    ca, cb, a, b = _synthetic(still)
    with pytest.raises(NoCommonMotionError):
        estimate_offset(ca, cb, a, b)


def test_offset_beyond_the_search_range_raises():
    traj, _, _ = rotor(frequency_hz=3.0)
    ca, cb, a, b = _synthetic(traj, offset_s=0.030)
    with pytest.raises(DelayOutOfRangeError, match="edge of the search range"):
        estimate_offset(ca, cb, a, b, offset_guess_s=0.0, search_half_width_s=0.010)


def test_periodic_motion_with_a_range_wider_than_its_period_is_ambiguous():
    traj, _, _ = rotor(frequency_hz=10.0)
    ca, cb, a, b = _synthetic(traj, offset_s=0.004)
    with pytest.raises(AmbiguousOffsetError, match="fit equally well"):
        estimate_offset(ca, cb, a, b, search_half_width_s=0.12)


def test_bad_time_stamps_and_too_few_frames():
    traj, _, _ = rotor(frequency_hz=3.0)
    ca, cb, (ta, ua), b = _synthetic(traj)
    back = ta.copy()
    back[100] = back[98]
    with pytest.raises(NonMonotonicTimestampsError, match=r"observations_a\[0\] timestamp_s\[100\]"):
        estimate_offset(ca, cb, (back, ua), b)
    with pytest.raises(TooFewSamplesError):
        estimate_offset(ca, cb, (ta[:20], ua[:20]), b)
    with pytest.raises(NoCommonMotionError, match="overlap"):
        estimate_offset(ca, cb, (ta + 100.0, ua), b)
    with pytest.raises(InputArrayError, match="pair"):
        estimate_offset(ca, cb, ta, b)
    with pytest.raises(InputArrayError, match="method"):
        estimate_offset(ca, cb, (ta, ua), b, method="audio")


def test_single_dropped_frames_of_camera_b_are_bridged_and_do_not_bias_the_offset():
    rec = twin_record(
        "rotor",
        "rotor",
        sigma_px=SIGMA_PX,
        duration_s=5.0,
        seed=5,
        right_overrides={"dropped_frames": [100, 101, 200]},
        setup=lambda w: w.rotor.set_frequency(0.0, 10.0),
    )
    assert np.max(np.diff(rec.t_right)) > 2.5 / FS_HZ  # the gaps are in the time stamps
    guess = rec.truth_offset_s(float(np.mean(rec.t_right))) + 0.004
    res = estimate_offset(
        rec.P_left, rec.P_right, (rec.t_left, rec.uv_left), (rec.t_right, rec.uv_right), offset_guess_s=guess
    )
    err_s = res.offset_s["b"] - rec.truth_offset_s(res.epoch_s["b"])
    gaps = res.details["gaps_b"]
    # both gaps (2 frames and 1) bridged: no instant of A left out around them
    assert (gaps["gaps"], gaps["frames_missing"], gaps["bridged"]) == (2, 3, 2), gaps
    assert res.details["n_left_out_near_gaps"] == 0 and gaps["left_out_ill_conditioned"] == 0
    # The residuals are as clean as the pixel noise (the bridging adds no error beyond its noise gain) …
    assert res.details["sigma_px"] == pytest.approx(SIGMA_PX, rel=0.15)
    # … and the offset is within its noise floor.
    assert abs(err_s) <= 5 * offset_floor_s(rec, SIGMA_PX)


def test_twenty_percent_of_frames_lost_at_random_in_both_cameras_leaves_a_joint_estimate_within_k3():
    """The sync's 3-s rotor recording with 20 % of both cameras' frames lost at random (≈ 30 gaps in B):
    today's guard of ±32 frames around every gap left nothing (NoCommonMotionError); bridged, offset,
    line time and drift lie within 3 stated standard uncertainties of the truth."""
    traj, _, _ = rotor(frequency_hz=10.0)
    cam_a, cam_b = stereo_pair(height_b_mm=120.0)
    rng = np.random.default_rng(2026)
    tau = np.arange(180) / FS_HZ
    truth = {"offset_s": 0.0043, "line_time_s": 12e-6, "drift_ppm": 30.0, "epoch_s": 1.5}
    ta, ua, _ = observe(cam_a, traj, tau, line_time_s=12e-6, sigma_px=SIGMA_PX, rng=rng)
    tb, ub, _ = observe(cam_b, traj, tau, offset_s=truth["offset_s"], line_time_s=truth["line_time_s"],
                        drift_ppm=truth["drift_ppm"], epoch_s=truth["epoch_s"], sigma_px=SIGMA_PX, rng=rng)
    keep_a, keep_b = rng.random(tau.size) > 0.2, rng.random(tau.size) > 0.2
    res = estimate_offset(cam_a, cam_b, (ta[keep_a], ua[keep_a]), (tb[keep_b], ub[keep_b]),
                          offset_guess_s=0.0043 + 0.004, search_half_width_s=2 / FS_HZ)
    u = res.uncertainty
    epoch_s = res.epoch_s["b"]
    offset_truth_s = truth["offset_s"] + truth["drift_ppm"] * 1e-6 * (epoch_s - truth["epoch_s"])
    assert abs(res.offset_s["b"] - offset_truth_s) <= 3 * u["offset_s"]["b"]
    assert abs(res.line_time_s["b"] - truth["line_time_s"]) <= 3 * u["line_time_s"]["b"]
    assert abs(res.drift_ppm["b"] - truth["drift_ppm"]) <= 3 * u["drift_ppm"]["b"]
    gaps = res.details["gaps_b"]
    assert gaps["bridged"] >= 20 and gaps["prediction_gain"][0] >= 1e3, gaps
    assert res.details["sigma_px"] == pytest.approx(SIGMA_PX, rel=0.2)


@pytest.mark.slow
def test_with_lens_distortion_the_observed_rows_set_the_rolling_shutter_instants() -> None:
    """The epipolar geometry needs undistorted centres, the rolling shutter the sensor rows (given as a third
    track element): with the default pair's lens distortion, offset and line time stay within their
    uncertainty of the truth. Undistortion here is OpenCV's, not ours."""
    import cv2

    rec = twin_record("rotor", "rotor", sigma_px=SIGMA_PX, lens_distortion=True,
                      setup=lambda w: w.rotor.set_frequency(0.0, 10.0))

    def undistorted(cam, uv):
        k = cam.camera_matrix
        pts = cv2.undistortPoints(uv.reshape(-1, 1, 2), k, cam.distortion, P=k)
        return pts.reshape(-1, 2)

    ua, ub = undistorted(rec.left, rec.uv_left), undistorted(rec.right, rec.uv_right)
    guess = rec.truth_offset_s(float(np.mean(rec.t_right))) + 0.004
    kwargs = {"names": ("left", "right"), "offset_guess_s": guess}
    with_rows = estimate_offset(rec.P_left, rec.P_right, (rec.t_left, ua, rec.uv_left[:, 1]),
                                (rec.t_right, ub, rec.uv_right[:, 1]), **kwargs)
    without = estimate_offset(rec.P_left, rec.P_right, (rec.t_left, ua), (rec.t_right, ub), **kwargs)

    def error_s(res):
        return res.offset_s["right"] - rec.truth_offset_s(res.epoch_s["right"])

    u_s = with_rows.uncertainty["offset_s"]["right"]
    assert abs(error_s(with_rows)) <= 5 * u_s
    u_line_s = with_rows.uncertainty["line_time_s"]["right"]
    assert with_rows.line_time_s["right"] == pytest.approx(rec.right.line_time_s, abs=5 * u_line_s)
    # Near the image centre the rows move little under distortion: undistorted rows are nearly as good here.
    assert abs(error_s(without)) <= 5 * without.uncertainty["offset_s"]["right"]


def _costs_one_offset_at_a_time(prob: JointTiming, offsets_s: np.ndarray, line_s: float,
                                drift_ppm: float) -> np.ndarray:
    """The straightforward coarse cost: B's track reconstructed anew at each offset (the reference)."""
    res = prob.res
    costs = []
    for d in offsets_s:
        total = 0.0
        for (ta, ua, ra, tb, ub, rb), bridge in zip(res.data, res.bridges, strict=True):
            t_src = tb + d + drift_ppm * 1e-6 * (tb - res.epoch_b) + line_s * rb
            uv_b_at = bandlimited(t_src, ub, ta + line_s * ra, **bridge)
            total += float(np.sum(sampson_px(res.F, ua, uv_b_at) ** 2))
        costs.append(total)
    return np.array(costs)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_coarse_costs_over_all_offsets_equal_one_reconstruction_per_offset(seed: int) -> None:
    rng = np.random.default_rng(seed)
    traj, _, _ = rotor(frequency_hz=rng.uniform(2.0, 12.0), radius_mm=rng.uniform(20.0, 80.0))
    ca, cb, (ta, ua), (tb, ub) = _synthetic(traj, n=240, offset_s=rng.uniform(-0.01, 0.01), seed=seed)
    keep = np.ones(tb.size, dtype=bool)
    keep[rng.choice(np.arange(40, 200), size=4, replace=False)] = False  # single lost frames: bridged
    prob = JointTiming(ca, cb, (ta, ua), (tb[keep], ub[keep]))
    assert prob.res.bridged_b > 0
    offsets = prob.guess_s + np.linspace(-0.03, 0.03, 31)
    for line_s, drift_ppm in ((0.0, 0.0), (rng.uniform(5e-6, 20e-6), rng.uniform(-100.0, 100.0))):
        want = _costs_one_offset_at_a_time(prob, offsets, line_s, drift_ppm)
        got = prob.res.offset_costs(offsets, line_s, drift_ppm)
        # Float rounding only: the instants (≤ 4 s) move by ~1e-15 s between the two ways, B's image by
        # ≤ 1e-11 px at ≤ 3e3 px/s, so each residual r by ~1e-11 px and the cost by ≤ 2·Σ|r|·1e-11 px²:
        # 1e-9 of the cost (whose residuals are ≥ the 0.1-px noise) bounds it.
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=0.0)
        assert np.argmin(got) == np.argmin(want)
        assert prob.cost(float(offsets[7]), line_s, drift_ppm) == pytest.approx(want[7], rel=1e-9, abs=0.0)
