"""Tracking many frames in one call: the rows equal those of track_markers called frame by frame."""

from __future__ import annotations

import numpy as np
import pytest
from marker_images import Disc, render

from rig.stereo import (
    FLAG_LOST,
    InputArrayError,
    track_markers,
    track_markers_batch,
    track_markers_sequence,
)

SHAPE = (240, 320)
OPTS = {"window_px": 33, "min_area_px": 40.0, "min_contrast": 40.0}
# the windows of one call are measured together in float32 matrix products whose summation order
# depends on how many rows a product has: the rows agree to float32 rounding, not bit for bit. A moment
# sum of ~10³ terms with coordinates up to the window's half side (16 px) rounded at 2⁻²³ relative moves
# the centroid by ≲ 16 px · 10³ · 2⁻²³ / √10³ ≈ 6e-5 px at worst, ~1e-6 px typically; 2000× below the
# centroid noise (≈ 0.007 px here)
ATOL_PX = 2e-5


def scene(n_frames: int, step_px: float | np.ndarray, seed: int = 3, *, vanish_at: int | None = None,
          edge: bool = False):
    """Frames of 6 markers moving ``step_px`` per frame (scalar or one per marker; one vanishes from frame
    ``vanish_at`` on), and the true centres (F, 6, 2); ``edge``: one marker sits 3 px from the left edge
    (windows cross it)."""
    rng = np.random.default_rng(seed)
    base = np.array([[60.0, 60.0], [160.0, 60.0], [260.0, 60.0], [60.0, 170.0], [160.0, 170.0],
                     [260.0, 170.0]]) + rng.uniform(-0.5, 0.5, (6, 2))
    if edge:
        base[0, 0] = 3.2
    direction = rng.uniform(-1, 1, (6, 2)) * np.reshape(step_px, (-1, 1))
    frames, truth = [], []
    for f in range(n_frames):
        uv = base + f * direction
        discs = [Disc(u, v, rng.uniform(7.5, 8.5) if f == 0 else 8.0) for u, v in uv]
        if vanish_at is not None and f >= vanish_at:
            discs = discs[1:]
        frames.append(render(SHAPE, discs, background_dn=20.0, blur_sigma_px=0.8, noise_sigma_dn=2.0,
                             seed=seed * 100 + f))
        truth.append(uv)
    return frames, np.array(truth)


def sequential(frames, start, **opts):
    """track_markers frame by frame, each fed the previous result; stops after the first loss."""
    rows, prev = [], start
    for frame in frames:
        rec = track_markers(frame, prev, **opts)
        rows.append(rec)
        if (rec["flags"] & FLAG_LOST).any():
            break
        prev = np.c_[rec["u_px"], rec["v_px"]]
    return np.array(rows)


def held(frames, start, hold_px, **opts):
    """track_markers frame by frame in windows that move only when a marker leaves hold_px of the centre."""
    rows, centre = [], np.rint(start)
    for frame in frames:
        rec = track_markers(frame, centre, **opts)
        rows.append(rec)
        if (rec["flags"] & FLAG_LOST).any():
            break
        uv = np.c_[rec["u_px"], rec["v_px"]]
        moved = (np.abs(uv - centre) > hold_px).any(axis=1)
        centre[moved] = np.rint(uv[moved])
    return np.array(rows)


def assert_rows_equal(got: np.ndarray, want: np.ndarray) -> None:
    assert got.shape == want.shape
    np.testing.assert_array_equal(got["flags"], want["flags"])
    for field in ("u_px", "v_px"):
        np.testing.assert_allclose(got[field], want[field], rtol=0, atol=ATOL_PX, equal_nan=True)
    for field in ("area_px", "roundness", "contrast"):
        np.testing.assert_allclose(got[field], want[field], rtol=1e-5, equal_nan=True)


@pytest.mark.parametrize("step_px", [0.05, 0.3, 1.5, np.array([0.02, 0.02, 1.5, 0.02, 0.6, 0.02])])
def test_sequence_equals_frame_by_frame_tracking(step_px):
    # slow motion keeps whole chunks; fast motion (a new window every frame) forces chunks of one frame,
    # for each marker on its own
    frames, truth = scene(20, step_px)
    start = truth[0] + 0.7
    got = track_markers_sequence(frames, start, **OPTS)
    want = sequential(frames, start, **OPTS)
    assert len(got) == len(frames)
    assert_rows_equal(got, want)
    assert np.abs(got["u_px"] - truth[..., 0]).max() < 0.1


