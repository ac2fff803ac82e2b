"""rig.deploy.plate_grid: the calibration plate's markers told from fixed references and ordered on their
grid."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig.deploy.plate_grid import GridError, moving_points, order_grid


def _project(rows: int, cols: int, *, yaw_deg: float, pitch_deg: float, roll_deg: float, depth_mm: float,
             pitch_mm: float = 40.0) -> np.ndarray:
    """A plate facing a pinhole camera (row 0 on top, column 0 on the left), turned by the angles."""
    nodes = np.array([((c - (cols - 1) / 2) * pitch_mm, (r - (rows - 1) / 2) * pitch_mm, 0.0)
                      for r in range(rows) for c in range(cols)])
    rx, ry, rz = np.radians([pitch_deg, yaw_deg, roll_deg])
    rot = [cv2.Rodrigues(np.array(v))[0] for v in ([rx, 0.0, 0.0], [0.0, ry, 0.0], [0.0, 0.0, rz])]
    rvec = cv2.Rodrigues(rot[0] @ rot[1] @ rot[2])[0]
    K = np.array([[2400.0, 0, 960], [0, 2400.0, 540], [0, 0, 1]])
    uv, _ = cv2.projectPoints(nodes, rvec, np.array([0.0, 0.0, depth_mm]), K, None)
    return uv.reshape(-1, 2)


@settings(max_examples=40, deadline=None)
@given(yaw=st.floats(-35, 35), pitch=st.floats(-35, 35), roll=st.floats(-20, 20),
       depth=st.floats(900, 2500), seed=st.integers(0, 2**31 - 1))
def test_order_grid_recovers_every_node_under_perspective(yaw, pitch, roll, depth, seed) -> None:
    truth = _project(5, 7, yaw_deg=yaw, pitch_deg=pitch, roll_deg=roll, depth_mm=depth)
    rng = np.random.default_rng(seed)
    perm = rng.permutation(len(truth))
    noisy = truth[perm] + rng.normal(0, 0.05, truth.shape)
    fit = order_grid(noisy, 5, 7)
    assert np.array_equal(perm[fit.order], np.arange(35))  # node k is the point that came from node k
    assert fit.residual_max_px < 0.5


def test_square_grid_and_order_convention() -> None:
    truth = _project(4, 4, yaw_deg=10, pitch_deg=-5, roll_deg=8, depth_mm=1500)
    fit = order_grid(truth[::-1], 4, 4)
    assert np.allclose(fit.uv_px, truth)
    assert fit.uv_px[0, 0] < fit.uv_px[3, 0] and fit.uv_px[0, 1] < fit.uv_px[12, 1]  # top-left first


def test_wrong_count_names_the_numbers() -> None:
    truth = _project(5, 7, yaw_deg=0, pitch_deg=0, roll_deg=0, depth_mm=1500)
    with pytest.raises(GridError, match=r"found 34 plate markers.*5 × 7 = 35"):
        order_grid(truth[:-1], 5, 7)


def test_points_off_the_grid_are_refused() -> None:
    pts = _project(5, 7, yaw_deg=0, pitch_deg=0, roll_deg=0, depth_mm=1500)
    pts[17] += (30.0, 25.0)  # one blob far from its node (a spurious detection replaced it)
    with pytest.raises(GridError, match="do not lie on a 5 × 7 grid"):
        order_grid(pts, 5, 7)


def test_bad_input() -> None:
    with pytest.raises(GridError, match=r"finite \(N, 2\)"):
        order_grid(np.full((35, 2), np.nan), 5, 7)
    with pytest.raises(GridError, match="at least 2 × 2"):
        order_grid(np.zeros((3, 2)), 1, 3)


def test_moving_points_separate_the_plate_from_the_references() -> None:
    refs = np.array([[100.0, 100.0], [1800.0, 120.0], [900.0, 1000.0]])
    positions = []
    for depth in (1300.0, 1500.0, 1700.0):
        plate = _project(5, 7, yaw_deg=12, pitch_deg=4, roll_deg=0, depth_mm=depth) + (depth - 1500) * 0.1
        jitter = np.random.default_rng(int(depth)).normal(0, 0.1, refs.shape)
        positions.append(np.vstack([refs + jitter, plate]))
    moving = moving_points(positions)
    for idx in moving:
        assert np.array_equal(idx, np.arange(3, 38))
    with pytest.raises(GridError, match="needs ≥ 2"):
        moving_points(positions[:1])


def test_a_plate_position_with_too_few_frames_is_named_not_fitted() -> None:
    """A still recording that lost frames (a loaded host dropping them) names the camera, the position and
    the counts, instead of averaging what is left and fitting the grid to the wrong points."""
    import pandas as pd

    from procedures.calibrate import StillFramesError, _control_points
    from rig.config.rig_config import default_config

    plate = default_config().targets.calibration_plate
    assert plate is not None

    def seen(frames: int) -> pd.DataFrame:
        return pd.DataFrame({"frame_index": np.repeat(np.arange(frames), 3),
                             "track_2d": np.tile([0, 1, 2], frames), "u_px": 1.0, "v_px": 2.0})

    positions = [{"observations": {"right": seen(frames)}, "slide_mm": slide, "points": {}}
                 for frames, slide in ((12, -120.0), (3, 0.0))]
    message = r"camera 'right', plate position 1 \(slide 0 mm\): 3 frames with markers recorded, at least 6"
    with pytest.raises(StillFramesError, match=message):
        _control_points(positions, "right", plate, 6)
    # a still recording that fell wholly into a skipped burst (the lab at load 9: 0 frames) is named too, not
    # left to make the references look moved in the other positions ("found 39 plate markers" at position 0)
    positions[1]["observations"]["right"] = seen(0)
    with pytest.raises(StillFramesError, match=r"plate position 1 \(slide 0 mm\): 0 frames with markers"):
        _control_points(positions, "right", plate, 6)
