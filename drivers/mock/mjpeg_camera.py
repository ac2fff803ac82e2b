"""A simulated camera served as an IP camera over HTTP, in two forms ``cv2.VideoCapture("http://…")`` (FFmpeg)
opens: MJPEG (``/<name>.mjpg``: ``multipart/x-mixed-replace``, one JPEG per part, the protocol of most
network cameras; no time stamps) and Matroska (``/<name>.mkv``: a live ``video/x-matroska`` stream of the
same JPEGs, :mod:`drivers.mock.mkv_stream`, each stamped with the camera's own clock).

:class:`MjpegCameraServer` renders a :class:`drivers.sim.camera.SimCamera` (rolling shutter, noise, the
world's LEDs, as the twin renders it) at the camera's frame rate, paced to the world clock: frame ``i`` is
rendered once its last row has been exposed (world time ``frame_start_true_s(i) + readout_s``) and sent at
once to every connected client. In MJPEG, frames carry no time stamp (like most IP cameras): the client
stamps them on arrival. In Matroska, frame ``i`` carries :meth:`SimCamera.frame_timestamp_s` ``(i)``: the
simulated camera's clock (its ppm drift and origin) at the start of the frame's exposure (row 0), what a
camera that stamps its frames (RTSP/RTP, a streaming muxer) sends; FFmpeg reports it relative to the first
frame of the connection, so a client keeps its connection to keep one clock.

A real IP camera drops frames when the host or the network is slow; so does this one: with ``catch_up_s``
0 (default, for clients that stamp frames on arrival), a frame whose successor is already fully exposed
when its turn comes (rendering fell behind) is skipped, never sent late as if on time — the client's driver
sees the gap in its arrival times or in the stream's stamps (``stats.skipped`` counts them); the frame sent
is always the newest one exposed when its rendering began: its latency is one render + encode (like a
camera's encoder), never a queue of older frames. A time-stamped stream's frames may arrive late without
harm (their stamps say when they were exposed), as from a camera whose network buffers: with
``catch_up_s`` > 0, rendering that fell behind catches up (every frame is sent, late) unless it is more
than ``catch_up_s`` behind, and only then skips to the newest frame (a starved renderer is the simulation's
limit, not the simulated camera's). A client that reads slowly gets the newest frame when it asks again
(the older ones are gone for it).
Frames are rendered only while a client is connected (an idle camera costs no CPU).

Binds a loopback address only (:func:`drivers.mock._serve.require_loopback`).
"""

from __future__ import annotations

import collections
import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from io import BufferedIOBase
from typing import Any

import cv2
import numpy as np

from drivers.mock import mkv_stream
from drivers.mock._serve import require_loopback
from drivers.sim.camera import SimCamera

__all__ = ["BOUNDARY", "MjpegCameraServer", "StreamStats"]

Part = Callable[[int, bytes], bytes]  # (frame index, JPEG) → the bytes that carry it

log = logging.getLogger("drivers.mock.mjpeg")
BOUNDARY = "rigframe"
_POLL_S = 0.1  # (wall s) how often waiting threads look at the stop flag


@dataclass
class StreamStats:
    """What the camera did: frames rendered and published, frames skipped because rendering fell behind,
    render + encode CPU time (thread CPU seconds); ``first_frames``: per Matroska connection, the index of
    its first frame (the origin of the client's clock: FFmpeg stamps relative to it)."""

    published: int = 0
    skipped: int = 0
    render_cpu_s: float = 0.0
    first_frames: list[int] = field(default_factory=list)


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    camera_server: MjpegCameraServer


