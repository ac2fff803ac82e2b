"""``analyse(run_dir)`` on run folders written by the real record writer from twin observations: tracks on
the controller clock, clock offset within its stated bound, volume from the configuration snapshot,
deterministic output, and a clear error for each missing input."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from analysis_twin import twin, write_run

from rig.analysis.analyse import SYNC_METHODS, TRACK_COLUMNS, analyse, pairing_volume
from rig.analysis.errors import (
    AnalysisError,
    ClockMappingError,
    MissingInputError,
    MissingObservationsError,
    NoPairableTracksError,
)
from rig.stereo.triangulate import triangulate

RIG = {
    "cameras": {"left": {"fps": 60.0}, "right": {"fps": 60.0}},
    "limits": {"robot": {"envelope_x_mm": [150.0, 650.0], "envelope_y_mm": [-350.0, 350.0],
                         "envelope_z_mm": [50.0, 650.0]}},
    "targets": {"references": {"positions_mm": [[200.0, -230.0, 470.0], [220.0, 0.0, 530.0],
                                                [200.0, 230.0, 470.0], [180.0, 250.0, 110.0]]}},
}
SEGMENTS = [("still", 1.0, 2.0), ("shake", 3.0, 4.0)]


def _moving():
    return twin("sweep_column", setup=lambda w: w.exciter.set_frequency(2.5, 5.0), sigma_px=0.15, seed=21,
                distortion=True)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    tw = _moving()
    return tw, write_run(tmp_path_factory.mktemp("runs"), tw, SEGMENTS, rig=RIG)


def test_tracks_are_on_the_controller_clock_within_the_stated_bound(run):
    tw, run_dir = run
    a = analyse(run_dir)
    assert list(a.tracks.columns) == TRACK_COLUMNS
    assert set(a.tracks["segment"]) == {"still", "shake"}
    assert a.sync == "trajectory" and a.timing.reference_camera == "left"
    assert set(a.calibration.cameras) == {"left", "right"}
    for seg in ("still", "shake"):
        assert a.tracks.loc[a.tracks["segment"] == seg, "track_id"].nunique() == 9  # 5 column + 4 references
        row = a.clock[a.clock["segment"] == seg].iloc[0]
        t_ref = a.tracks.loc[a.tracks["segment"] == seg, "time_s"].median() - row["offset_s"]
        true_offset = float(tw.world_time(np.array([t_ref]))[0] - t_ref)
        # first frame exposes within one period after the start event; both cameras averaged: ≤ T/2
        assert abs(row["offset_s"] - true_offset) <= 0.5 / 60.0
        assert "start event" in row["source"]


def test_contract_style_events_give_the_same_clock(run, tmp_path):
    """Events written at the start with only the contract's fields give the same offsets as events written
    after the recording carrying ``t_s`` and ``segment`` (rig/run/acquire.py)."""
    tw = _moving()
    run_dir = write_run(tmp_path, tw, SEGMENTS, rig=RIG, event_style="contract")
    a, b = analyse(run_dir, sync="linear"), analyse(run[1], sync="linear")
    assert np.allclose(a.clock["offset_s"], b.clock["offset_s"], rtol=0, atol=1e-9)


def test_static_segment_reaches_the_noise_floor(run):
    """Still markers: the controller-clock uncertainty does not matter; the error is the pixel noise's."""
    tw, run_dir = run
    a = analyse(run_dir, sync="linear")
    still = a.tracks[a.tracks["segment"] == "still"]
    cams = [tw.cameras["left"], tw.cameras["right"]]
    for _, g in still.groupby("track_id"):
        X = g[["x_mm", "y_mm", "z_mm"]].to_numpy()
        pos = tw.world.markers(g["time_s"].to_numpy())
        m = min(pos, key=lambda k: np.linalg.norm(pos[k] - X, axis=1).mean())
        truth = pos[m]
        cov = triangulate(cams, [c.project(truth) for c in cams], pixel_sigma_px=tw.sigma_px).covariance_mm2
        sq = np.sum((X - truth) ** 2, axis=1)
        expected = float(np.mean(np.trace(cov, axis1=1, axis2=2)))
        sd = float(np.sqrt(2 * np.sum(np.einsum("nij,nji->n", cov, cov)))) / len(sq)
        assert np.mean(sq) <= expected + 4 * sd, (m, np.mean(sq), expected)


def test_analysis_is_deterministic_and_methods_differ(run):
    _, run_dir = run
    first, again = analyse(run_dir, sync="cubic"), analyse(run_dir, sync="cubic")
    assert first.tracks.equals(again.tracks)
    linear = analyse(run_dir, sync="linear")
    assert len(linear.tracks) == len(first.tracks)
    assert not np.allclose(linear.tracks["z_mm"], first.tracks["z_mm"])


def test_a_run_prepared_once_gives_each_methods_analysis(run, monkeypatch):
    """A report's analyses prepare the run once (2-D tracks, pairs, clocks: what no sync method changes) and
    triangulate it per method: the same tracks, pairs, clock and notes as analysing the folder anew."""
    from reports.build import _default_analyse
    from rig.analysis import analyse as module
    from rig.record.folder import load_folder

    _, run_dir = run
    prepared = []
    prepare = module.prepare_run
    monkeypatch.setattr(module, "prepare_run", lambda *a, **k: prepared.append(a) or prepare(*a, **k))
    report_analyse, folder = _default_analyse(), load_folder(run_dir)
    for sync in ("trajectory", "linear", "trajectory"):
        shared, anew = report_analyse(folder, sync=sync), analyse(run_dir, sync=sync)
        for field in ("tracks", "pairs", "clock"):
            assert getattr(shared, field).equals(getattr(anew, field)), (sync, field)
        assert shared.notes == anew.notes and shared.sync == sync
    assert len(prepared) == 1 + 3  # the report's once, each fresh analyse() its own


