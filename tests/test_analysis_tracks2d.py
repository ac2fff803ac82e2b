"""Per-camera 2-D tracking on twin observations: continuity through dropped frames, duplicated frames left
out, fast oscillation kept in one track per marker, segments never crossed, bad input named."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

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
from rig.analysis.tracks2d import (
    NOT_TRACKED,
    _distances,
    _LiveTracks,
    _track_group,
    circle_prediction,
    tracks_2d,
)
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


def _scene(draw: Callable[[st.SearchStrategy[Any]], Any]) -> pd.DataFrame:
    """Observations of a random scene: 1–6 markers 14, 40 or 220 px apart (still, drifting, oscillating at
    3–23 Hz or turning at 10 Hz: a few px to ≈ 60 px a frame), 60 fps over 4–90 frames, with pixel noise,
    markers missed, spurious detections near them, dropped frames (time-stamp gaps) and duplicated frames (a
    stamp repeated)."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    n_frames, n_markers = draw(st.integers(4, 90)), draw(st.integers(1, 6))
    spacing_px = draw(st.sampled_from([14.0, 40.0, 220.0]))  # close markers: two candidates in a gate
    missed = draw(st.sampled_from([0.0, 0.02, 0.2]))  # the share of a marker's detections missed
    frequency_hz = rng.uniform(3.0, 23.0, n_markers)
    slots = np.cumsum(rng.choice([1, 1, 1, 1, 1, 1, 2, 3, 8], size=n_frames))  # drops between frames
    rows = []
    for f, slot in enumerate(slots):
        t = slot / 60.0
        for m in range(n_markers):
            if rng.random() < missed:
                continue
            base = np.array([150.0 + spacing_px * m, 300.0 + 15.0 * m])
            kind = m % 4
            if kind == 1:
                base += rng.uniform(-3, 3) * slot * np.array([1.0, 0.3])
            elif kind == 2:
                base += 30.0 * np.sin(2 * np.pi * frequency_hz[m] * t) * np.array([1.0, 0.5])
            elif kind == 3:
                base += 60.0 * np.array([np.cos(2 * np.pi * 10.0 * t), np.sin(2 * np.pi * 10.0 * t)])
            rows.append((f, t, *(base + rng.normal(0.0, 0.3, 2))))
        if rng.random() < 0.05 and rows:  # a spurious detection, near a marker
            rows.append((f, t, *(np.array(rows[-1][2:]) + rng.uniform(-30, 30, 2))))
        if rng.random() < 0.05 and rows:  # the camera repeats this frame: the same stamp and detections
            rows.extend([(f + 0.5, r[1], r[2], r[3]) for r in rows if r[0] == f])
    obs = pd.DataFrame(rows, columns=["frame_index", "timestamp_s", "u_px", "v_px"])
    obs["frame_index"] = pd.factorize(obs["frame_index"], sort=True)[0]
    return obs.sample(frac=1.0, random_state=int(rng.integers(2**31)))  # any row order


@settings(max_examples=150, deadline=None)
@given(st.data(), st.sampled_from([8.0, 25.0]), st.integers(0, 5), st.sampled_from([150.0, 8.0]))
def test_compiled_frames_give_the_labels_of_the_frame_by_frame_path(data, gate_px, max_gap, acquire_px):
    """The compiled usual frames (rig.analysis.tracks2d_kernel) change no label, bit for bit, whatever the
    scene, gate and gap allowance."""
    obs = _scene(data.draw)
    compiled = _track_group(obs, gate_px, max_gap, 2, acquire_px, compiled=True)
    frame_by_frame = _track_group(obs, gate_px, max_gap, 2, acquire_px, compiled=False)
    assert compiled[1] == frame_by_frame[1]
    np.testing.assert_array_equal(compiled[0], frame_by_frame[0])


def test_the_usual_frames_are_tracked_by_the_compiled_path(monkeypatch):
    """Three oscillating markers seen in every frame: after the first frame starts their tracks, no frame
    needs the frame-by-frame assignment (a kernel that declined every frame would still give the labels)."""
    tw = twin("sweep_column", setup=lambda w: w.exciter.set_frequency(0.0, 5.0), t_start_s=1.0,
              t_stop_s=2.0, sigma_px=0.2, marker_ids=["col0", "col1", "col2"])
    obs = tw.observations["left"]
    calls = []
    assign = _LiveTracks.assign

    def counted(self: _LiveTracks, *args: Any) -> np.ndarray:
        calls.append(args)
        return assign(self, *args)

    monkeypatch.setattr(_LiveTracks, "assign", counted)
    _one_track_per_marker(obs, tracks_2d(obs))
    assert obs["frame_index"].nunique() > 50 and len(calls) == 1


