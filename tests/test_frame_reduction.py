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


def test_reduce_many_equals_reduce_frame_by_frame() -> None:
    # still markers (tracked in runs), one vanishing (lost → whole-frame search), one reappearing, one
    # that starts moving fast in a run and a fast new one (≥ a quarter window per frame: reduce's motion
    # prediction, frame by frame)
    rng = np.random.default_rng(5)
    frames = []
    for f in range(40):
        centres = [(60.0 + 0.05 * np.sin(f), 60.0 + 9.0 * max(f - 26, 0)),
                   (250.0, 180.0 + 0.2 * np.cos(f / 3))]
        if not 12 <= f < 15:
            centres.append((150.0 + rng.uniform(-0.3, 0.3), 120.0))
        if f >= 25:
            centres.append((40.0 + 9.0 * (f - 25), 200.0))
        frames.append(_frame(centres, seed=f))
    options = ReduceOptions(mode="track", window_px=31, redetect_every=10)
    one, many = MarkerReducer(options), MarkerReducer(options)
    want = [one.reduce(frame) for frame in frames]
    got = many.reduce_many(frames[:7]) + many.reduce_many(frames[7:])
    assert len(got) == len(want)
    for (rows_got, ids_got), (rows_want, ids_want) in zip(got, want, strict=True):
        np.testing.assert_array_equal(ids_got, ids_want)
        np.testing.assert_array_equal(rows_got["flags"], rows_want["flags"])
        np.testing.assert_allclose(rows_got["u_px"], rows_want["u_px"], rtol=0, atol=2e-5)
        np.testing.assert_allclose(rows_got["v_px"], rows_want["v_px"], rtol=0, atol=2e-5)
    assert many.whole_frame_searches == one.whole_frame_searches and many.next_id == one.next_id
