"""Per-camera 2-D tracking on twin observations: continuity through dropped frames, duplicated frames left
out, fast oscillation kept in one track per marker, segments never crossed, bad input named."""

from __future__ import annotations

import measure_twin as mt
import numpy as np
import pandas as pd
import pytest
from analysis_twin import twin
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.sim.clock import VirtualClock
from drivers.sim.world import World, WorldLayout
from rig.analysis.errors import AnalysisError
from rig.analysis.tracks2d import NOT_TRACKED, circle_prediction, tracks_2d
from rig.deploy.video_markers import extract_video


def _one_track_per_marker(obs: pd.DataFrame, ids: pd.Series) -> None:
    """Every marker's observations carry one track id, and no two markers share one."""
    pairs = pd.DataFrame({"marker": obs["marker_id"].to_numpy(), "track": ids.to_numpy()})
    per_marker = pairs.groupby("marker")["track"].nunique()
    per_track = pairs.groupby("track")["marker"].nunique()
    assert (per_marker == 1).all(), per_marker
    assert (per_track == 1).all(), per_track
    assert (ids >= 0).all()


@pytest.mark.parametrize("f_hz", [5.0, 20.0])
def test_oscillating_column_is_one_track_per_marker(f_hz):
    tw = twin("sweep_column", setup=lambda w: w.exciter.set_frequency(0.0, f_hz), t_start_s=1.0,
              t_stop_s=3.0, sigma_px=0.2)
    for obs in tw.observations.values():
        _one_track_per_marker(obs, tracks_2d(obs))


def test_tracks_continue_through_dropped_frames():
    dropped = (75, 76, 130)  # sensor frames never delivered: gaps in the time stamps
    tw = twin("rotor", setup=lambda w: w.rotor.set_frequency(0.0, 2.0), t_start_s=1.0, t_stop_s=3.0,
              sigma_px=0.2, left_overrides={"dropped_frames": dropped})
    obs = tw.observations["left"]
    stamps = np.unique(obs["timestamp_s"])
    assert np.max(np.diff(stamps)) > 2.5 / 60  # the gap is really there
    _one_track_per_marker(obs, tracks_2d(obs))


def test_a_gap_longer_than_allowed_splits_the_track():
    tw = twin("rotor", setup=lambda w: w.rotor.set_frequency(0.0, 0.5), t_start_s=1.0, t_stop_s=3.0,
              sigma_px=0.2, marker_ids=["rotor"], left_overrides={"dropped_frames": tuple(range(80, 90))})
    obs = tw.observations["left"]
    assert tracks_2d(obs, max_gap_frames=5).nunique() == 2
    assert tracks_2d(obs, max_gap_frames=12).nunique() == 1


def test_duplicated_frames_are_left_out():
    tw = twin("rotor", setup=lambda w: w.rotor.set_frequency(0.0, 2.0), t_start_s=1.0, t_stop_s=2.0,
              sigma_px=0.2, marker_ids=["rotor"], left_overrides={"duplicated_frames": (70, 71, 90)})
    obs = tw.observations["left"]
    ids = tracks_2d(obs)
    repeated = obs["timestamp_s"].duplicated(keep="first").to_numpy()
    assert repeated.sum() == 3
    assert (ids[repeated] == NOT_TRACKED).all()
    assert ids[~repeated].nunique() == 1 and (ids[~repeated] >= 0).all()


def test_segments_are_never_crossed():
    tw = twin("sweep_column", t_start_s=1.0, t_stop_s=2.0, sigma_px=0.1, marker_ids=["col0", "col1"])
    obs = tw.observations["left"].copy()
    obs["segment"] = np.where(obs["frame_index"] < obs["frame_index"].median(), "one", "two")
    ids = tracks_2d(obs)
    assert ids.nunique() == 4
    assert (pd.DataFrame({"s": obs["segment"], "t": ids}).groupby("t")["s"].nunique() == 1).all()


def test_short_tracks_are_not_tracked():
    obs = pd.DataFrame({"frame_index": [0, 1, 2, 3, 1], "timestamp_s": [0, 1 / 60, 2 / 60, 3 / 60, 1 / 60],
                        "u_px": [100.0, 101, 102, 103, 900], "v_px": [100.0, 100, 100, 100, 500]})
    ids = tracks_2d(obs, min_length=3)
    assert ids.tolist() == [0, 0, 0, 0, NOT_TRACKED]


@pytest.mark.parametrize(("kwargs", "word"), [({"gate_px": 0.0}, "gate_px"), ({"gate_px": np.nan}, "gate_px"),
                                              ({"max_gap_frames": -1}, "max_gap_frames"),
                                              ({"min_length": 0}, "min_length")])
def test_bad_options_are_named(kwargs, word):
    obs = pd.DataFrame({"frame_index": [0], "timestamp_s": [0.0], "u_px": [1.0], "v_px": [1.0]})
    with pytest.raises(AnalysisError, match=word):
        tracks_2d(obs, **kwargs)


