"""Pieces of the procedures without a station: frame reduction, plans, profiles, truth geometry, verdicts."""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd
import pytest

from drivers.denso.pose import rotation_matrix
from drivers.mock import vp6242
from procedures import accuracy, calibrate, certify, plate, sweep, sync
from procedures._common import arm_marker_positions, plate_offsets_tool_mm
from procedures._report import verdict_of
from rig.analysis.frame_reduction import MarkerReducer, ReduceOptions
from rig.config.rig_config import default_config
from rig.run.acquire import mean_positions, settled_frames
from rig.run.procedure import ParameterError


def _frame(centres: list[tuple[float, float]], seed: int = 0) -> np.ndarray:
    img = np.full((240, 320), 30, np.uint8)
    for u, v in centres:
        centre = (round(u * 16), round(v * 16))
        cv2.circle(img, centre, 8 * 16, 220, -1, lineType=cv2.LINE_AA, shift=4)
    noise = np.random.default_rng(seed).normal(0, 2, img.shape)
    return np.clip(cv2.GaussianBlur(img, (0, 0), 0.8) + noise, 0, 255).astype(np.uint8)


def test_reducer_keeps_track_numbers_and_redetects_a_lost_marker() -> None:
    reducer = MarkerReducer(ReduceOptions(mode="track", window_px=31, redetect_every=100))
    still = (60.0, 60.0)
    first, ids0 = reducer.reduce(_frame([still, (150.0, 120.0)]))
    assert len(first) == 2 and sorted(ids0) == [0, 1]
    moved, ids1 = reducer.reduce(_frame([still, (155.0, 123.0)], seed=1))  # within the window: tracked
    assert list(ids1) == list(ids0)
    k = int(np.argmax(moved["u_px"]))
    assert abs(moved["u_px"][k] - 155.0) < 0.3 and abs(moved["v_px"][k] - 123.0) < 0.3
    jumped, ids2 = reducer.reduce(_frame([still, (260.0, 200.0)], seed=2))  # lost: whole-frame detection
    assert len(jumped) == 2
    still_id = ids0[int(np.argmin(first["u_px"]))]
    assert still_id in ids2 and 2 in ids2  # the still marker keeps its number, the far one is new


def test_reduce_options_are_checked() -> None:
    with pytest.raises(ValueError, match="mode='fast'"):
        ReduceOptions(mode="fast")
    with pytest.raises(ValueError, match="window_px=5"):
        ReduceOptions(window_px=5)


def test_mean_positions_average_still_frames() -> None:
    obs = pd.DataFrame({"track_2d": [0, 0, 0, 1], "u_px": [1.0, 2.0, 3.0, 9.0], "v_px": [0.0, 0.0, 3.0, 9.0]})
    out = mean_positions(obs, min_frames=2)
    assert list(out["track_2d"]) == [0] and out["u_px"][0] == 2.0 and out["n"][0] == 3


def test_settled_frames_leave_out_the_frames_before_the_plate_came_to_rest() -> None:
    # two plate markers arriving (10 → 0.3 px from rest over frames 0–3), then still with 0.05 px noise, and a
    # static reference; marker 1's track broke while it moved (ids 1 then 3): one marker, not two
    rng = np.random.default_rng(3)
    rows = []
    for frame in range(12):
        off_px = [10.0, 4.0, 1.6, 0.3][frame] if frame < 4 else 0.0
        markers = ((0, (100.0, 50.0)), (1 if frame < 2 else 3, (140.0, 50.0)), (2, (400.0, 300.0)))
        for track, (u, v) in markers:
            moving = track != 2
            rows.append({"frame_index": frame, "track_2d": track,
                         "u_px": u + (off_px if moving else 0.0) + rng.normal(0, 0.05), "v_px": v})
    obs = pd.DataFrame(rows)
    still = settled_frames(obs)
    assert sorted(still["frame_index"].unique()) == list(range(3, 12))  # frame 3 (0.3 px) is at rest
    means = mean_positions(still, min_frames=6)
    assert sorted(means["track_2d"]) == [0, 2, 3]
    assert np.allclose(means.sort_values("track_2d")["u_px"], [100.0, 400.0, 140.0], atol=0.15)
    # without the filter the average is biased by the arrival and marker 1 shows twice
    biased = mean_positions(obs, min_frames=2)
    assert sorted(biased["track_2d"]) == [0, 1, 2, 3] and biased["u_px"][0] > 101.0
    assert settled_frames(obs.iloc[:0]).empty


def test_sweep_profiles_rise_monotonically_to_the_peak() -> None:
    for shape in ("fig17", "linear", "log"):
        prof = sweep.profile_of(sweep.Parameters(shape=shape))
        pts = np.array(prof.points(0.5))
        assert pts[0, 1] == pytest.approx(1.0) and pts[-1, 1] == pytest.approx(30.0)
        assert np.all(np.diff(pts[:, 1]) >= 0) and pts[-1, 0] == pytest.approx(25.0)
    fig17 = sweep.profile_of(sweep.Parameters())
    assert fig17.max_slope_hz_per_s() == pytest.approx(1.4 * 29 / 24)  # steepest in the last quarter
    assert fig17.max_slope_hz_per_s() <= default_config().limits.exciter.max_ramp_rate_hz_per_s
    with pytest.raises(ValueError, match="must exceed start_hz"):
        sweep.Parameters(start_hz=5.0, max_hz=4.0)


