"""Time-stamped camera streams: the live Matroska muxer byte for byte (parsed back by an independent EBML
reader here), FFmpeg reading its stamps through ``cv2.VideoCapture``, and :class:`OpenCVCamera` using them
(``timestamps = "stream"``): the camera's clock kept across recordings, gaps as drops, repeats flagged,
stamps going backwards refused, an MJPEG stream's made-up stamps refused, the rig.toml option validated.

Streams are served over real loopback HTTP; nothing is timed (waits are bounded, generously).
"""

from __future__ import annotations

import contextlib
import struct
import threading
from collections.abc import Iterator, Sequence
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.camera.opencv_device import CameraDeviceError, OpenCVCamera, stamps_itself
from drivers.mock import mkv_stream
from drivers.mock.mjpeg_camera import MjpegCameraServer
from drivers.sim.camera import SimCamera
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World
from rig.config.rig_config import config_from_dict, load_config
from rig.config.schema import ConfigError, to_dict

W, H = 64, 48


# ------------------------------------------------------------------ an independent EBML reader
def _vint(data: bytes, pos: int, *, keep_marker: bool) -> tuple[int, int]:
    first = data[pos]
    length = 8 - first.bit_length() + 1
    value = int.from_bytes(data[pos:pos + length], "big")
    if not keep_marker:
        value &= (1 << (7 * length)) - 1
    return value, length


def elements(data: bytes, start: int = 0, end: int | None = None) -> Iterator[tuple[int, bytes | None, int]]:
    """(id, payload, offset) of the elements in ``data[start:end]``; an unknown-size element's payload is
    None and its children follow it."""
    pos, end = start, len(data) if end is None else end
    while pos < end:
        eid, n = _vint(data, pos, keep_marker=True)
        size, m = _vint(data, pos + n, keep_marker=False)
        body = pos + n + m
        if size == (1 << (7 * m)) - 1:  # unknown size: the children follow
            yield eid, None, pos
            pos = body
            continue
        yield eid, data[body:body + size], pos
        pos = body + size


def _uint(payload: bytes | None) -> int:
    assert payload is not None
    return int.from_bytes(payload, "big")


def parse_stream(data: bytes) -> dict[str, Any]:
    """Header fields and the (timestamp ticks, JPEG) of every frame of a live stream."""
    out: dict[str, Any] = {"frames": []}
    for eid, payload, _ in elements(data):
        if eid == 0x1A45DFA3:
            fields = {e: p for e, p, _ in elements(payload or b"")}
            out["doctype"] = (fields[0x4282] or b"").decode()
            out["doctype_read_version"] = _uint(fields[0x4285])
        elif eid == 0x18538067:
            out["segment_unknown_size"] = payload is None
        elif eid == 0x1549A966:
            out["timestamp_scale_ns"] = _uint(dict((e, p) for e, p, _ in elements(payload or b""))[0x2AD7B1])
        elif eid == 0x1654AE6B:
            (entry_id, entry, _), = list(elements(payload or b""))
            assert entry_id == 0xAE
            fields = {e: p for e, p, _ in elements(entry or b"")}
            video = {e: p for e, p, _ in elements(fields[0xE0] or b"")}
            out["codec"] = (fields[0x86] or b"").decode()
            out["size_px"] = (_uint(video[0xB0]), _uint(video[0xBA]))
            out["track"] = _uint(fields[0xD7])
        elif eid == 0x1F43B675:
            fields = {e: p for e, p, _ in elements(payload or b"")}
            block = fields[0xA3] or b""
            track, relative, flags = block[0] & 0x7F, struct.unpack(">h", block[1:3])[0], block[3]
            assert (track, relative, flags) == (1, 0, 0x80)  # track 1, at the cluster's time, a keyframe
            out["frames"].append((_uint(fields[0xE7]), block[4:]))
    return out


def _jpeg(value: int) -> bytes:
    ok, jpeg = cv2.imencode(".jpg", np.full((H, W), value, np.uint8))
    assert ok
    return bytes(jpeg)


