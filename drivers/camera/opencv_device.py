"""Live capture from an OpenCV video device (USB/V4L2 camera, or any source ``cv2.VideoCapture`` opens).

:class:`OpenCVCamera` implements ``FrameSource``. :meth:`~OpenCVCamera.start` opens the device and starts
**one grabbing thread per camera**: it calls ``grab()`` back to back (the device's own pace), stamps each
frame, decodes it to grey and puts it in a **bounded queue**. The thread never blocks on the queue: when
the consumer falls behind, the oldest queued frame is discarded and counted (``stats.overflow``), so the
device buffer never overruns silently.

**Time stamps** (``timestamps``, rig.toml ``cameras.<name>.timestamps``):

- ``"stream"``: the source's presentation time stamp (``CAP_PROP_POS_MSEC`` after ``grab()``; FFmpeg gives
  it to the µs): the **camera's own clock**, as a time-stamping network camera (Matroska, RTSP/RTP) sends
  it. FFmpeg reports it relative to the connection's first frame, so the connection (and with it the
  camera's clock) is **kept from the first** :meth:`start` **to** :meth:`close`: between recordings the
  thread grabs and discards (an MJPEG stream's packets are not even decoded: :meth:`_raw_jpeg`), and a
  recording holds the frames grabbed between :meth:`start` and :meth:`stop` (on a kept connection, once it
  has streamed :data:`SETTLE_S`). A stream without stamps is refused when it shows: FFmpeg makes up 25 fps
  stamps for an MJPEG stream (its first :data:`MADE_UP_CHECK` intervals all exactly 40 ms, while the camera
  is configured otherwise). A stamp that goes backwards ends the stream with an error, a repeated one is a
  duplicate (delivered, its index in ``stats.duplicated``). A reconnection (after an error) starts a new
  clock: ``stats.connections`` counts them. The network source is opened by the grabbing thread:
  :meth:`connect` (the station calls it when it builds the camera, so that every camera streams before the
  first recording) returns at once, and :meth:`start` waits (``connect_timeout_s``) for the first frame, so
  that a short first recording is not lost to FFmpeg's probing (≈ 0.5 s). Two connections' clocks start at
  different instants (each its first frame), so a recording on a kept connection starts by exposure, not by
  arrival: with the camera's clock mapped onto the host's by the lowest arrival latency of the last
  :data:`LAG_WINDOW_S` of frames (``arrival − stamp``), it holds the frames exposed at or after
  :meth:`start`'s host instant — late by at most that lowest latency (the camera's readout, encoding and
  transport), and ends alike: after :meth:`stop`, :meth:`frames` goes on yielding the frames exposed
  before it that arrive late, until the first frame exposed after it arrives (or :data:`DRAIN_S` passes).
  The mapping in use when a recording's first frame came is kept (:meth:`~OpenCVCamera.clock_mapping`,
  :func:`clock_mapping_of`): the cameras' start events carry it, and the sync's offset guess is the
  difference of two cameras' mappings — exact to their latencies' difference whatever frames either skipped
  at the start (a first frame would date it only to a frame, and a skipped burst of frames would shift it).
  Frames that arrive late (a host or camera catching up) raise the window's median latency
  (``lag_spread_s``), never its lowest.
- ``"host"``: the **host clock** right after ``grab()`` returns (``time.monotonic`` by default,
  injectable): for a source whose frames carry no time stamp (MJPEG IP cameras); the arrival jitters with
  the host's load. The device is opened by :meth:`start` and released by :meth:`stop`.
- ``"auto"`` (default): ``"stream"`` for a network source in a time-stamping form (an ``rtsp://`` or
  ``rtsps://`` URL, or a URL to a Matroska/WebM stream: ``….mkv``, ``….webm``), ``"host"`` otherwise
  (MJPEG URLs, devices, files). FFmpeg gives no reliable sign whether a stream's stamps are its own
  (``CAP_PROP_PTS`` is unset on some connections of the same Matroska stream), so the form decides.

**Dropped frames** are detected from the time-stamp gaps within a recording: a gap longer than
(1 + ``gap_tolerance``) nominal frame periods means ``round(gap / period) − 1`` frames the device did not
deliver (``stats.dropped``, with the index after which they are missing). Indices count delivered frames
(``Frame.index``; with stream stamps, every frame grabbed on the connection), so a consumer sees both kinds
of loss as index or time gaps, never as a silent shift.

:meth:`~OpenCVCamera.stop` ends the recording (at most one ``grab()`` later); :meth:`~OpenCVCamera.frames`
yields the queued frames, waiting for new ones while recording, and ends when the camera is stopped and the
queue is empty. Errors of the grabbing thread (device unplugged) end the stream and are raised by
:meth:`frames` as :class:`CameraDeviceError`.
"""