def test_missing_and_non_finite_columns_are_named():
    with pytest.raises(AnalysisError, match="v_px"):
        tracks_2d(pd.DataFrame({"frame_index": [0], "timestamp_s": [0.0], "u_px": [1.0]}))
    with pytest.raises(AnalysisError, match="u_px"):
        tracks_2d(pd.DataFrame({"frame_index": [0], "timestamp_s": [0.0], "u_px": [np.nan], "v_px": [1.0]}))


@settings(max_examples=25, deadline=None)
@given(st.permutations(list(range(12))))
def test_row_order_does_not_change_the_partition(perm):
    """Three well separated markers over four frames: the same tracks whatever the row order."""
    rows = [(f, f / 60, 100.0 + 300 * m + 2 * f, 200.0 + 50 * m, m) for f in range(4) for m in range(3)]
    obs = pd.DataFrame(rows, columns=["frame_index", "timestamp_s", "u_px", "v_px", "marker"])
    shuffled = obs.iloc[list(perm)]
    ids = tracks_2d(shuffled)
    pairs = pd.DataFrame({"m": shuffled["marker"].to_numpy(), "t": ids.to_numpy()})
    assert pairs.groupby("m")["t"].nunique().eq(1).all() and pairs["t"].nunique() == 3


@pytest.mark.parametrize("f_hz", [5.0, 10.0])
def test_fast_rotor_is_one_track(f_hz):
    """At 10 Hz the rotor marker moves 60° (≈ 100 px) per frame: no polynomial prediction is within the gate;
    the lone-marker acquisition starts the track and the periodic prediction keeps it."""
    tw = twin("rotor", setup=lambda w: w.rotor.set_frequency(0.0, f_hz), t_start_s=1.0, t_stop_s=2.5,
              sigma_px=0.2)
    for obs in tw.observations.values():
        rotor = obs[obs["marker_id"] == "rotor"][["u_px", "v_px"]].to_numpy()
        assert np.median(np.linalg.norm(np.diff(rotor, axis=0), axis=1)) > (60 if f_hz >= 10 else 30)
        _one_track_per_marker(obs, tracks_2d(obs))


def test_rotor_turning_from_the_first_frame_is_one_track_in_each_video(tmp_path):
    """A rotor already turning at 10 Hz when the recording starts, filmed by the half-size twin cameras with
    the still reference markers within the acquisition distance: the lone-marker acquisition must skip the
    detections that still tracks took, then the circle and periodic predictions keep the track."""
    world = World(VirtualClock(), seed=5, layout=WorldLayout(initial_scene="rotor"))
    world.rotor.set_frequency(-5.0, 10.0)
    left, right = mt.camera_pair(world)
    paths = mt.write_pair(left, right, tmp_path, t_left_s=(0.0, 1.0), t_right_s=(0.15, 1.15))
    for path in paths:
        obs = extract_video(path).observations
        ids = tracks_2d(obs[~obs["duplicate"]])
        per_frame = obs.groupby("frame_index").size()
        assert (per_frame == 5).all()  # the rotor and the 4 references in every frame
        assert ids.nunique() == 5 and (ids >= 0).all(), ids.value_counts().to_dict()
        counts = ids.value_counts()
        assert (counts == len(per_frame)).all(), counts.to_dict()  # each track spans the whole record
        steps = [np.median(np.linalg.norm(np.diff(g[["u_px", "v_px"]].to_numpy(), axis=0), axis=1))
                 for _, g in obs.groupby(ids.to_numpy())]
        assert max(steps) > 30  # the rotor's marker: tens of px per frame at half size


@settings(max_examples=60, deadline=None)
@given(st.tuples(st.floats(-500, 500), st.floats(-500, 500)), st.floats(5, 400), st.floats(-np.pi, np.pi),
       st.one_of(st.floats(0.05, 2.5), st.floats(-2.5, -0.05)), st.integers(1, 3))
def test_circle_prediction_continues_a_uniform_rotation(centre, radius, phase, step, ahead):
    """Three points of a uniform rotation (any centre, radius, step below 143°) predict the point ``ahead``
    frames on exactly (to rounding)."""
    angles = phase + step * np.arange(3 + ahead)
    pts = np.c_[centre[0] + radius * np.cos(angles), centre[1] + radius * np.sin(angles)]
    got = circle_prediction([0.0, 1.0, 2.0], list(pts[:3]), 2.0 + ahead)
    assert got is not None
    assert np.allclose(got, pts[2 + ahead], atol=1e-6 * max(radius, 1.0))


def test_circle_prediction_declines_collinear_or_irregular_points():
    assert circle_prediction([0.0, 1.0, 2.0], [np.array([0.0, 0.0]), np.array([1.0, 1.0]),
                                              np.array([2.0, 2.0])], 3.0) is None
    a = np.deg2rad([0.0, 30.0, 90.0])  # steps of 30° then 60°: not a uniform rotation
    pts = [np.array([np.cos(x), np.sin(x)]) * 50 for x in a]
    assert circle_prediction([0.0, 1.0, 2.0], pts, 3.0) is None
