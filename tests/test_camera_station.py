"""The station builds the real camera devices of rig.toml: ``driver = "file"`` and ``driver = "opencv"``."""

from __future__ import annotations

from pathlib import Path

import measure_twin as mt
import pytest

from drivers.camera.opencv_device import OpenCVCamera
from drivers.camera.video_file import VideoFile
from rig.config.rig_config import load_config
from rig.run.clock import make_clock
from rig.run.station import StationError, open_station

BUILTIN = Path(__file__).resolve().parents[1] / "rig" / "data" / "sim.toml"


def _bench_config(folder: Path, left: str, right: str) -> Path:
    """The built-in rig without devices and twin: a camera-only real station (as on site)."""
    out, skip = [], False
    for line in BUILTIN.read_text().splitlines():
        if line.startswith("["):
            skip = line.startswith(("[devices.", "[sim", "[fiducial"))  # no generator: no LED
        if not skip:
            out.append(line)
    text = "\n".join(out).replace("[station]", "[devices]\n\n[station]")
    for old, new in (("simulated = true", "simulated = false"), ('clock = "virtual"', 'clock = "wall"'),
                     ('[cameras.left]\ndriver = "sim"',
                      f'[cameras.left]\ndriver = "file"\nsource = "{left}"'),
                     ('[cameras.right]\ndriver = "sim"',
                      f'[cameras.right]\ndriver = "opencv"\nsource = "{right}"')):
        text = text.replace(old, new)
    text = text.replace("resolution_px = [1920, 1080]", "resolution_px = [960, 540]")
    (folder / "rig.toml").write_text(text)
    return folder / "rig.toml"


def test_file_and_opencv_cameras_are_built(tmp_path: Path) -> None:
    left, right = mt.camera_pair(mt.measurement_world())
    left.write_video(tmp_path / "l.avi", 0.0, 0.3, fourcc="MJPG")
    right.write_video(tmp_path / "r.avi", 0.0, 0.3, fourcc="MJPG")
    cfg = load_config(_bench_config(tmp_path, str(tmp_path / "l.avi"), str(tmp_path / "r.avi")))
    with open_station(cfg, make_clock(False)) as station:
        file_cam, live = station.cameras["left"], station.cameras["right"]
        assert isinstance(file_cam, VideoFile) and isinstance(live, OpenCVCamera)
        assert sum(1 for _ in file_cam.frames()) == 18
        live.start()
        first = next(live.frames())
        live.stop()
        assert first.index == 0 and first.image.shape == (540, 960)


def test_a_missing_video_file_is_a_station_error(tmp_path: Path) -> None:
    cfg = load_config(_bench_config(tmp_path, str(tmp_path / "none.mp4"), "0"))
    with pytest.raises(StationError, match=r"cameras.left.source: .*no such video file"), \
            open_station(cfg, make_clock(False)):
        pass