from __future__ import annotations

import collections
import math
import queue
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import cv2
import numpy as np

if TYPE_CHECKING:
    from cv2.typing import MatLike

from drivers.camera.base import ClockMapping, Frame, FrameGap
from drivers.roles import Camera

__all__ = ["TIMESTAMPS", "CameraDeviceError", "Capture", "CaptureStats", "OpenCVCamera", "clock_mapping_of",
           "open_capture", "parse_source", "stamps_itself"]

TIMESTAMPS = ("auto", "stream", "host")
STAMPED_SCHEMES = ("rtsp", "rtsps")
STAMPED_SUFFIXES = (".mkv", ".webm")
MADE_UP_CHECK = 5  # intervals of a new connection compared with FFmpeg's made-up MJPEG stamps
MADE_UP_PERIOD_S = 0.040  # FFmpeg's default 25 fps for a stream without stamps
# (s of frames) over which the lowest arrival latency maps the camera's clock onto the host's: long enough
# to hold a promptly read frame on a loaded host, short enough for a 200-ppm clock to drift ≤ 4 ms
LAG_WINDOW_S = 20.0
DRAIN_S = 10.0  # (host s) how long frames() waits after stop() for the frames exposed before it
SETTLE_S = 2.0  # (camera s) a kept connection's frames before a recording on it starts: FFmpeg's probing
#                 delivers the first ones in a late burst, whose latencies would map the clock late


def stamps_itself(source: str | int) -> bool:
    """True for a source in a form whose frames carry their camera's time stamps (``"auto"``'s choice)."""
    if not isinstance(source, str) or "://" not in source:
        return False
    scheme, rest = source.split("://", 1)
    path = rest.split("?", 1)[0].split("#", 1)[0].lower()
    return scheme.lower() in STAMPED_SCHEMES or path.endswith(STAMPED_SUFFIXES)


def clock_mapping_of(lags_s: Iterable[float], start_host_s: float | None = None) -> ClockMapping:
    """The clock mapping of a window of arrival latencies (arrival − stamp, s; at least one): its lowest,
    the median's excess over it, and ``start_host_s`` (a recording's start, host s) on the camera's clock."""
    lags = np.fromiter(lags_s, dtype=float)
    if lags.size == 0 or not np.all(np.isfinite(lags)):
        raise ValueError(f"lags_s: {lags.size} values; need at least one, all finite")
    lowest_s = float(lags.min())
    start_camera_s = None if start_host_s is None else float(start_host_s) - lowest_s
    return ClockMapping(lowest_s, float(np.median(lags)) - lowest_s, int(lags.size), start_camera_s)


class Capture(Protocol):
    """What :class:`OpenCVCamera` needs of a capture object (``cv2.VideoCapture`` provides it)."""

    def isOpened(self) -> bool: ...  # noqa: N802 (OpenCV's name)
    def set(self, prop_id: int, value: float) -> bool: ...
    def get(self, prop_id: int) -> float: ...
    def grab(self) -> bool: ...
    def retrieve(self) -> tuple[bool, MatLike | None]: ...
    def release(self) -> None: ...


def open_capture(source: str | int, api: int) -> Capture:
    """``cv2.VideoCapture(source, api)``: the default capture factory."""
    return cv2.VideoCapture(source, api)


class CameraDeviceError(RuntimeError):
    """The device cannot be opened, or stopped delivering frames while recording."""


def parse_source(source: str | int) -> int | str:
    """``"0"`` / ``0`` → device index 0; ``"/dev/video2"``, a URL or a file → that string (rig.toml
    ``cameras.<name>.source``)."""
    if isinstance(source, int) and not isinstance(source, bool):
        if source < 0:
            raise ValueError(f"source={source!r}: a device index must be ≥ 0")
        return source
    text = str(source).strip()
    if not text:
        raise ValueError("source is empty; allowed: a device index (0, 1, …), a device path or a URL")
    return int(text) if text.isdigit() else text