@pytest.mark.parametrize("step_px", [0.1, 1.5, np.array([0.02, 0.02, 1.5, 0.02, 0.6, 0.02])])
def test_sequence_holding_windows_equals_tracking_in_held_windows(step_px):
    frames, truth = scene(20, step_px)
    start = truth[0] + 0.3
    got = track_markers_sequence(frames, start, hold_px=1.0, **OPTS)
    assert_rows_equal(got, held(frames, start, 1.0, **OPTS))
    # the same measurement as re-centring every frame, up to the background plane's placement
    exact = sequential(frames, start, **OPTS)
    assert np.abs(got["u_px"] - exact["u_px"]).max() < 0.02
    lost_at_7 = track_markers_sequence(scene(12, 0.1, vanish_at=7)[0], truth[0], hold_px=1.0, **OPTS)
    assert len(lost_at_7) == 8 and lost_at_7[-1]["flags"][0] & FLAG_LOST


def test_sequence_stops_after_the_first_loss():
    frames, truth = scene(12, 0.1, vanish_at=7)
    got = track_markers_sequence(frames, truth[0], **OPTS)
    want = sequential(frames, truth[0], **OPTS)
    assert len(got) == 8  # frames 0..7, frame 7 holding the lost marker
    assert got[-1]["flags"][0] & FLAG_LOST and not (got[:-1]["flags"] & FLAG_LOST).any()
    assert_rows_equal(got, want)


def test_sequence_with_windows_crossing_the_frame_edge_and_the_ellipse_centre():
    frames, truth = scene(10, 0.2, edge=True)
    opts = {**OPTS, "centre": "ellipse"}
    got = track_markers_sequence(frames, truth[0], **opts)
    assert_rows_equal(got, sequential(frames, truth[0], **opts))


def test_batch_equals_separate_calls_with_lost_and_unusable_predictions():
    frames, truth = scene(5, 2.0)
    pred = truth + np.random.default_rng(1).normal(0, 0.5, truth.shape)
    pred[1, 2] = np.nan  # unusable: NaN
    pred[3, 4] = (-5.0, 10.0)  # unusable: outside the frame
    pred[2, 1] = (110.0, 115.0)  # nothing there: lost
    got = track_markers_batch(np.stack(frames), pred, **OPTS)
    want = np.array([track_markers(f, p, **OPTS) for f, p in zip(frames, pred, strict=True)])
    assert_rows_equal(got, want)
    assert all(got[f, k]["flags"] & FLAG_LOST for f, k in ((1, 2), (3, 4), (2, 1)))
    same = track_markers_batch(frames, truth[0], **OPTS)  # (K, 2): the same predictions in every frame
    assert_rows_equal(same, np.array([track_markers(f, truth[0], **OPTS) for f in frames]))


def test_empty_inputs():
    frames, truth = scene(3, 0.1)
    assert track_markers_sequence([], truth[0], **OPTS).shape == (0, 6)
    assert track_markers_sequence(frames, np.empty((0, 2)), **OPTS).shape == (3, 0)
    assert track_markers_batch(frames, np.empty((3, 0, 2)), **OPTS).shape == (3, 0)


@pytest.mark.parametrize("call, message", [
    (lambda f, t: track_markers_batch(f, t[:2], **OPTS), "predicted_uv_px has shape"),
    (lambda f, t: track_markers_sequence(f, t, **OPTS), "start_uv_px has shape"),
    (lambda f, t: track_markers_sequence([f[0], f[1][:100]], t[0], **OPTS), "different shapes"),
    (lambda f, t: track_markers_sequence([f[0].astype(float)], t[0], **OPTS), r"frames\[0\] has dtype"),
    (lambda f, t: track_markers_sequence(f, t[0], window_px=5), "window_px=5"),
    (lambda f, t: track_markers_sequence(f, t[0], window_px=11, hold_px=3.0), "hold_px=3.0"),
])
def test_bad_input_is_named(call, message):
    frames, truth = scene(3, 0.1)
    with pytest.raises(InputArrayError, match=message):
        call(frames, truth)
