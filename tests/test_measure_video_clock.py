"""Relating an imported video's clock to the controller's record from the motion it shows."""

from __future__ import annotations

from pathlib import Path

import measure_twin as mt
import pandas as pd
import pytest

from drivers.sim.clock import VirtualClock
from drivers.sim.world import World, WorldLayout
from rig.deploy.video_clock import VideoClockError, relate_to_record
from rig.deploy.video_markers import extract_video
from rig.record.reader import load_run
from rig.record.writer import RunRecord

MOVES = ((0.8, (350.0, 80.0, 300.0)), (1.9, (350.0, 80.0, 360.0)), (2.6, (350.0, -40.0, 330.0)))


def _scene(tmp_path: Path) -> tuple[Path, list[tuple[float, float]], World]:
    clock = VirtualClock()
    world = World(clock, seed=7, layout=WorldLayout(initial_scene="single_marker"))
    spans = []
    for t, xyz in MOVES:
        end = world.robot.move(t, (*xyz, 90.0, 0.0, 90.0), 250.0, 2000.0, True)
        spans.append((t, end))
    rec = RunRecord.create(tmp_path / "runs", "accuracy", {}, {}, clock)
    for k, (t, end) in enumerate(spans):
        clock.advance_to(t)
        rec.event("arm", {"commanded_pose": [*MOVES[k][1], 90, 0, 90], "reported_pose": None,
                          "t_start_s": t, "t_end_s": end})
    rec.stop("success")
    rec.close()
    return rec.run_dir, spans, world


def test_offset_from_the_arm_moves_the_video_shows(tmp_path: Path) -> None:
    run_dir, _, world = _scene(tmp_path)
    left, _ = mt.camera_pair(world)
    left.write_video(tmp_path / "cam.mp4", 0.3, 3.6)
    obs = extract_video(tmp_path / "cam.mp4", "cam").observations
    events = load_run(run_dir).events
    rel = relate_to_record(obs, events, 1 / 60)
    first = left.first_frame_index_at_or_after(0.3)
    truth = left.frame_start_true_s(first) + 0.5 * left.exposure_s  # controller (= world) − video clock
    assert rel["streams"] == ["arm"] and rel["correlation"] > 0.5
    # the stated bound (a frame for the sampling, a frame for the rolling-shutter readout) holds: the arm's
    # symmetric trapezoid moves centre on the commanded spans
    assert abs(rel["offset_s"] - truth) <= rel["uncertainty_s"], (rel, truth)


def test_a_video_without_the_recorded_motion_is_refused(tmp_path: Path) -> None:
    run_dir, _, _ = _scene(tmp_path)
    still = World(VirtualClock(), seed=8, layout=WorldLayout(initial_scene="single_marker"))
    left, _ = mt.camera_pair(still)
    left.write_video(tmp_path / "still.mp4", 0.3, 1.5)
    obs = extract_video(tmp_path / "still.mp4", "cam").observations
    with pytest.raises(VideoClockError, match="does not show the recorded procedure"):
        relate_to_record(obs, load_run(run_dir).events, 1 / 60)
    with pytest.raises(VideoClockError, match="no motion events"):
        relate_to_record(obs, {"arm": pd.DataFrame()}, 1 / 60)
