"""Live capture from an OpenCV video device (USB/V4L2 camera, or any source ``cv2.VideoCapture`` opens).

:class:`OpenCVCamera` implements ``FrameSource``. :meth:`~OpenCVCamera.start` opens the device and starts
**one grabbing thread per camera**: it calls ``grab()`` back to back (the device's own pace), stamps each
frame with the **host clock** right after ``grab()`` returns (``time.monotonic`` by default, injectable),
decodes it to grey and puts it in a **bounded queue**. The thread never blocks on the queue: when the
consumer falls behind, the oldest queued frame is discarded and counted (``stats.overflow``), so the device
buffer never overruns silently.

**Dropped frames** are detected from the time-stamp gaps: a gap longer than (1 + ``gap_tolerance``) nominal
frame periods means ``round(gap / period) − 1`` frames the device did not deliver (``stats.dropped``, with
the index after which they are missing). Indices count delivered frames (``Frame.index``), so a consumer
sees both kinds of loss as index or time gaps, never as a silent shift.

:meth:`~OpenCVCamera.stop` ends the thread (at most one ``grab()`` later), joins it and releases the device;
:meth:`~OpenCVCamera.frames` yields the queued frames, waiting for new ones while recording, and ends when
the camera is stopped and the queue is empty. Errors of the grabbing thread (device unplugged) end the
stream and are raised by :meth:`frames` as :class:`CameraDeviceError`.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import cv2
import numpy as np

if TYPE_CHECKING:
    from cv2.typing import MatLike

from drivers.camera.base import Frame, FrameGap
from drivers.roles import Camera

__all__ = ["CameraDeviceError", "Capture", "CaptureStats", "OpenCVCamera", "open_capture", "parse_source"]


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
    """What the grabbing thread saw: frames delivered, device drops (gaps), queue overflows (slow reader)."""

    delivered: int = 0
    dropped: list[FrameGap] = field(default_factory=list)
    overflow: list[int] = field(default_factory=list)  # indices discarded because the queue was full
    first_timestamp_s: float | None = None
    last_timestamp_s: float | None = None
    error: str | None = None

    @property
    def missing_frames(self) -> int:
        return int(sum(d["missing_frames"] for d in self.dropped))


class OpenCVCamera(Camera):
    """A live camera through ``cv2.VideoCapture`` (see the module docstring).

    ``source``: device index, path or URL. ``fps``, ``width_px``, ``height_px``: requested from the device
    (what it grants is read back). ``queue_frames``: queue bound (frames held in memory; 2 MB each at
    1080p). ``clock``: host clock in seconds (monotonic). ``capture_factory``: builds the capture object
    from (source, api) — ``cv2.VideoCapture`` by default.

    ``live = True``: frames stream while recording and must be consumed then (the queue is bounded);
    consumers such as ``rig.run.acquire.Acquirer`` read a live source during the recording.
    """

    live = True

    def __init__(self, name: str, source: str | int, *, fps: float = 60.0, width_px: int = 1920,
                 height_px: int = 1080, queue_frames: int = 120, gap_tolerance: float = 0.5,
                 clock: Callable[[], float] = time.monotonic, api: int = cv2.CAP_ANY,
                 capture_factory: Callable[[str | int, int], Capture | None] = open_capture) -> None:
        if not (math.isfinite(fps) and 0 < fps <= 10000):
            raise ValueError(f"fps={fps!r}; allowed: within (0, 10000] Hz")
        if width_px < 16 or height_px < 16:
            raise ValueError(f"width_px={width_px}, height_px={height_px}; allowed: ≥ 16 px each")
        if queue_frames < 1:
            raise ValueError(f"queue_frames={queue_frames!r}; allowed: ≥ 1")
        if not 0.0 < gap_tolerance < 1.0:
            raise ValueError(f"gap_tolerance={gap_tolerance!r}; allowed: within (0, 1) frame periods")
        self.name, self.source = str(name), parse_source(source)
        self.fps, self.width_px, self.height_px = float(fps), int(width_px), int(height_px)
        self.gap_tolerance, self._clock, self._api = float(gap_tolerance), clock, api
        self._factory = capture_factory
        self._queue: queue.Queue[Frame] = queue.Queue(maxsize=int(queue_frames))
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.stats = CaptureStats()

    @property
    def streamed(self) -> bool:
        """True for a network stream (a URL such as an IP camera's ``http://…/video.mjpg``): it cannot be
        asked for a frame rate and reports none of its own; its rate shows in the arrival times."""
        return isinstance(self.source, str) and "://" in self.source

    @property
    def recording(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def safe_state(self) -> None:
        """Stop a recording in progress (the runner's make-safe; nothing to do otherwise)."""
        if self.recording and not self._stop.is_set():
            self.stop()

    def read_back(self) -> dict[str, Any]:
        return {"recording": self.recording, "delivered": self.stats.delivered, "error": self.stats.error}

    def heartbeat(self, *, wait: bool = False) -> bool:
        return True  # a camera's loss shows in its frames (stats.error), not in a link to probe

    def snapshot(self) -> dict[str, Any]:
        return {"driver": "opencv", "fps": self.fps, "resolution_px": [self.width_px, self.height_px]}

    def start(self) -> None:
        """Open the device, apply the requested mode, start the grabbing thread."""
        if self.recording:
            raise CameraDeviceError(f"camera {self.name!r} is already recording (call stop first)")
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
        self.stats = CaptureStats()
        self._stop.clear()
        while not self._queue.empty():
            self._queue.get_nowait()
        self._thread = threading.Thread(target=self._grab_loop, args=(cap,), name=f"grab-{self.name}",
                                        daemon=True)
        self._thread.start()

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

    def _grab_loop(self, cap: Capture) -> None:
        period = 1.0 / self.fps
        index, prev = 0, None
        try:
            while not self._stop.is_set():
                if not cap.grab():
                    if not self._stop.is_set():
                        self.stats.error = f"device {self.source!r} stopped delivering frames after {index}"
                    break
                t = float(self._clock())
                ok, img = cap.retrieve()
                if not ok or img is None:
                    self.stats.error = f"frame {index} could not be decoded"
                    break
                gray = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
                if prev is not None and t - prev > (1.0 + self.gap_tolerance) * period:
                    self.stats.dropped.append({"after_index": index - 1, "gap_s": t - prev,
                                               "missing_frames": max(1, round((t - prev) / period) - 1)})
                if self.stats.first_timestamp_s is None:
                    self.stats.first_timestamp_s = t
                self.stats.last_timestamp_s, prev = t, t
                self._put(Frame(index=index, timestamp_s=t, image=np.ascontiguousarray(gray, dtype=np.uint8)))
                index += 1
                self.stats.delivered = index
        except Exception as exc:  # a device error ends the stream; frames() reports it
            self.stats.error = f"{type(exc).__name__}: {exc}"
        finally:
            cap.release()

    def stop(self) -> None:
        """Stop grabbing (after at most one more frame), join the thread, release the device."""
        if self._thread is None:
            raise CameraDeviceError(f"camera {self.name!r} is not recording (call start first)")
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
            if not self._thread.is_alive() and self._queue.empty():
                break
        if self.stats.error and not self._stop.is_set():
            raise CameraDeviceError(f"camera {self.name!r}: {self.stats.error}")
