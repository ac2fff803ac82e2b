"""On-site calibration from a video pair of the slid plate (twin videos), and its clear errors."""

from __future__ import annotations

import json
from pathlib import Path

import measure_twin as mt
import numpy as np
import pandas as pd
import pytest

from rig.deploy.onsite_calibration import (
    OnsiteCalibrationError,
    calibrate_from_videos,
    load_target,
    still_segments,
)
from rig.deploy.video_markers import ExtractOptions, extract_video
from rig.stereo import DLTCamera


@pytest.fixture(scope="module")
def videos(mjpg_site: dict) -> dict:
    """The twin's slid-plate pair as Motion-JPEG AVIs: the session's ``mjpg_site`` plate videos (rendered once
    for the files that read them, tests/conftest.py), its target and truth, and the twin's cameras."""
    world, _, _ = mt.calibration_world()
    folder = mjpg_site["folder"]
    return {"truth": mjpg_site["truth"], "cams": mt.camera_pair(world),
            "paths": {"left": folder / "cal_left.avi", "right": folder / "cal_right.avi"},
            "target": mjpg_site["target"]}


def test_still_segments_are_the_holds(videos: dict) -> None:
    obs = extract_video(videos["paths"]["left"], "left", ExtractOptions(mode="detect")).observations
    segs = still_segments(obs)
    assert len(segs) == len(mt.SLIDES_MM)
    # each found segment lies inside its hold (the robot's moves take the time between the holds)
    holds_end = np.cumsum([mt.HOLD_S] * len(mt.SLIDES_MM))
    for seg in segs:
        assert seg["t_stop_s"] - seg["t_start_s"] >= 19 / 60
    # (the arm accelerates from rest: its first frame of motion may still be within still_px of the hold)
    assert segs[0]["t_start_s"] == 0.0 and segs[0]["t_stop_s"] < holds_end[0] + 1.5 / 60


def test_calibration_identifies_the_grid_and_reports_residuals(videos: dict) -> None:
    cal = calibrate_from_videos(videos["paths"], videos["target"])
    pts = np.concatenate(videos["truth"])
    for name, sim in zip(("left", "right"), videos["cams"], strict=True):
        entry = cal["cameras"][name]
        assert entry["n_points"] == 105 and entry["image_size"] == [960, 540]
        assert len(entry["residuals_px"]) == 105 and entry["residuals_rms_px"] > 0
        # a wrongly identified node would be off by a grid pitch (≈ 30 px); the fitted camera reproduces
        # the twin's exact projection far below that, at the level of the centroid noise
        err = np.linalg.norm(DLTCamera.from_dict(entry).project(pts) - sim.project(pts), axis=1)
        assert err.max() < 0.25
        assert len(cal["videos"][name]["segments"]) == 3
    json.dumps(cal)  # JSON-ready


def test_wrong_number_of_positions_is_a_clear_error(videos: dict, tmp_path: Path) -> None:
    two = mt.write_target(tmp_path / "two.toml", videos["truth"][:2])
    with pytest.raises(OnsiteCalibrationError,
                       match=r"found 3 still segment\(s\) \(0.00–.* but target lists 2"):
        calibrate_from_videos(videos["paths"], two)
    with pytest.raises(OnsiteCalibrationError, match=r"found 0 still segment\(s\) \(none\)"):
        calibrate_from_videos(videos["paths"], videos["target"], min_still_frames=200)


def test_unidentifiable_grid_is_a_clear_error(videos: dict, tmp_path: Path) -> None:
    four_rows = mt.write_target(tmp_path / "t.toml", [p[:28] for p in videos["truth"]])
    four_rows.write_text(four_rows.read_text().replace("rows = 5", "rows = 4"))
    with pytest.raises(OnsiteCalibrationError,
                       match=r"'left', position 0 .*plate grid not identified: found 35 plate markers"):
        calibrate_from_videos(videos["paths"], four_rows)
    # a transposed grid is still a grid in the image: the wrong coordinates then fit no camera
    text = videos["target"].read_text().replace("rows = 5", "rows = 7").replace("cols = 7", "cols = 5")
    (tmp_path / "transposed.toml").write_text(text)
    with pytest.raises(OnsiteCalibrationError, match=r"camera .left.: the control points do not fit"):
        calibrate_from_videos(videos["paths"], tmp_path / "transposed.toml")


@pytest.mark.parametrize(("text", "message"), [
    ("[plate]\nrows = 5\ncols = 7\n", r"\[\[positions\]\] has 0 entries"),
    ("[plate]\nrows = 1\ncols = 7\n", r"plate.rows = 1; allowed: an integer ≥ 2"),
    ("rows = 5", r"\[plate\] missing"),
    ("[plate\n", "not valid TOML"),
    ("[plate]\nrows = 2\ncols = 2\n[[positions]]\nmarkers_mm = [[0, 0, 0]]\n"
     "[[positions]]\nmarkers_mm = []\n",
     r"positions\[0\].markers_mm has shape \(1, 3\); allowed: 4 finite"),
])
def test_target_file_errors_name_the_field(tmp_path: Path, text: str, message: str) -> None:
    (tmp_path / "t.toml").write_text(text)
    with pytest.raises(OnsiteCalibrationError, match=message):
        load_target(tmp_path / "t.toml")
    with pytest.raises(OnsiteCalibrationError, match="no such target file"):
        load_target(tmp_path / "missing.toml")


def _holds(lengths: list[int], move_frames: int = 8, seed: int = 0) -> pd.DataFrame:
    """Observations of a 3-marker plate held still for ``lengths`` frames, sliding 2 px/frame between holds
    (noise 0.03 px)."""
    rng = np.random.default_rng(seed)
    base = np.array([[100.0, 100.0], [200.0, 120.0], [150.0, 300.0]])
    rows, offset, k = [], 0.0, 0
    for n in lengths:
        for i in range(n + move_frames):
            at = offset + 2.0 * max(0, i - n + 1)
            for uv in base + np.array([at, 0.3 * at]) + rng.normal(0, 0.03, base.shape):
                rows.append((k, k / 60, *uv))
            k += 1
        offset += 2.0 * (move_frames + 1)
    return pd.DataFrame(rows, columns=["frame_index", "timestamp_s", "u_px", "v_px"])


def test_a_hold_of_exactly_min_still_frames_is_a_segment() -> None:
    """The hold needed is min_still_frames itself (no hidden lag on either side): 12 frames pass at 12."""
    obs = _holds([12, 11, 30])
    short: list[int] = []
    segs = still_segments(obs, min_still_frames=12, short_runs=short)
    assert [s["last_index"] - s["first_index"] + 1 for s in segs] == [12, 30]
    assert short == [11]  # the 11-frame hold between them, reported for the error message
    assert len(still_segments(obs, min_still_frames=11)) == 3


def test_short_holds_error_says_what_is_needed(videos: dict) -> None:
    with pytest.raises(OnsiteCalibrationError, match=r"≥ 200 frames \(--min-still-frames\) .*longest shorter "
                       r"still runs last \[\d+"):
        calibrate_from_videos(videos["paths"], videos["target"], min_still_frames=200)