def test_marker_truth_follows_the_commanded_pose() -> None:
    pose = [400.0, 20.0, 310.0, 90.0, 0.0, 90.0]
    pos = arm_marker_positions(pose, {"m": [10.0, 20.0, 30.0]})["m"]
    assert np.allclose(pos, np.array(pose[:3]) + rotation_matrix(90, 0, 90) @ [10, 20, 30])
    assert np.allclose(pos, [430.0, 30.0, 330.0])  # tool x = base y, tool y = base z, tool z = base x
    cfg = default_config()
    offsets = plate_offsets_tool_mm(cfg.targets.calibration_plate)
    assert offsets["cal_r0c0"] == [-120.0, 80.0, 30.0] and len(offsets) == 35
    poses = calibrate.plate_poses(cfg.targets.calibration_plate, (-50.0, 50.0))
    assert np.allclose(np.array(poses)[:, 0], [370.0, 470.0])  # slid along tool z = base x


def test_accuracy_plan_fills_the_volume_and_puts_the_marker_on_target() -> None:
    volume = default_config().targets.volume
    grid = accuracy.grid_targets(volume, 3, 0.8)
    assert len(grid) == 27
    assert np.allclose(np.min(grid, axis=0), [340.0, -120.0, 220.0])
    assert np.allclose(np.max(grid, axis=0), [500.0, 120.0, 380.0])
    iso = accuracy.iso_targets(volume, 0.8)
    assert np.allclose(iso["P1"], volume.centre_mm) and set(iso) == {"P1", "P2", "P3", "P4", "P5"}
    orient = np.array([90.0, 0.0, 90.0])
    for target in grid:
        flange = accuracy.flange_pose_for(target, np.array([0.0, 0.0, 30.0]), orient)
        assert np.allclose(arm_marker_positions(flange, {"arm": [0, 0, 30]})["arm"], target)
        assert vp6242.solve(flange).violation is None  # the twin's arm reaches every default pose
    offsets = np.array(default_config().targets.marker_frame.offsets_mm)
    for pose in accuracy.frame_flange_poses(volume, offsets, orient, 4):
        assert vp6242.solve(pose).violation is None


def test_builtin_calibration_slides_are_within_the_mock_arms_reach() -> None:
    plate_cfg = default_config().targets.calibration_plate
    for pose in calibrate.plate_poses(plate_cfg, plate_cfg.slide_positions_mm):
        assert vp6242.solve(pose).violation is None, pose


def test_plate_marker_amplitudes_follow_the_cantilever_shape() -> None:
    amps = plate.marker_amplitudes_mm(default_config().targets.plate, 4.0)
    row = [amps[f"plate_r0c{c}"] for c in range(6)]
    assert np.all(np.diff(row) > 0) and row[-1] < 4.0
    xi = 300.0 / 320.0
    assert row[-1] == pytest.approx(4.0 * (3 * xi**2 - xi**3) / 2)


def test_moving_marker_is_told_from_the_references() -> None:
    rows = []
    for k in range(30):
        rows += [(k, 0.1 + k / 60, 100.0, 100.0), (k, 0.1 + k / 60, 500.0, 80.0)]  # references
        a = 2 * np.pi * 10 * k / 60
        rows.append((k, 0.1 + k / 60, 300 + 100 * np.cos(a), 300 + 100 * np.sin(a)))  # the rotor
    obs = pd.DataFrame(rows, columns=["frame_index", "timestamp_s", "u_px", "v_px"])
    t, uv = sync.moving_marker(obs)
    assert len(t) == 30 and np.allclose(np.hypot(uv[:, 0] - 300, uv[:, 1] - 300), 100)
    events = [{"camera": "left", "action": "start", "first_timestamp_s": 12.5},
              {"camera": "right", "action": "start", "first_timestamp_s": 800.0}]
    assert sync.offset_guess_s(events, "left", "right") == pytest.approx(-787.5)


def test_certify_presets_and_overrides() -> None:
    sub = certify.sub_parameters(certify.Parameters(preset="fast", sweep_max_hz=14.0, accuracy_cycles=2))
    assert sub["sweep"].max_hz == 14.0 and sub["sweep"].start_hz == 2.0 and sub["accuracy"].cycles == 2
    assert certify.sub_parameters(certify.Parameters())["sweep"].max_hz == 30.0
    with pytest.raises(ParameterError, match=r"certify\.sweep: .*must exceed start_hz"):
        certify.sub_parameters(certify.Parameters(preset="fast", sweep_max_hz=1.0))


def test_verdict_needs_every_criterion_evaluated_and_passing() -> None:
    rows = [{"id": "a", "status": "PASS"}, {"id": "b", "status": "PASS"}]
    assert verdict_of({"criteria": rows}) == (True, "2/2 criteria pass")
    passed, text = verdict_of({"criteria": [*rows, {"id": "c", "status": "NOT EVALUATED"}]})
    assert not passed and "not evaluated: c" in text
    passed, text = verdict_of({"criteria": [*rows, {"id": "d", "status": "FAIL"}]})
    assert not passed and "failed: d" in text
    assert verdict_of({"criteria": []})[0] is False
