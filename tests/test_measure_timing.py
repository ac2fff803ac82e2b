"""Coarse offset between two videos' clocks from the cross-correlated marker velocities (no time stamps
shared): seconds apart, non-periodic motion, found to within a frame; periodic motion flagged ambiguous."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig.deploy.video_timing import VideoTimingError, coarse_offset

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