@dataclass
class CaptureStats:
    """What the grabbing thread saw in one recording: frames delivered, device drops (gaps), queue
    overflows (slow reader), repeated stream stamps (``duplicated``: indices delivered with the previous
    frame's stamp), host arrival times (s, diagnostic: first and last, and the largest arrival interval
    ``max_arrival_gap_s``); ``connections``: how many times the source was opened (each a clock origin);
    ``clock``: the camera clock's mapping onto the host's at its first recorded frame (stream stamps)."""

    delivered: int = 0
    dropped: list[FrameGap] = field(default_factory=list)
    overflow: list[int] = field(default_factory=list)  # indices discarded because the queue was full
    duplicated: list[int] = field(default_factory=list)
    first_timestamp_s: float | None = None
    last_timestamp_s: float | None = None
    first_arrival_s: float | None = None
    last_arrival_s: float | None = None
    max_arrival_gap_s: float = 0.0
    connections: int = 0
    error: str | None = None
    clock: ClockMapping | None = None

    @property
    def missing_frames(self) -> int:
        return int(sum(d["missing_frames"] for d in self.dropped))


class OpenCVCamera(Camera):
    """A live camera through ``cv2.VideoCapture`` (see the module docstring).

    ``source``: device index, path or URL. ``fps``, ``width_px``, ``height_px``: requested from the device
    (what it grants is read back). ``queue_frames``: queue bound (frames held in memory; 2 MB each at
    1080p). ``timestamps``: ``"auto"``, ``"stream"`` or ``"host"`` (module docstring);
    ``connect_timeout_s``: how long :meth:`start` waits for a stream-stamped source's first frame.
    ``clock``: host clock in seconds (monotonic). ``capture_factory``: builds the capture object from
    (source, api) — ``cv2.VideoCapture`` by default.

    ``live = True``: frames stream while recording and must be consumed then (the queue is bounded);
    consumers such as ``rig.run.acquire.Acquirer`` read a live source during the recording.
    """

    live = True

    def __init__(self, name: str, source: str | int, *, fps: float = 60.0, width_px: int = 1920,
                 height_px: int = 1080, queue_frames: int = 120, gap_tolerance: float = 0.5,
                 timestamps: str = "auto", connect_timeout_s: float = 30.0,
                 clock: Callable[[], float] = time.monotonic,
                 api: int = cv2.CAP_ANY,
                 capture_factory: Callable[[str | int, int], Capture | None] = open_capture) -> None:
        if not (math.isfinite(fps) and 0 < fps <= 10000):
            raise ValueError(f"fps={fps!r}; allowed: within (0, 10000] Hz")
        if width_px < 16 or height_px < 16:
            raise ValueError(f"width_px={width_px}, height_px={height_px}; allowed: ≥ 16 px each")
        if queue_frames < 1:
            raise ValueError(f"queue_frames={queue_frames!r}; allowed: ≥ 1")
        if not 0.0 < gap_tolerance < 1.0:
            raise ValueError(f"gap_tolerance={gap_tolerance!r}; allowed: within (0, 1) frame periods")
        if not (math.isfinite(connect_timeout_s) and connect_timeout_s > 0):
            raise ValueError(f"connect_timeout_s={connect_timeout_s!r}; allowed: > 0 s")
        if timestamps not in TIMESTAMPS:
            raise ValueError(f"timestamps={timestamps!r}; allowed: {', '.join(map(repr, TIMESTAMPS))}")
        self.name, self.source = str(name), parse_source(source)
        self.fps, self.width_px, self.height_px = float(fps), int(width_px), int(height_px)
        self.gap_tolerance, self._clock, self._api = float(gap_tolerance), clock, api
        self.timestamps, self.connect_timeout_s = timestamps, float(connect_timeout_s)
        self._streaming = threading.Event()  # the connection delivered its first frame
        self._settled = threading.Event()  # … and SETTLE_S of frames: its arrival latencies tell its clock
        self._record_from_s = -math.inf  # host instant of start(): a recording's first exposure
        self.stamping = timestamps if timestamps != "auto" else (
            "stream" if stamps_itself(self.source) else "host")  # the stamping in use
        self._factory = capture_factory
        self._queue: queue.Queue[Frame] = queue.Queue(maxsize=int(queue_frames))
        self._lock = threading.Lock()  # the recording flag and what is queued under it
        self._recording = False  # between start() and stop()
        # the thread's recording window: open from start(); closed by the first frame exposed after stop()
        self._capturing = False
        self._record_until_s = math.inf  # host instant of stop()
        self._drain_deadline_s = math.inf
        self._stop = threading.Event()  # ends the grabbing thread
        self._thread: threading.Thread | None = None
        self.stats = CaptureStats()

    @property
    def streamed(self) -> bool:
        """True for a network stream (a URL such as an IP camera's ``http://…/video.mjpg``): it cannot be
        asked for a frame rate and reports none of its own; its rate shows in its stamps or arrival times."""
        return isinstance(self.source, str) and "://" in self.source

    @property
    def _connected(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def recording(self) -> bool:
        return self._recording and self._connected

    def safe_state(self) -> None:
        """Stop a recording in progress (the runner's make-safe; nothing to do otherwise)."""
        if self.recording:
            self.stop()

    def read_back(self) -> dict[str, Any]:
        return {"recording": self.recording, "delivered": self.stats.delivered, "error": self.stats.error,
                "stamping": self.stamping, "duplicated": len(self.stats.duplicated),
                "connections": self.stats.connections}

    def heartbeat(self, *, wait: bool = False) -> bool:
        return True  # a camera's loss shows in its frames (stats.error), not in a link to probe

    def snapshot(self) -> dict[str, Any]:
        return {"driver": "opencv", "fps": self.fps, "resolution_px": [self.width_px, self.height_px],
                "timestamps": self.timestamps, "stamping": self.stamping}

    def clock_mapping(self) -> ClockMapping | None:
        """The last recording's clock mapping (module docstring); None with host stamps or before a frame."""
        return self.stats.clock

    def start(self) -> None:
        """Begin a recording: open the device (unless a stream-stamped connection is open) and grab."""
        if self.recording:
            raise CameraDeviceError(f"camera {self.name!r} is already recording (call stop first)")
        connections = self.stats.connections
        self.stats = CaptureStats(connections=connections)
        self._record_from_s = -math.inf
        while not self._queue.empty():
            self._queue.get_nowait()
        if self.stamping == "host" or not self.streamed:  # errors raised here, by start()
            cap = self._open()
            with self._lock:
                self._recording = self._capturing = True
                self._record_until_s = math.inf
            self._launch(cap)
            return
        if self._connected:  # a kept connection: once its clock is mapped onto the host's (settled) …
            self.wait_settled()
            self._record_from_s = float(self._clock())  # … the frames exposed from now on
        else:  # a new connection: recorded from its first frame
            with self._lock:
                self._recording = self._capturing = True
                self._record_until_s = math.inf
            self.connect()
        deadline_s = time.monotonic() + self.connect_timeout_s
        while not self._streaming.wait(0.05) and self._connected and time.monotonic() < deadline_s:
            pass
        if not self._streaming.is_set():  # (a stream that ended after its first frame: frames() says so)
            self.close()
            reason = self.stats.error or f"no frame within {self.connect_timeout_s:g} s"
            raise CameraDeviceError(f"camera {self.name!r}: {self.source!r} is not streaming: {reason}")
        with self._lock:
            self._recording = self._capturing = True
            self._record_until_s = math.inf

    def wait_settled(self) -> bool:
        """Wait (at most ``connect_timeout_s``) until a kept connection has streamed :data:`SETTLE_S`; True
        when it has (the station waits for it, so that a first recording starts when asked)."""
        deadline_s = time.monotonic() + self.connect_timeout_s
        while not self._settled.wait(0.05) and self._connected and time.monotonic() < deadline_s:
            pass
        return self._settled.is_set()

    def connect(self) -> None:
        """Open a stream-stamped source now (in the grabbing thread; returns at once) and keep it: its clock
        runs from its first frame. Nothing to do for host stamps or a connection already open."""
        if self.stamping == "stream" and self.streamed and not self._connected:
            self._launch(None)

    def _launch(self, cap: Capture | None) -> None:
        self._stop.clear()
        self._streaming.clear()
        self._settled.clear()
        self._thread = threading.Thread(target=self._grab_loop, args=(cap,), name=f"grab-{self.name}",
                                        daemon=True)
        self._thread.start()

    def _open(self) -> Capture:
        """Open the source and check the granted mode (CameraDeviceError naming the mismatch)."""
        cap = self._factory(self.source, self._api)
        if cap is None or not cap.isOpened():
            raise CameraDeviceError(f"camera {self.name!r}: cannot open device {self.source!r} (not "
                                    "connected, busy in another program, or no permission)")
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.width_px)
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height_px)
        cap.set(cv2.CAP_PROP_FPS, self.fps)
        granted = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        if all(granted) and granted != (self.width_px, self.height_px):
            cap.release()
            raise CameraDeviceError(f"camera {self.name!r}: requested {self.width_px}×{self.height_px} px, "
                                    f"the device gives {granted[0]}×{granted[1]}; configure resolution_px to "
                                    "match")
        granted_fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        if self.streamed:  # a network stream's nominal rate (FFmpeg's MJPEG demuxer: 25) is not the camera's
            granted_fps = 0.0
        if math.isfinite(granted_fps) and granted_fps > 0 and abs(granted_fps - self.fps) > 0.01 * self.fps:
            cap.release()
            raise CameraDeviceError(f"camera {self.name!r}: requested {self.fps:g} fps, the device gives "
                                    f"{granted_fps:g}; configure fps to match")
        self.stats.connections += 1
        return cap

    def _put(self, frame: Frame) -> None:
        while True:
            try:
                self._queue.put_nowait(frame)
                return
            except queue.Full:
                try:
                    old = self._queue.get_nowait()
                    self.stats.overflow.append(old.index)
                except queue.Empty:
                    pass

    def _raw_jpeg(self, cap: Capture) -> bool:
        """Ask a stream-stamped MJPEG source for its packets undecoded (True when granted): a kept
        connection's frames between recordings are then never decoded, and recorded ones are decoded
        straight to grey (``cv2.imdecode``) — what keeps a kept connection cheap."""
        if self.stamping != "stream" or not self.streamed:
            return False
        fourcc = int(cap.get(cv2.CAP_PROP_FOURCC)) & 0xFFFFFFFF
        return fourcc.to_bytes(4, "little") == b"MJPG" and bool(cap.set(cv2.CAP_PROP_FORMAT, -1))

    def _check_made_up(self, intervals_s: list[float]) -> None:
        """CameraDeviceError when a new connection's first intervals are FFmpeg's made-up 25 fps."""
        if abs(self.fps - 1.0 / MADE_UP_PERIOD_S) <= 0.01 * self.fps:
            return  # a 25 fps camera's own stamps look the same
        if all(abs(dt - MADE_UP_PERIOD_S) < 1e-6 for dt in intervals_s):
            raise CameraDeviceError(
                f"camera {self.name!r}: source {self.source!r} carries no time stamps (FFmpeg made up 25 fps "
                f"ones: an MJPEG stream?); set cameras.{self.name}.timestamps = \"host\" to stamp frames on "
                "arrival, or serve a time-stamped stream (Matroska, RTSP)")

    def _grab_loop(self, cap: Capture | None) -> None:
        period = 1.0 / self.fps
        index = 0
        prev_stamp: float | None = None  # the previous frame's stamp on this connection
        prev_recorded: tuple[float, float] | None = None  # (stamp, arrival) of the previous recorded frame
        try:
            if cap is None:
                cap = self._open()
            raw = self._raw_jpeg(cap)
            intervals_s: list[float] = []  # the connection's first ones (made-up stamps?)
            lags_s: collections.deque[float] = collections.deque(  # arrival − stamp
                maxlen=round(LAG_WINDOW_S * self.fps))
            while not self._stop.is_set():
                if not cap.grab():
                    if not self._stop.is_set():
                        self.stats.error = f"device {self.source!r} stopped delivering frames after {index}"
                    break
                arrival_s = float(self._clock())
                self._streaming.set()
                stamp = arrival_s if self.stamping == "host" else float(cap.get(cv2.CAP_PROP_POS_MSEC)) / 1e3
                if stamp >= SETTLE_S:  # (a stream's stamps count from its first frame)
                    self._settled.set()
                if self.stamping == "stream" and prev_stamp is not None and stamp < prev_stamp:
                    self.stats.error = (f"the stream's time stamps went backwards at frame {index}: "
                                        f"{stamp:.6f} s after {prev_stamp:.6f} s")
                    break
                repeated = prev_stamp is not None and stamp == prev_stamp
                if self.stamping == "stream" and prev_stamp is not None and len(intervals_s) < MADE_UP_CHECK:
                    intervals_s.append(stamp - prev_stamp)
                    if len(intervals_s) == MADE_UP_CHECK:
                        self._check_made_up(intervals_s)
                prev_stamp = stamp
                lags_s.append(arrival_s - stamp)
                exposed_s = stamp + min(lags_s)  # on the host's clock, late by the lowest latency
                with self._lock:  # a kept connection records the frames exposed between start() and stop()
                    if self._capturing and exposed_s >= self._record_until_s:
                        self._capturing = False
                    recording = self._capturing and exposed_s >= self._record_from_s
                if not recording:
                    prev_recorded = None
                    if self.stamping == "host":
                        break  # a host-stamped connection is not kept between recordings
                    index += 1
                    continue
                ok, img = cap.retrieve()
                if ok and img is not None and raw:  # the frame's JPEG, decoded straight to grey
                    img = cv2.imdecode(np.asarray(img, dtype=np.uint8).ravel(), cv2.IMREAD_GRAYSCALE)
                if not ok or img is None:
                    self.stats.error = f"frame {index} could not be decoded"
                    break
                gray = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
                if self.stamping == "stream" and self.stats.clock is None:  # the mapping that dated start()
                    self.stats.clock = clock_mapping_of(
                        lags_s, self._record_from_s if math.isfinite(self._record_from_s) else None)
                self._account(index, stamp, arrival_s, prev_recorded, repeated=repeated, period=period)
                prev_recorded = (stamp, arrival_s)
                with self._lock:
                    if self._capturing:
                        self._put(Frame(index=index, timestamp_s=stamp,
                                        image=np.ascontiguousarray(gray, dtype=np.uint8)))
                        self.stats.delivered += 1
                index += 1
        except CameraDeviceError as exc:
            self.stats.error = str(exc).removeprefix(f"camera {self.name!r}: ")
        except Exception as exc:  # a device error ends the stream; frames() reports it
            self.stats.error = f"{type(exc).__name__}: {exc}"
        finally:
            if cap is not None:
                cap.release()

    def _account(self, index: int, stamp: float, arrival_s: float, prev: tuple[float, float] | None, *,
                 repeated: bool, period: float) -> None:
        """Statistics of a recorded frame: gaps (drops), repeats (duplicates), arrival times."""
        stats = self.stats
        if repeated and prev is not None:
            stats.duplicated.append(index)
        if prev is not None and stamp - prev[0] > (1.0 + self.gap_tolerance) * period:
            stats.dropped.append({"after_index": index - 1, "gap_s": stamp - prev[0],
                                  "missing_frames": max(1, round((stamp - prev[0]) / period) - 1)})
        if prev is not None:
            stats.max_arrival_gap_s = max(stats.max_arrival_gap_s, arrival_s - prev[1])
        if stats.first_timestamp_s is None:
            stats.first_timestamp_s, stats.first_arrival_s = stamp, arrival_s
        stats.last_timestamp_s, stats.last_arrival_s = stamp, arrival_s

    def stop(self) -> None:
        """End the recording. A host-stamped device is released (its thread joined, at most one ``grab()``
        later); a stream-stamped connection is kept (:meth:`close` ends it)."""
        if self._thread is None:
            raise CameraDeviceError(f"camera {self.name!r} is not recording (call start first)")
        with self._lock:
            self._recording = False
            if self.stamping == "stream":
                self._record_until_s = float(self._clock())
                self._drain_deadline_s = time.monotonic() + DRAIN_S
            else:
                self._capturing = False
        if self.stamping != "stream":
            self._join()

    def close(self) -> None:
        """End the recording and the connection (its thread joined; the device released)."""
        with self._lock:
            self._recording = self._capturing = False
        if self._thread is not None:
            self._join()

    def _join(self) -> None:
        assert self._thread is not None
        self._stop.set()
        self._thread.join(timeout=max(2.0, 10.0 / self.fps))
        if self._thread.is_alive():
            raise CameraDeviceError(f"camera {self.name!r}: the grabbing thread did not stop within 2 s "
                                    "(device hung)")

    def frames(self) -> Iterator[Frame]:
        """Queued frames in order, waiting while recording; ends when stopped and drained."""
        if self._thread is None:
            raise CameraDeviceError(f"camera {self.name!r} has not recorded anything (call start first)")
        while True:
            try:
                yield self._queue.get(timeout=0.05)
                continue
            except queue.Empty:
                pass
            if not self._recording and time.monotonic() > self._drain_deadline_s:
                with self._lock:
                    self._capturing = False  # the frames exposed before stop() did not all come
            if (not self._capturing or not self._connected) and self._queue.empty():
                break
        if self.stats.error and (self._recording or self.stamping == "stream"):
            raise CameraDeviceError(f"camera {self.name!r}: {self.stats.error}")