class _Handler(BaseHTTPRequestHandler):
    server: _Server
    protocol_version = "HTTP/1.0"

    def log_message(self, format: str, *args: Any) -> None:
        log.debug("mjpeg %s: " + format, self.address_string(), *args)

    def do_GET(self) -> None:
        cam = self.server.camera_server
        path = self.path.split("?", 1)[0]
        if path not in (cam.path, cam.mkv_path):
            self.send_error(404, f"no such stream; this camera serves {cam.path} and {cam.mkv_path}")
            return
        matroska = path == cam.mkv_path
        self.send_response(200)
        self.send_header("Content-Type", mkv_stream.CONTENT_TYPE if matroska
                         else f"multipart/x-mixed-replace; boundary={BOUNDARY}")
        self.send_header("Cache-Control", "no-cache, no-store")
        self.send_header("Connection", "close")
        self.end_headers()
        with contextlib.suppress(OSError):  # the client hung up
            if matroska:
                cam.stream_matroska_to(self.wfile)
            else:
                cam.stream_to(self.wfile)


class MjpegCameraServer:
    """Serve ``camera`` (see the module docstring) on ``host:port`` (loopback only; port 0 = any free port)
    at paths ``/<camera.name>.mjpg`` (:attr:`url`) and ``/<camera.name>.mkv`` (:attr:`mkv_url`).
    ``jpeg_quality``: 1..100; ``catch_up_s``: how far behind rendering may fall before frames are skipped
    (module docstring; 0: always the newest frame)."""

    def __init__(self, camera: SimCamera, *, host: str = "127.0.0.1", port: int = 0,
                 jpeg_quality: int = 90, catch_up_s: float = 0.0) -> None:
        if not 1 <= int(jpeg_quality) <= 100:
            raise ValueError(f"jpeg_quality={jpeg_quality!r}; allowed: 1..100")
        if not (math.isfinite(catch_up_s) and 0.0 <= catch_up_s <= 10.0):
            raise ValueError(f"catch_up_s={catch_up_s!r}; allowed: 0..10 s")
        self.catch_up_frames = math.floor(catch_up_s * camera.fps)
        self.camera = camera
        self.clock = camera.world.clock
        self.host = require_loopback(host)
        self.path = f"/{camera.name}.mjpg"
        self.mkv_path = f"/{camera.name}.mkv"
        self.jpeg_quality = int(jpeg_quality)
        self.stats = StreamStats()
        self._httpd = _Server((self.host, int(port)), _Handler, bind_and_activate=True)
        self._httpd.camera_server = self
        self.port: int = self._httpd.server_address[1]
        self._cond = threading.Condition()
        self._latest: tuple[int, bytes] | None = None  # (frame index, JPEG) last published
        # the frames published lately, sent in order to a client that fell behind (catch_up_s > 0)
        self._recent: collections.deque[tuple[int, bytes]] = collections.deque(
            maxlen=self.catch_up_frames + 2)
        self._clients = 0
        self._stopped = threading.Event()
        self._threads: list[threading.Thread] = []

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}{self.path}"

    @property
    def mkv_url(self) -> str:
        return f"http://{self.host}:{self.port}{self.mkv_path}"

    def start(self) -> MjpegCameraServer:
        for target, name in ((self._httpd.serve_forever, "http"), (self._produce, "render")):
            thread = threading.Thread(target=target, name=f"mjpeg-{self.camera.name}-{name}", daemon=True)
            thread.start()
            self._threads.append(thread)
        log.info("camera %s: MJPEG over HTTP at %s, time-stamped Matroska at %s (%d×%d px, %g fps)",
                 self.camera.name, self.url, self.mkv_url, self.camera.width_px, self.camera.height_px,
                 self.camera.fps)
        return self

    def stop(self) -> None:
        """Stop rendering, end every stream, close the socket."""
        self._stopped.set()
        with self._cond:
            self._cond.notify_all()
        self._httpd.shutdown()
        self._httpd.server_close()
        for thread in self._threads:
            thread.join(timeout=5.0)

    def __enter__(self) -> MjpegCameraServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------------ rendering (one thread)
    def _ready_s(self, index: int) -> float:
        """World time at which frame ``index`` is fully exposed (its last row's exposure ended)."""
        return self.camera.frame_start_true_s(index) + self.camera.readout_s

    def _latest_ready(self, now_s: float) -> int:
        """The newest frame fully exposed at world time ``now_s`` (−1 if none)."""
        cam = self.camera
        k = math.floor((now_s - cam.readout_s - cam.start_offset_s) / cam.frame_period_true_s + 1e-9)
        return cam.first_frame_index_at_or_after(cam.start_offset_s + (k + 0.5) * cam.frame_period_true_s) - 1

    def _wait_world(self, t_s: float) -> bool:
        """Sleep until world time ``t_s`` in slices (stop looked at); False when stopped."""
        while not self._stopped.is_set():
            remaining_s = t_s - self.clock.now_s()
            if remaining_s <= 0:
                return True
            rate = self.clock.rate or 1.0
            self._stopped.wait(min(_POLL_S, remaining_s / rate))
        return False

    def _wait_for_client(self) -> bool:
        with self._cond:
            while self._clients == 0 and not self._stopped.is_set():
                self._cond.wait(_POLL_S)
        return not self._stopped.is_set()

    def _produce(self) -> None:
        index: int | None = None
        while self._wait_for_client():
            if index is None:  # (re)starting: the next frame from now on
                index = self.camera.first_frame_index_at_or_after(self.clock.now_s())
            if not self._wait_world(self._ready_s(index)):
                return
            newest = self._latest_ready(self.clock.now_s())
            if newest > index + self.catch_up_frames:  # too far behind: the frames before the newest dropped
                self.stats.skipped += newest - index
                index = newest
            cpu0_s = time.thread_time()
            image = self.camera.render(index)
            ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
            self.stats.render_cpu_s += time.thread_time() - cpu0_s
            if ok:
                self._publish(index, np.asarray(jpeg).tobytes())
            else:
                log.error("camera %s: frame %d could not be JPEG-encoded; skipped", self.camera.name, index)
            index += 1
            with self._cond:
                if self._clients == 0:
                    index = None

    def _publish(self, index: int, jpeg: bytes) -> None:
        with self._cond:
            self._latest = (index, jpeg)
            self._recent.append(self._latest)
            self.stats.published += 1
            self._cond.notify_all()

    # ------------------------------------------------------------------ streaming (one thread per client)
    def stream_to(self, out: BufferedIOBase) -> None:
        """Write every frame published from now on to ``out`` (a binary file) as multipart parts, until the
        server stops or the client hangs up (``OSError``)."""
        self._follow(out, lambda _index, jpeg: (
            f"--{BOUNDARY}\r\nContent-Type: image/jpeg\r\nContent-Length: {len(jpeg)}\r\n\r\n"
            .encode("ascii") + jpeg + b"\r\n"))

    def stream_matroska_to(self, out: BufferedIOBase) -> None:
        """As :meth:`stream_to`, as a live Matroska stream: its header, then one cluster per frame stamped
        with the camera's clock (:meth:`SimCamera.frame_timestamp_s`)."""
        out.write(mkv_stream.stream_header(self.camera.width_px, self.camera.height_px))
        first = True

        def cluster(index: int, jpeg: bytes) -> bytes:
            nonlocal first
            if first:
                self.stats.first_frames.append(index)
                first = False
            return mkv_stream.frame_cluster(self.camera.frame_timestamp_s(index), jpeg)

        self._follow(out, cluster)

    def _follow(self, out: BufferedIOBase, part: Part) -> None:
        """Write ``part(index, jpeg)`` of every frame published from now on to ``out``, until the server
        stops or the client hangs up (``OSError``)."""
        with self._cond:
            self._clients += 1
            sent = self._latest[0] if self._latest is not None else -1
            self._cond.notify_all()
        try:
            while True:
                with self._cond:
                    while not self._stopped.is_set() and (self._latest is None or self._latest[0] <= sent):
                        self._cond.wait(_POLL_S)
                    if self._stopped.is_set() or self._latest is None:
                        return
                    batch = ([f for f in self._recent if f[0] > sent] if self.catch_up_frames
                             else [self._latest])
                    sent = batch[-1][0]
                for index, jpeg in batch:
                    out.write(part(index, jpeg))
                out.flush()
        finally:
            with self._cond:
                self._clients -= 1
