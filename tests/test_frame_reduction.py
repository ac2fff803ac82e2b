"""rig.analysis.frame_reduction: the one frame → marker-rows reduction of recordings and video files."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig.analysis.frame_reduction import (
    DETECT_ONLY_KEYS,
    MarkerReducer,
    ReduceOptions,
    _follow,
    track_options,
)
from rig.analysis.tracks2d import circle_prediction
from rig.deploy import video_markers
from rig.run import acquire
from rig.stereo import FLAG_LOST, MARKER_DTYPE


def _frame(centres: list[tuple[float, float]], seed: int = 0) -> np.ndarray:
    img = np.full((240, 320), 30, np.uint8)
    for u, v in centres:
        cv2.circle(img, (round(u * 16), round(v * 16)), 8 * 16, 220, -1, lineType=cv2.LINE_AA, shift=4)
    noise = np.random.default_rng(seed).normal(0, 2, img.shape)
    return np.clip(cv2.GaussianBlur(img, (0, 0), 0.8) + noise, 0, 255).astype(np.uint8)


def test_procedures_and_video_files_share_one_reducer() -> None:
    assert acquire.ReduceOptions is ReduceOptions  # one options class (rig.analysis.reduce_options)
    assert not hasattr(video_markers, "_track_options")
    assert video_markers.ExtractOptions(window_px=31).reduce_options() == ReduceOptions(
        window_px=31, redetect_every=60)


def test_detect_only_options_are_not_passed_to_the_tracker() -> None:
    # threshold, roi, downsample and require are options of the whole-frame search only: track_markers
    # would raise TypeError on them at the second frame
    detect = {"threshold": "otsu", "roi": (0, 0, 320, 240), "downsample": 1, "require": True,
              "min_contrast": 30.0, "polarity": "bright"}
    assert track_options(detect) == {"min_contrast": 30.0, "polarity": "bright"}
    assert set(DETECT_ONLY_KEYS) <= set(detect)
    reducer = MarkerReducer(ReduceOptions(mode="track", window_px=31, detect=detect))
    _, ids0 = reducer.reduce(_frame([(60.0, 60.0), (150.0, 120.0)]))
    found, ids1 = reducer.reduce(_frame([(61.0, 60.5), (152.0, 121.0)], seed=1))  # tracked
    assert list(ids1) == list(ids0)
    k = int(np.argmax(found["u_px"]))
    # 2 DN noise on a 190 DN edge: centroid error ≪ 0.3 px
    assert abs(found["u_px"][k] - 152.0) < 0.3 and abs(found["v_px"][k] - 121.0) < 0.3


def test_unknown_detect_option_is_refused_by_name() -> None:
    with pytest.raises(ValueError, match=r"\['thresh'\].*allowed: polarity"):
        ReduceOptions(detect={"thresh": 3})
    with pytest.raises(ValueError, match="thresh"):
        video_markers.ExtractOptions(detect={"thresh": 3})
    with pytest.raises(ValueError, match="redetect_every=0"):
        ReduceOptions(redetect_every=0)


def test_a_rotor_is_followed_in_its_window_not_searched_whole_every_frame() -> None:
    """A marker on a 10 Hz circle (60° ≈ 70 px per frame) beside a still one: after three frames the circle
    through its last positions puts the window on it, so whole-frame searches stop and its number stays
    (before that, a jump beyond half a window is a new number, as for any marker)."""
    centre, radius = np.array([160.0, 120.0]), 70.0
    frames = []
    for k in range(30):
        a = np.deg2rad(60.0 * k + 10.0)
        on_circle = tuple(centre + radius * np.array([np.cos(a), np.sin(a)]))
        frames.append(_frame([on_circle, (20.0, 20.0)], seed=k))
    reducer = MarkerReducer(ReduceOptions(window_px=41, redetect_every=1000))
    ids = [reducer.reduce(img)[1] for img in frames]
    assert all(len(i) == 2 for i in ids)
    assert len({tuple(sorted(i.tolist())) for i in ids[3:]}) == 1  # the same two numbers from frame 3
    assert reducer.whole_frame_searches <= 3  # the first frame and the two before the circle is known


def _predicted_reference(hist: np.ndarray, depth: np.ndarray, window_px: int, shape: tuple[int, int],
                         ) -> np.ndarray:
    """The prediction written out in numpy, marker by marker (what the compiled bookkeeping replaces)."""
    out = hist[:, 2].copy()
    step = hist[:, 2] - hist[:, 1]
    moved = np.sqrt(step[:, 0] * step[:, 0] + step[:, 1] * step[:, 1])
    for j in np.flatnonzero((depth >= 2) & ~(moved <= window_px / 4)).tolist():
        p = circle_prediction([0.0, 1.0, 2.0], list(hist[j]), 3.0) if depth[j] == 3 else None
        out[j] = p if p is not None else 2 * hist[j, 2] - hist[j, 1]
    return np.clip(out, 0, (shape[1] - 1, shape[0] - 1))


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_the_compiled_prediction_and_history_are_the_numpy_ones(seed: int) -> None:
    """Still, slow, fast (a circle or a straight line), lost (NaN) and off-frame markers, with one to three
    positions known: the predicted positions bit for bit, and a followed frame's history moved on by one."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(0, 7))
    hist = rng.uniform(-20, 340, (n, 3, 2)) * (rng.random((n, 1, 1)) < 0.7)  # some on the corner 0
    slow = rng.random(n) < 0.5
    hist[slow, :2] = hist[slow, 2:] + rng.normal(0, 2, (int(slow.sum()), 1, 2))
    edge = rng.random((n, 3, 2)) < 0.2  # on and just beyond the frame's edges, and lost (NaN)
    hist[edge] = rng.choice([-0.5, -0.0, 0.0, 0.25, 239.0, 239.5, 319.0, 319.5, 1e9, np.nan], int(edge.sum()))
    depth = rng.integers(1, 4, n)
    reducer = MarkerReducer(ReduceOptions(window_px=31))
    reducer._hist, reducer._depth, reducer._ids = hist.copy(), depth.copy(), np.arange(n)
    expected = _predicted_reference(hist, depth, 31, (240, 320))
    np.testing.assert_array_equal(reducer._predicted((240, 320)), expected)
    tracked = np.zeros(n, MARKER_DTYPE)
    tracked["u_px"], tracked["v_px"] = rng.uniform(0, 320, n), rng.uniform(0, 240, n)
    lost = n > 0 and rng.random() < 0.3
    if lost:
        tracked["flags"][int(rng.integers(0, n))] = FLAG_LOST
    assert _follow(reducer._hist, reducer._depth, tracked, FLAG_LOST) is not lost
    moved_on = np.concatenate([hist[:, 1:], np.c_[tracked["u_px"], tracked["v_px"]][:, None]], axis=1)
    np.testing.assert_array_equal(reducer._hist, hist if lost else moved_on)
    np.testing.assert_array_equal(reducer._depth, depth if lost else np.minimum(depth + 1, 3))