def _live_tracks(rng: np.random.Generator, n_tracks: int, spread_px: float) -> _LiveTracks:
    """``n_tracks`` live tracks started at random and moved on over 0–2 frames by about ``spread_px``."""
    live = _LiveTracks()
    live.advance(np.full(n_tracks, -1), rng.uniform(0, 1000, (n_tracks, 2)), 0.0)
    for s in (1.0, 2.0)[: int(rng.integers(0, 3))]:
        live.advance(np.arange(n_tracks), live.last + rng.normal(0, spread_px, (n_tracks, 2)), s)
    return live


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 5), st.integers(1, 6), st.integers(0, 2**32 - 1), st.floats(0.5, 40.0))
def test_the_compiled_simple_costs_are_those_of_the_frame_by_frame_path(n_tracks, n_det, seed, spread_px):
    """The kernel's distances from each track's last position and constant-velocity extrapolation are
    numpy's in :meth:`_LiveTracks.assign`, bit for bit."""
    from rig.analysis.tracks2d_kernel import simple_costs

    rng = np.random.default_rng(seed)
    live = _live_tracks(rng, n_tracks, spread_px)
    s_now = float(live.s_last.max() + rng.choice([1.0, 2.0, 3.5]) + rng.uniform(-0.01, 0.01))
    det = live.last.mean(axis=0) + rng.normal(0, 3 * spread_px, (n_det, 2))
    gap = s_now - live.s_last
    velocity = (live.last - live.prev) / np.maximum(live.s_last - live.s_prev, 1e-9)[:, None]
    expected = np.minimum(_distances(det, live.last), _distances(det, live.last + velocity * gap[:, None]))
    cost = np.empty((n_tracks, n_det))
    simple_costs(det, s_now, live.last, live.prev, live.s_last, live.s_prev, cost)
    np.testing.assert_array_equal(cost, expected)


@settings(max_examples=300, deadline=None)
@given(st.integers(1, 5), st.integers(0, 2**32 - 1), st.sampled_from([1.0, 8.0, 25.0]))
def test_the_compiled_frame_test_takes_exactly_the_frames_assign_pairs_off_by_their_simple_predictions(
        n_tracks, seed, gate_px):
    """On cost matrices at and around 0.2 × the gate and the gate (× the frames elapsed): the kernel takes a
    frame exactly when :meth:`_LiveTracks.assign` would try no other prediction, find each track and
    detection with at most one candidate, and leave no detection to start a track — with its pairs."""
    from rig.analysis.tracks2d_kernel import assign_one_to_one

    rng = np.random.default_rng(seed)
    gaps = rng.choice([1.0, 1.0, 0.999, 2.0, 3.0], n_tracks)
    reach = gate_px * np.maximum(gaps, 1.0)[:, None]
    levels = np.stack([np.full(n_tracks, 0.2 * gate_px), np.nextafter(0.2 * gate_px, np.inf) + 0 * gaps,
                       reach[:, 0], np.nextafter(reach[:, 0], np.inf), 0.1 * gate_px + 0 * gaps,
                       0.5 * reach[:, 0], 3.0 * reach[:, 0]], axis=1)
    pick = rng.integers(0, levels.shape[1], (n_tracks, n_tracks))
    cost = levels[np.arange(n_tracks)[:, None], pick]
    cost[np.arange(n_tracks), rng.permutation(n_tracks)] = rng.choice([0.0, 0.05, 0.2, 0.21]) * gate_px
    assigned = np.empty(n_tracks, np.int64)
    taken = assign_one_to_one(cost, gaps, gate_px, assigned)
    feasible = cost <= reach
    expected = (not (cost.min(axis=1) > 0.2 * gate_px).any() and feasible.sum(axis=0).max() <= 1
                and feasible.sum(axis=1).max() <= 1 and feasible.sum(axis=0).min() == 1)
    assert taken == expected
    if taken:
        rows, cols = np.nonzero(feasible)
        np.testing.assert_array_equal(assigned[cols], rows)


@settings(max_examples=100, deadline=None)
@given(st.integers(1, 5), st.integers(0, 2**32 - 1))
def test_the_compiled_advance_moves_the_tracks_on_as_the_frame_by_frame_path_does(n_tracks, seed):
    """After any number of frames (the history full or not), the kernel's step to the assigned detections
    leaves the live tracks' arrays and gives the labels of :meth:`_LiveTracks.advance`, to the bit."""
    from rig.analysis.tracks2d_kernel import advance

    rng = np.random.default_rng(seed)
    live = _LiveTracks()
    live.advance(np.full(n_tracks, -1), rng.uniform(0, 1000, (n_tracks, 2)), 0.0)
    for s in range(1, int(rng.integers(1, 14))):
        live.advance(rng.permutation(n_tracks), live.last + rng.normal(0, 5, (n_tracks, 2)), float(s))
    assigned = rng.permutation(n_tracks)
    det = rng.uniform(0, 1000, (n_tracks, 2))
    s_now = float(live.s_last.max() + 1.0)
    compiled = [a.copy() for a in live.arrays()]
    labels = np.full(n_tracks + 3, -7, np.int64)
    rows = rng.permutation(n_tracks + 3)[:n_tracks]
    ids, slots, px, known, last, prev, s_last, s_prev = compiled
    advance(det, rows, s_now, assigned, ids, slots, px, known, last, prev, s_last, s_prev, labels)
    expected = np.full(n_tracks + 3, -7, np.int64)
    expected[rows] = live.advance(assigned, det, s_now)
    np.testing.assert_array_equal(labels, expected)
    for kernel_array, frame_by_frame in zip(compiled, live.arrays(), strict=True):
        np.testing.assert_array_equal(kernel_array, frame_by_frame)
