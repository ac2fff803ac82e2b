"""The lab's parts: the MJPEG-over-HTTP camera (bytes on the wire, what a client decodes, frames skipped when
rendering falls behind), the scaled configuration it serves and the ``rig.toml`` it hands out."""

from __future__ import annotations

import itertools
import re
import socket
import tomllib

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.mock.mjpeg_camera import BOUNDARY, MjpegCameraServer
from drivers.sim.clock import VirtualClock
from drivers.sim.stereo_rig import default_camera_specs, make_camera
from drivers.sim.world import World
from rig.config.rig_config import config_from_dict, default_config
from rig.config.toml_text import to_toml
from rig.run.lab import client_table, lab_table, open_lab
from rig.run.station import StationError, camera_specs, mount_in_lab

WAIT_S = 60.0  # socket time-out on a loaded machine


def _camera(rate: float, width_px: int = 320, height_px: int = 180) -> MjpegCameraServer:
    spec = default_camera_specs()[0]
    s = width_px / 1920
    camera = make_camera(spec, World(VirtualClock(rate=rate), seed=3), width_px=width_px, height_px=height_px,
                         fx_px=spec.fx_px * s, fy_px=spec.fy_px * s, cx_px=(spec.cx_px + 0.5) * s - 0.5,
                         cy_px=(spec.cy_px + 0.5) * s - 0.5)
    return MjpegCameraServer(camera)


