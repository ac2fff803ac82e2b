"""rig.analysis.frame_reduction: the one frame → marker-rows reduction of recordings and video files."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rig.analysis.frame_reduction import DETECT_ONLY_KEYS, MarkerReducer, ReduceOptions, track_options
from rig.deploy import video_markers
from rig.run import acquire


def _frame(centres: list[tuple[float, float]], seed: int = 0) -> np.ndarray:
    img = np.full((240, 320), 30, np.uint8)
    for u, v in centres:
        cv2.circle(img, (round(u * 16), round(v * 16)), 8 * 16, 220, -1, lineType=cv2.LINE_AA, shift=4)
    noise = np.random.default_rng(seed).normal(0, 2, img.shape)
    return np.clip(cv2.GaussianBlur(img, (0, 0), 0.8) + noise, 0, 255).astype(np.uint8)


def test_procedures_and_video_files_share_one_reducer() -> None:
    assert acquire.MarkerReducer is MarkerReducer and acquire.ReduceOptions is ReduceOptions
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