def test_the_header_and_clusters_are_the_matroska_a_live_muxer_writes() -> None:
    data = mkv_stream.stream_header(W, H) + mkv_stream.frame_cluster(12.345678, _jpeg(7)) \
        + mkv_stream.frame_cluster(12.3623, _jpeg(9))
    # the exact bytes of the EBML header and the open segment (RFC 8794/9559)
    assert data.startswith(bytes.fromhex("1a45dfa3a3 4286 8101 42f7 8101 42f2 8104 42f3 8108 4282 88")
                           + b"matroska" + bytes.fromhex("4287 8104 4285 8102")
                           + bytes.fromhex("18538067 01ffffffffffffff"))
    got = parse_stream(data)
    assert got["doctype"] == "matroska" and got["doctype_read_version"] == 2
    assert got["segment_unknown_size"] and got["timestamp_scale_ns"] == 1000
    assert got["codec"] == "V_MJPEG" and got["size_px"] == (W, H) and got["track"] == 1
    assert [t for t, _ in got["frames"]] == [12_345_678, 12_362_300]
    assert [cv2.imdecode(np.frombuffer(j, np.uint8), cv2.IMREAD_GRAYSCALE).mean() for _, j in got["frames"]] \
        == pytest.approx([7, 9], abs=1)


@given(st.floats(min_value=0.0, max_value=1e7, allow_nan=False),
       st.binary(min_size=1, max_size=300))
@settings(max_examples=60, deadline=None)
def test_any_stamp_and_payload_parse_back_exactly(timestamp_s: float, payload: bytes) -> None:
    (ticks, jpeg), = parse_stream(mkv_stream.frame_cluster(timestamp_s, payload))["frames"]
    assert jpeg == payload and ticks == round(timestamp_s * 1e6)


@pytest.mark.parametrize("bad", [-1e-6, float("nan"), float("inf")])
def test_a_stamp_matroska_cannot_carry_is_refused(bad: float) -> None:
    with pytest.raises(ValueError, match="timestamp_s"):
        mkv_stream.frame_cluster(bad, b"x")


# ------------------------------------------------------------------ a stream with chosen stamps, over HTTP
@contextlib.contextmanager
def serve_stamps(stamps_s: Sequence[float]) -> Iterator[str]:
    """A live Matroska stream of one frame per stamp (then it ends), at http://127.0.0.1:PORT/cam.mkv."""

    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.0"

        def log_message(self, format: str, *args: Any) -> None:
            pass

        def do_GET(self) -> None:
            self.send_response(200)
            self.send_header("Content-Type", mkv_stream.CONTENT_TYPE)
            self.end_headers()
            with contextlib.suppress(OSError):
                self.wfile.write(mkv_stream.stream_header(W, H))
                for k, t in enumerate(stamps_s):
                    self.wfile.write(mkv_stream.frame_cluster(t, _jpeg(4 * k % 256)))

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/cam.mkv"
    finally:
        server.shutdown()
        server.server_close()
        thread.join(timeout=10)


def _record_all(camera: OpenCVCamera) -> list[Any]:
    camera.start()
    frames = []
    with contextlib.suppress(CameraDeviceError):
        frames.extend(camera.frames())
    return frames


def test_ffmpeg_reports_the_stamps_to_the_microsecond_relative_to_the_first_frame() -> None:
    stamps = [1000.123456 + k / 60 * (1 + 35e-6) for k in range(40)]
    with serve_stamps(stamps) as url:
        cap = cv2.VideoCapture(url, cv2.CAP_FFMPEG)
        got = []
        while cap.grab():
            got.append(cap.get(cv2.CAP_PROP_POS_MSEC) / 1e3)
        cap.release()
    expected = np.round(np.array(stamps) * 1e6) / 1e6
    assert len(got) == len(stamps)
    assert np.max(np.abs(np.array(got) - (expected - expected[0]))) < 1e-9  # µs ticks, exactly


def test_the_driver_stamps_with_the_stream_flags_gaps_and_repeats() -> None:
    period = 1 / 60
    stamps = [5.0 + k * period for k in range(20)]
    stamps[10:] = [t + 2 * period for t in stamps[10:]]  # two frames lost after the 10th
    stamps.insert(15, stamps[14])  # the 15th repeated
    with serve_stamps(stamps) as url:
        camera = OpenCVCamera("cam", url, fps=60, width_px=W, height_px=H, timestamps="stream")
        frames = _record_all(camera)
        camera.close()
    assert camera.stamping == "stream"
    assert [f.index for f in frames] == list(range(len(stamps)))
    relative = np.array(stamps) - stamps[0]
    assert np.allclose([f.timestamp_s for f in frames], relative, atol=2e-6)
    assert [(d["after_index"], d["missing_frames"]) for d in camera.stats.dropped] == [(9, 2)]
    assert camera.stats.duplicated == [15]
    assert camera.stats.first_arrival_s is not None  # the host's arrival time kept as a diagnostic


def test_stamps_going_backwards_end_the_stream_with_an_error() -> None:
    stamps = [5.0 + k / 60 for k in range(12)]
    stamps[8] = stamps[6]
    with serve_stamps(stamps) as url:
        camera = OpenCVCamera("cam", url, fps=60, width_px=W, height_px=H, timestamps="stream")
        camera.start()
        frames = []
        with pytest.raises(CameraDeviceError, match=r"time stamps went backwards at frame 8"):
            frames.extend(camera.frames())
        camera.close()
    assert [f.index for f in frames] == list(range(8))


