"""Coarse offset between two videos' clocks from the cross-correlated marker velocities (no time stamps
shared): seconds apart, non-periodic motion, found to within a frame; periodic motion flagged ambiguous."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig.deploy.video_timing import (
    VideoTimingError,
    _joint_tracks,
    _Views,
    _views,
    coarse_offset,
    line_time_precision,
)
from rig.stereo.dlt import DLTCamera
from rig.stereo.timing import TimingResult

FPS = 60.0


def _obs(t_world: np.ndarray, x: np.ndarray, t0: float, noise: float, seed: int) -> pd.DataFrame:
    """One track seen by a camera whose clock reads t_world − t0 (time stamps from the file's start)."""
    rng = np.random.default_rng(seed)
    keep = t_world >= t0
    n = int(keep.sum())
    return pd.DataFrame({"frame_index": np.arange(n), "timestamp_s": t_world[keep] - t0,
                         "u_px": 500 + 0.3 * x[keep] + rng.normal(0, noise, n),
                         "v_px": 300 + x[keep] + rng.normal(0, noise, n), "track_id": 0})


@settings(max_examples=15, deadline=None)
@given(offset_s=st.floats(min_value=-12.0, max_value=12.0), seed=st.integers(0, 1000))
def test_offset_of_a_non_periodic_motion_within_a_frame(offset_s: float, seed: int) -> None:
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 40.0, 1 / FPS)
    # a smooth random motion (low-pass filtered noise), like a structure under ambient excitation
    x = np.convolve(rng.normal(0, 1, t.size), np.hanning(31), mode="same")
    start_a, start_b = 13.0, 13.0 + offset_s  # camera B started offset_s later (world seconds)
    a, b = _obs(t, x, start_a, 0.05, seed), _obs(t, x, start_b, 0.05, seed + 1)
    pairs = pd.DataFrame({"track_a": [0], "track_b": [0]})
    got = coarse_offset(a, b, pairs, 1 / FPS)
    # t_a = t_b + offset  ⇔  world − start_a = world − start_b + offset
    assert abs(got["offset_s"] - (start_b - start_a)) <= 1 / FPS
    assert not got["ambiguous"]


def test_steady_sine_is_flagged_ambiguous() -> None:
    t = np.arange(0.0, 10.0, 1 / FPS)
    x = 3.0 * np.sin(2 * np.pi * 4.0 * t)
    a, b = _obs(t, x, 1.0, 0.02, 1), _obs(t, x, 1.3, 0.02, 2)
    got = coarse_offset(a, b, pd.DataFrame({"track_a": [0], "track_b": [0]}), 1 / FPS)
    assert got["ambiguous"]  # whole periods (0.25 s) apart correlate as well


def test_no_motion_is_a_clear_error() -> None:
    t = np.arange(0.0, 5.0, 1 / FPS)
    a = _obs(t, np.zeros_like(t), 0.0, 0.0, 1)
    with pytest.raises(VideoTimingError, match="no paired marker moves"):
        coarse_offset(a, a, pd.DataFrame({"track_a": [0], "track_b": [0]}), 1 / FPS)


def test_an_observable_line_time_is_stated_with_what_it_rests_on() -> None:
    """The statement's numbers: the row difference v_B − v_A (two markers 2 px apart in it, each moving
    ±0.5 px more in B than in A), the line time's share of the offset's u (u_offset·|ρ|), and what 1 µs
    needs (u / 1 µs times the variation, its square times the record)."""
    t = np.arange(0.0, 2.0, 1 / FPS)
    offset_s = 0.0123
    tracks_a, tracks_b = [], []
    for mean_px in (4.0, 6.0):
        rows_a = 300 + 2.0 * np.sin(2 * np.pi * 5 * t)
        rows_b = rows_a + mean_px + 0.5 * np.sin(2 * np.pi * 5 * t)
        tracks_a.append((t, np.zeros((t.size, 2)), rows_a))
        tracks_b.append((t - offset_s, np.zeros((t.size, 2)), rows_b))  # B's clock: A's − offset
    u_offset_s, rho = 40e-6, -0.8
    result = TimingResult("a", {"a": 0.0, "b": offset_s}, {"a": 20e-6, "b": 20e-6}, {"a": 0.0, "b": 0.0},
                          "joint", uncertainty={"offset_s": {"a": 0.0, "b": u_offset_s},
                                                "line_time_s": {"a": 3e-6, "b": 3e-6},
                                                "drift_ppm": {"a": 0.0, "b": 1.0}},
                          details={"parameters": ["offset", "line_time", "drift"],
                                   "correlation": [[1.0, rho, 0.0], [rho, 1.0, 0.0], [0.0, 0.0, 1.0]]})
    got = line_time_precision(result, tracks_a, tracks_b, "b", [(0.0, 2.0)])
    inner = slice(2, -2)  # np.interp holds the ends of B's shifted times
    assert got["row_difference_per_marker_px"] == pytest.approx([4.0, 6.0], abs=0.02)
    assert got["row_difference_mean_px"] == pytest.approx(5.0, abs=0.02)
    expected_std = np.std(np.concatenate([m + 0.5 * np.sin(2 * np.pi * 5 * t[inner]) for m in (4.0, 6.0)]))
    assert got["row_difference_std_px"] == pytest.approx(expected_std, rel=0.02)
    assert got["offset_uncertainty_from_line_time_s"] == pytest.approx(u_offset_s * 0.8)
    assert "20.00 ± 3.00 µs" in got["statement"] and "≈ 3.0× that variation" in got["statement"]
    assert "≈ 9× the 2.0 s used" in got["statement"] and "0.0320 ms from the line time" in got["statement"]


