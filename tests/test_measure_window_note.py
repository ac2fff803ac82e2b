"""`rig measure` says when its markers do not fit the tracking window (rig.deploy.video_markers.window_note):
a marker that still fills its window after the retries is measured from its cut-off part, unflagged."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest
from marker_images import Disc, render

from rig.deploy.video_markers import WINDOW_MARGIN_PX, ExtractOptions, extract_video, window_note


def _rows(area_px: float, roundness: float, count: int = 20) -> pd.DataFrame:
    return pd.DataFrame({"area_px": np.full(count, area_px), "roundness": np.full(count, roundness)})


@pytest.mark.parametrize(("a_px", "b_px", "fits"), [(16.0, 16.0, True), (16.6, 16.6, False),
                                                     (18.0, 9.0, False), (14.0, 7.0, True)])
def test_the_major_axis_plus_the_margin_decides(a_px: float, b_px: float, fits: bool) -> None:
    """An ellipse of semi-axes a, b has area πab and roundness b/a: its major axis 2a is what must fit."""
    note = window_note(_rows(math.pi * a_px * b_px, b_px / a_px), 41, "left")
    assert (note is None) == fits
    assert (2 * a_px + WINDOW_MARGIN_PX <= 41) == fits


def test_the_note_names_the_camera_the_size_and_an_odd_window_that_fits() -> None:
    note = window_note(_rows(math.pi * 20.0**2, 1.0), 41, "right")
    assert note is not None and note.startswith("camera right: markers up to 40 px across")
    assert "--window-px 49 or more" in note  # 40 + 8 = 48, rounded up to odd (track_markers' windows)


def test_no_measured_row_gives_no_note() -> None:
    assert window_note(_rows(float("nan"), float("nan")), 41, "left") is None
    assert window_note(_rows(1.0, 1.0, count=0), 41, "left") is None


def _video(path: Path, radius_px: float, frames: int = 12) -> Path:
    """A still, blurred bright disc of ``radius_px`` on 160×160 frames (MJPG AVI: written everywhere)."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 60.0, (160, 160), False)
    assert writer.isOpened()
    for k in range(frames):
        writer.write(render((160, 160), [Disc(80.3, 79.6, radius_px)], blur_sigma_px=2.0, seed=k))
    writer.release()
    return path


@pytest.mark.parametrize(("radius_px", "window_px", "noted"), [(22.0, 41, True), (22.0, 61, False),
                                                               (8.0, 41, False)])
def test_measured_markers_too_large_for_the_window_are_noted(tmp_path: Path, radius_px: float,
                                                             window_px: int, noted: bool) -> None:
    """The size comes from what the tracker measured: a blurred r 22 px disc needs more than 41 px."""
    vo = extract_video(_video(tmp_path / "disc.avi", radius_px), "left", ExtractOptions(window_px=window_px))
    assert len(vo.observations) >= 10
    assert (window_note(vo.observations, window_px, "left") is not None) == noted
