"""Live capture through cv2.VideoCapture: grabbing thread, host time stamps, drops, bounded queue, stop.

No camera is attached to the test machine, so the device is OpenCV's capture of a video file written by the
twin (a real ``cv2.VideoCapture``, grabbed as fast as it decodes). Drop detection is tested through the
injected host clock, which is where a device's drops show.
"""

from __future__ import annotations

import threading
from pathlib import Path

import measure_twin as mt
import numpy as np
import pytest

from drivers.camera.base import FrameSource
from drivers.camera.opencv_device import CameraDeviceError, OpenCVCamera, parse_source


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int]:
    folder = tmp_path_factory.mktemp("live")
    left, _ = mt.camera_pair(mt.measurement_world())
    n = left.write_video(folder / "clip.avi", 0.0, 1.0, fourcc="MJPG")
    return folder / "clip.avi", n


def test_frames_in_order_with_host_stamps_and_clean_stop(clip: tuple[Path, int]) -> None:
    path, n = clip
    cam = OpenCVCamera("left", str(path), fps=60, width_px=960, height_px=540, queue_frames=n + 5)
    assert isinstance(cam, FrameSource)
    cam.start()
    got = []
    with pytest.raises(CameraDeviceError, match="stopped delivering frames after 60"):
        got.extend(cam.frames())  # the file ends: for a device, the stream stopped while recording
    assert [f.index for f in got] == list(range(n))
    stamps = np.array([f.timestamp_s for f in got])
    assert np.all(np.diff(stamps) >= 0)
    assert got[0].image.shape == (540, 960) and got[0].image.dtype == np.uint8
    assert cam.stats.delivered == n and cam.stats.overflow == []
    cam.stop()
    assert not cam.recording


def test_stop_while_grabbing_ends_the_stream_without_error(clip: tuple[Path, int]) -> None:
    path, n = clip
    cam = OpenCVCamera("left", str(path), fps=60, width_px=960, height_px=540, queue_frames=4)
    cam.start()
    first = []
    it = cam.frames()
    first.append(next(it))
    cam.stop()
    rest = list(it)  # drains what was queued, then ends (no error: stopped on request)
    indices = [f.index for f in first + rest]
    assert indices == sorted(indices) and len(indices) <= n
    # a bounded queue: what the consumer could not take is counted, never blocking the grabber
    assert cam.stats.delivered == len(indices) + len(cam.stats.overflow)
    assert not cam.recording


def test_drops_detected_from_host_time_stamp_gaps(clip: tuple[Path, int]) -> None:
    path, n = clip
    skip = {10: 2, 25: 1}  # after delivered frame 10 the device lost 2 frames, after 25 one
    lock = threading.Lock()
    state = {"t": 0.0, "k": 0}

    def host_clock() -> float:
        with lock:
            k = state["k"]
            state["t"] += (1 + skip.get(k - 1, 0)) / 60 if k else 0.0
            state["k"] += 1
            return state["t"]

    cam = OpenCVCamera("left", str(path), fps=60, width_px=960, height_px=540, queue_frames=n + 5,
                       clock=host_clock)
    cam.start()
    with pytest.raises(CameraDeviceError):
        list(cam.frames())
    assert [(d["after_index"], d["missing_frames"]) for d in cam.stats.dropped] == [(10, 2), (25, 1)]
    assert cam.stats.missing_frames == 3
    cam.stop()


def test_bad_device_and_mode_are_clear_errors(clip: tuple[Path, int], tmp_path: Path) -> None:
    with pytest.raises(CameraDeviceError, match="cannot open device"):
        OpenCVCamera("x", str(tmp_path / "no-such-device"), fps=60).start()
    with pytest.raises(CameraDeviceError, match="requested 1920×1080 px, the device gives 960×540"):
        OpenCVCamera("x", str(clip[0]), fps=60, width_px=1920, height_px=1080).start()
    with pytest.raises(CameraDeviceError, match="not recording"):
        OpenCVCamera("x", 0).stop()
    assert parse_source("2") == 2 and parse_source("/dev/video1") == "/dev/video1"
    with pytest.raises(ValueError, match="source is empty"):
        parse_source(" ")
    with pytest.raises(ValueError, match="fps"):
        OpenCVCamera("x", 0, fps=0)