def _get(port: int, path: str) -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", port), timeout=WAIT_S)
    sock.sendall(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
    return sock


def _read_until(sock: socket.socket, buffer: bytearray, marker: bytes) -> bytes:
    while marker not in buffer:
        chunk = sock.recv(65536)
        assert chunk, "the server closed the stream"
        buffer += chunk
    head, _, rest = bytes(buffer).partition(marker)
    buffer[:] = rest
    return head


def _read_exactly(sock: socket.socket, buffer: bytearray, n: int) -> bytes:
    while len(buffer) < n:
        chunk = sock.recv(65536)
        assert chunk, "the server closed the stream"
        buffer += chunk
    out = bytes(buffer[:n])
    buffer[:] = buffer[n:]
    return out


def test_the_stream_is_multipart_jpeg_parts_of_the_rendered_frames() -> None:
    with _camera(rate=1.0) as server:
        sock = _get(server.port, "/left.mjpg")
        buffer = bytearray()
        head = _read_until(sock, buffer, b"\r\n\r\n").decode("ascii")
        assert head.startswith("HTTP/1.0 200")
        assert f"Content-Type: multipart/x-mixed-replace; boundary={BOUNDARY}" in head
        for _ in range(3):
            part = _read_until(sock, buffer, b"\r\n\r\n").decode("ascii")
            assert part.startswith(f"--{BOUNDARY}\r\n") and "Content-Type: image/jpeg" in part
            length = int(re.search(r"Content-Length: (\d+)", part).group(1))  # type: ignore[union-attr]
            jpeg = _read_exactly(sock, buffer, length)
            assert _read_exactly(sock, buffer, 2) == b"\r\n"
            image = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
            assert image.shape == (180, 320)
            # the JPEG of a rendered frame: close to one of the frames exposed up to now (noise differs)
            now = server.clock.now_s()
            last = server.camera.first_frame_index_at_or_after(now) - 1
            errors = [np.abs(image.astype(float) - server.camera.render(i)).mean()
                      for i in range(max(0, last - 240), last + 1)]
            assert min(errors) < 3.0, min(errors)
        sock.close()


def test_unknown_path_is_404_naming_the_stream() -> None:
    with _camera(rate=1.0) as server:
        sock = _get(server.port, "/video")
        reply = sock.recv(4096).decode("ascii", "replace")
        sock.close()
    assert reply.startswith("HTTP/1.0 404") and "/left.mjpg" in reply


def test_frames_are_skipped_not_sent_late_when_rendering_falls_behind() -> None:
    # 50 virtual s per wall s: 3000 frames per wall second, far more than any host renders
    with _camera(rate=50.0) as server:
        cap = cv2.VideoCapture(server.url, cv2.CAP_FFMPEG)
        assert cap.isOpened()
        for _ in range(5):
            assert cap.grab()
        cap.release()
        stats = server.stats
    assert stats.published >= 5
    assert stats.skipped > stats.published  # each render takes ≥ 1 ms wall = 50 virtual ms = 3 frames


def test_the_server_binds_loopback_only() -> None:
    spec = default_camera_specs()[0]
    camera = make_camera(spec, World(VirtualClock(rate=1.0)), width_px=320, height_px=180)
    with pytest.raises(ValueError, match="loopback"):
        MjpegCameraServer(camera, host="0.0.0.0")


def test_scaled_cameras_see_the_world_where_the_configured_ones_do_scaled() -> None:
    config = default_config()
    scaled = config_from_dict(lab_table(config, 0.5), "lab")
    world = World(VirtualClock())
    point = np.array([[420.0, 30.0, 310.0], [300.0, -150.0, 420.0]])
    for full, half in zip(camera_specs(config), camera_specs(scaled), strict=True):
        assert scaled.cameras[half.name].resolution_px == (960, 540)
        uv_full = make_camera(full, world).project(point)
        uv_half = make_camera(half, world, width_px=960, height_px=540).project(point)
        np.testing.assert_allclose(uv_half, (uv_full + 0.5) * 0.5 - 0.5, atol=1e-9)
    assert scaled.fiducial is not None and config.fiducial is not None
    x0, y0, x1, y1 = scaled.fiducial.regions_px["left"]
    X0, Y0, X1, Y1 = config.fiducial.regions_px["left"]
    assert (x0, y0) == (X0 // 2, Y0 // 2) and (x1, y1) == (-(-X1 // 2), -(-Y1 // 2))


def test_bad_scale_and_non_simulated_configurations_are_refused_naming_the_field() -> None:
    with pytest.raises(ValueError, match=r"--scale.*allowed: within \(0, 1\]"):
        lab_table(default_config(), 1.5)


def test_the_client_config_puts_every_device_and_camera_at_its_endpoint() -> None:
    served = lab_table(default_config(), 0.5, fps=30.0)
    endpoints = {"robot": "tcp://127.0.0.1:5007", "exciter": "tcp://127.0.0.1:5008",
                 "rotor": "tcp://127.0.0.1:5009", "generator": "tcp://127.0.0.1:5010",
                 "cameras.left": "http://127.0.0.1:5011/left.mjpg",
                 "cameras.right": "http://127.0.0.1:5012/right.mjpg", "control": "http://127.0.0.1:5013"}
    text = to_toml(client_table(served, endpoints), "header")
    config = config_from_dict(tomllib.loads(text), "written")
    assert {name: dev.address for name, dev in config.devices.configured().items()} == \
        {k: v for k, v in endpoints.items() if k in ("robot", "exciter", "rotor", "generator")}
    for name, cam in config.cameras.items():
        assert (cam.driver, cam.source, cam.fps, cam.resolution_px) == \
            ("opencv", endpoints[f"cameras.{name}"], 30.0, (960, 540))
    assert config.sim is not None and (config.sim.rate, config.sim.lab_url) == (1.0, endpoints["control"])


@pytest.mark.parametrize("url", ["http://10.0.0.5:8000", "https://127.0.0.1:8000", "http://127.0.0.1",
                                 "127.0.0.1:8000"])
def test_lab_url_must_be_a_loopback_http_endpoint(url: str) -> None:
    table = lab_table(default_config(), 0.5)
    table["sim"]["lab_url"] = url
    with pytest.raises(ValueError, match=r"sim\.lab_url.*allowed: http://127\.0\.0\.1:PORT"):
        config_from_dict(table, "t")


def test_the_station_mounts_targets_in_the_lab_world() -> None:
    import urllib.request

    with open_lab(default_config()) as lab:
        control = lab.endpoints["control"]
        with urllib.request.urlopen(f"{control}/mount", timeout=WAIT_S) as reply:
            assert reply.read().decode().strip() == "calibration_plate"  # [sim] initial_scene
        mount_in_lab(control, "sweep_column")
        with urllib.request.urlopen(f"{control}/mount", timeout=WAIT_S) as reply:
            assert reply.read().decode().strip() == "sweep_column"
        with pytest.raises(StationError, match=r"mount 'spinning_top'.*sim\.lab_url.*404"):
            mount_in_lab(control, "spinning_top")
    with pytest.raises(StationError, match="did not mount it"):  # the lab is gone
        mount_in_lab(control, "rotor", timeout_s=WAIT_S)


_names = st.text(st.characters(codec="utf-8", exclude_categories=("Cs",)), min_size=1, max_size=8)
_scalars = st.one_of(st.booleans(), st.integers(-2**63, 2**63 - 1), st.floats(allow_nan=False),
                     st.text(st.characters(codec="utf-8", exclude_categories=("Cs",)), max_size=12))
_values = st.recursive(_scalars, lambda inner: st.lists(inner, max_size=4), max_leaves=8)
_tables = st.recursive(st.dictionaries(_names, _values, max_size=4),
                       lambda inner: st.dictionaries(_names, st.one_of(_values, inner), max_size=4),
                       max_leaves=12)


@settings(max_examples=200, deadline=None)
@given(_tables)
def test_toml_text_reads_back_equal(table: dict) -> None:
    assert tomllib.loads(to_toml(table, "a header\nof two lines")) == table


@pytest.mark.parametrize(("argv", "message"), [(["--scale", "2"], r"--scale: 2\.0; allowed: within \(0, 1\]"),
                                               (["--fps", "0"], r"fps"),
                                               (["--host", "0.0.0.0"], "loopback")])
def test_bad_lab_options_exit_4_naming_the_option(argv: list[str], message: str,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    from rig.run.lab import main

    with pytest.raises(SystemExit) as exit_info:
        main(argv, prog="rig mock lab")
    assert exit_info.value.code == 4
    assert re.search(message, capsys.readouterr().err)


def test_the_opencv_camera_driver_records_the_stream_at_the_configured_rate() -> None:
    """FFmpeg reports 25 fps for any MJPEG stream: the driver takes a URL source's rate from arrival times
    instead of refusing the 60 fps it was configured with; the size is still checked."""
    from drivers.camera.opencv_device import CameraDeviceError, OpenCVCamera

    with _camera(rate=1.0) as server:
        camera = OpenCVCamera("left", server.url, fps=60.0, width_px=320, height_px=180)
        assert camera.streamed
        camera.start()
        frames = []
        for frame in camera.frames():
            frames.append(frame)
            if len(frames) == 5:
                camera.stop()
        assert len(frames) >= 5 and frames[0].image.shape == (180, 320)
        assert all(b.timestamp_s > a.timestamp_s for a, b in itertools.pairwise(frames))
        with pytest.raises(CameraDeviceError, match="requested 640×360 px, the device gives 320×180"):
            OpenCVCamera("left", server.url, fps=60.0, width_px=640, height_px=360).start()