# ------------------------------------------------------------------ the lab's camera server
@pytest.fixture
def lab_camera() -> Iterator[MjpegCameraServer]:
    world = World(VirtualClock(rate=1.0), seed=3)
    camera = SimCamera("left", world, width_px=160, height_px=96, fx_px=200.0, cx_px=79.5, cy_px=47.5,
                       clock_ppm=250.0, timestamp_origin_s=803.1)
    with MjpegCameraServer(camera) as server:
        yield server


def _record(camera: OpenCVCamera, n: int) -> list[Any]:
    camera.start()
    frames = []
    for frame in camera.frames():
        frames.append(frame)
        if len(frames) == n and camera.recording:
            camera.stop()
    return frames


def test_the_lab_camera_stamps_are_its_own_clock_kept_across_recordings(
        lab_camera: MjpegCameraServer) -> None:
    """Two recordings on one kept connection: every stamp is the simulated camera's clock of the frame it
    carries (its origin and 1/fps steps, not the host's arrival) relative to the connection's first frame,
    and the clock goes on between recordings."""
    sim = lab_camera.camera
    camera = OpenCVCamera("left", lab_camera.mkv_url, fps=60, width_px=160, height_px=96)
    assert camera.stamping == "stream"  # "auto" on a Matroska URL
    try:
        first = _record(camera, 20)
        second = _record(camera, 20)
    finally:
        camera.close()
    assert lab_camera.stats.first_frames and camera.stats.connections == 1
    origin_s = sim.frame_timestamp_s(lab_camera.stats.first_frames[0])
    assert all(frame.image.shape == (96, 160) for frame in first + second)
    stamps = np.array([f.timestamp_s for f in first + second])
    assert np.all(np.diff(stamps) > 0) and second[0].index > first[-1].index
    # each stamp is k/fps after the connection's first frame (µs ticks); k is the sensor frame
    steps = (stamps + origin_s - sim.timestamp_origin_s) * sim.fps
    assert np.max(np.abs(steps - np.round(steps))) < 1e-3
    assert stamps[0] >= 0.0 and second[0].timestamp_s > first[-1].timestamp_s


def test_an_mjpeg_stream_has_no_stamps_of_its_own(lab_camera: MjpegCameraServer) -> None:
    auto = OpenCVCamera("left", lab_camera.url, fps=60, width_px=160, height_px=96)
    assert auto.stamping == "host"  # "auto" on an MJPEG URL: stamped on arrival
    frames = _record(auto, 3)
    assert len(frames) >= 3 and not auto.recording
    forced = OpenCVCamera("left", lab_camera.url, fps=60, width_px=160, height_px=96, timestamps="stream")
    forced.start()
    with pytest.raises(CameraDeviceError, match=r"carries no time stamps \(FFmpeg made up 25 fps"):
        list(forced.frames())
    forced.close()


def test_the_sources_auto_trusts_and_the_option_validated() -> None:
    assert stamps_itself("http://cam/left.mkv") and stamps_itself("rtsp://10.0.0.2/stream1")
    assert stamps_itself("http://cam/live.webm?token=x")
    assert not stamps_itself("http://cam/video.mjpg") and not stamps_itself(0)
    assert not stamps_itself("/videos/left.mkv")  # a file: host stamps unless asked ("stream")
    with pytest.raises(ValueError, match="timestamps='camera'; allowed: 'auto', 'stream', 'host'"):
        OpenCVCamera("x", 0, timestamps="camera")
    table = to_dict(load_config())
    table.pop("source", None)
    table["cameras"]["left"]["timestamps"] = "stream"  # a sim camera: refused, naming the field
    with pytest.raises(ConfigError, match=r"cameras\.left\.timestamps.*driver \"opencv\""):
        config_from_dict(table)
    table["cameras"]["left"].update(driver="opencv", source="http://127.0.0.1:1/left.mkv", timestamps="clock")
    with pytest.raises(ConfigError, match=r"cameras\.left\.timestamps"):
        config_from_dict(table)


def test_a_stamped_source_that_cannot_be_opened_is_refused_by_start() -> None:
    camera = OpenCVCamera("left", "http://127.0.0.1:9/left.mkv", fps=60, width_px=W, height_px=H)
    with pytest.raises(CameraDeviceError, match=r"is not streaming: .*cannot open device"):
        camera.start()
    assert not camera.recording