def test_pairing_volume_comes_from_the_snapshot():
    vol = pairing_volume(RIG, margin_mm=100.0)
    assert vol == ((50.0, 750.0), (-450.0, 450.0), (-50.0, 750.0))
    assert pairing_volume({}) is None


def test_bad_sync_is_named(run):
    with pytest.raises(AnalysisError, match="sync"):
        analyse(run[1], sync="nearest")
    assert "linear" in SYNC_METHODS


@pytest.fixture
def copy(run, tmp_path):
    def make():
        target = tmp_path / "run"
        shutil.copytree(run[1], target)
        return target
    return make


def test_missing_calibration_says_what_to_run(copy):
    run_dir = copy()
    (run_dir / "calibration.json").unlink()
    with pytest.raises(MissingInputError, match=r"calibration\.json.*rig run calibrate"):
        analyse(run_dir)


def test_missing_timing_says_what_to_run(copy):
    run_dir = copy()
    (run_dir / "timing.json").unlink()
    with pytest.raises(MissingInputError, match=r"timing\.json.*rig run sync"):
        analyse(run_dir)


def test_camera_without_observations_is_named(copy):
    run_dir = copy()
    shutil.rmtree(run_dir / "observations" / "right")
    with pytest.raises(MissingObservationsError, match="right"):
        analyse(run_dir)


def test_segment_where_one_camera_saw_nothing_is_named(tmp_path):
    tw = _moving()
    run_dir = write_run(tmp_path, tw, SEGMENTS, rig=RIG, blind=(("shake", "right"),))
    with pytest.raises(MissingObservationsError, match=r"shake.*right"):
        analyse(run_dir)


def test_swapped_calibration_gives_no_pairable_tracks(copy):
    run_dir = copy()
    cal = json.loads((run_dir / "calibration.json").read_text())
    cal["cameras"]["left"], cal["cameras"]["right"] = cal["cameras"]["right"], cal["cameras"]["left"]
    (run_dir / "calibration.json").write_text(json.dumps(cal))
    with pytest.raises(NoPairableTracksError, match=r"shake.*still.*rig run calibrate"):
        analyse(run_dir)


def test_no_camera_events_is_a_clock_error(tmp_path):
    tw = _moving()
    run_dir = write_run(tmp_path, tw, SEGMENTS[:1], rig=RIG, camera_events=False)
    with pytest.raises(ClockMappingError, match="still"):
        analyse(run_dir)


def test_malformed_timing_is_named(copy):
    run_dir = copy()
    (run_dir / "timing.json").write_text(json.dumps({"offset_s": {"left": 0.0}}))
    with pytest.raises(AnalysisError, match="reference_camera"):
        analyse(run_dir)


def test_not_a_run_folder(tmp_path):
    with pytest.raises(MissingInputError, match=r"record\.jsonl"):
        analyse(tmp_path)


def test_short_still_recordings_at_several_arm_poses(tmp_path):
    """The accuracy procedure's pattern: one step, a few still frames at each pose, the arm moving unseen in
    between. Every pose gives its own track of the arm marker, at the commanded place within the noise."""
    tw = twin("single_marker", t_start_s=0.5, t_stop_s=0.6, sigma_px=0.15, seed=31)
    poses = [(420.0, -60.0, 260.0, 90.0, 0.0, 90.0), (470.0, 60.0, 340.0, 90.0, 0.0, 90.0),
             (380.0, 0.0, 300.0, 90.0, 0.0, 90.0)]
    t, windows = 1.0, []
    for pose in poses:
        t_end = tw.world.robot.move(t, np.array(pose), 300.0, 2000.0, True)
        windows.append(("accuracy", t_end + 0.2, t_end + 0.2 + 5.5 / 60.0))  # four or five still frames
        t = t_end + 0.5
    run_dir = write_run(tmp_path, tw, windows, rig=RIG)
    a = analyse(run_dir, sync="trajectory")
    cams = [tw.cameras["left"], tw.cameras["right"]]
    arm_tracks = 0
    for _, g in a.tracks.groupby("track_id"):
        X = g[["x_mm", "y_mm", "z_mm"]].to_numpy()
        pos = tw.world.markers(g["time_s"].to_numpy())
        if np.linalg.norm(pos["arm"] - X, axis=1).mean() > 20.0:
            continue  # a reference marker
        arm_tracks += 1
        truth = pos["arm"]  # still: the ± T/2 clock uncertainty does not matter
        cov = triangulate(cams, [c.project(truth) for c in cams], pixel_sigma_px=tw.sigma_px).covariance_mm2
        # the spline of a few still frames averages them: its error is at most one frame's triangulation
        # error; bound the mean square by a single frame's expectation + 4 sd
        tr = np.trace(cov, axis1=1, axis2=2)
        assert np.mean(np.sum((X - truth) ** 2, axis=1)) <= np.mean(tr) * (1 + 4 * np.sqrt(2)), g
    assert arm_tracks == len(poses)
    assert len(a.clock) == 1 and "3 camera" not in a.clock["source"].iloc[0]
    assert a.clock["source"].iloc[0].startswith("fit of all 6 camera start events")


def test_a_resumed_run_analyses_both_sessions(tmp_path):
    tw = _moving()
    run_dir = write_run(tmp_path, tw, SEGMENTS, rig=RIG, resume_before="shake")
    a = analyse(run_dir, sync="linear")
    assert list(a.clock["session"]) == [1, 0] and list(a.clock["segment"]) == ["shake", "still"]
    assert set(a.tracks["segment"]) == {"still", "shake"}
    for seg in ("still", "shake"):
        assert a.tracks.loc[a.tracks["segment"] == seg, "track_id"].nunique() == 9