def _joint_tracks_per_call(views: _Views, offset_s: float) -> tuple[list, list, list]:
    """The joint estimate's tracks as selected before the series were kept: each track filtered, sorted and
    deduplicated from the DataFrame on every call (the reference for :func:`_joint_tracks`)."""
    t_b = views.tracked[views.other]["timestamp_s"].to_numpy(float)
    t0, t1 = float(t_b.min()) + offset_s, float(t_b.max()) + offset_s
    windows = [(t0, t1)] if t1 - t0 <= 2 * views.window_s else [(t0, t0 + views.window_s),
                                                                 (t1 - views.window_s, t1)]
    tracks_a: list = []
    tracks_b: list = []
    for a, b in zip(views.use["track_a"], views.use["track_b"], strict=True):
        for lo, hi in windows:
            for name, tid, dest, shift in ((views.reference, a, tracks_a, 0.0), (views.other, b, tracks_b,
                                                                                   offset_s)):
                tr = views.tracked[name]
                tr = tr[tr["track_id"] == tid].sort_values("timestamp_s").drop_duplicates("timestamp_s")
                t = tr["timestamp_s"].to_numpy(float)
                sel = (t + shift >= lo) & (t + shift <= hi)
                uv = tr[["u_px", "v_px"]].to_numpy(float)[sel]
                dest.append((t[sel], views.cameras[name].undistort_px(uv), uv[:, 1]))
    keep = [i for i, (ta, tb) in enumerate(zip(tracks_a, tracks_b, strict=True))
            if len(ta[0]) >= 30 and len(tb[0]) >= 30]
    return [tracks_a[i] for i in keep], [tracks_b[i] for i in keep], windows


@pytest.mark.parametrize("window_s", [3.0, 20.0])
def test_joint_tracks_from_the_kept_series_equal_the_per_call_selection(window_s: float) -> None:
    # two markers per camera, frames shuffled and some stamped twice, a record long enough for two windows
    # (window 3 s) or taken whole (20 s); three candidate offsets
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 12.0, 1 / FPS)
    frames = []
    for tid, start in ((0, 1.0), (4, 1.3)):
        obs = _obs(t, 5 * np.sin(2 * np.pi * 1.3 * t + tid), start, 0.1, tid).assign(track_id=tid)
        frames.append(pd.concat([obs, obs.sample(15, random_state=tid)]))
    both = pd.concat(frames).sample(frac=1.0, random_state=1).reset_index(drop=True)
    P = np.hstack([np.eye(3), np.zeros((3, 1))])
    cameras = {"left": DLTCamera(P=P), "right": DLTCamera(P=P)}
    use = pd.DataFrame({"track_a": [0, 4], "track_b": [4, 0]})
    tracked = {"left": both, "right": both.assign(timestamp_s=both["timestamp_s"] + rng.normal(0, 1e-4))}
    views = _views(tracked, use, cameras, reference="left", other="right", window_s=window_s)
    for offset_s in (-0.3, 0.0, 0.45):
        got, want = _joint_tracks(views, offset_s), _joint_tracks_per_call(views, offset_s)
        assert got[2] == want[2]
        for mine, theirs in zip(got[0] + got[1], want[0] + want[1], strict=True):
            for x, y in zip(mine, theirs, strict=True):
                assert np.array_equal(x, y)
        assert len(got[0]) == len(want[0]) >= 2
