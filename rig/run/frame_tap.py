"""The latest camera frame per camera, with its markers, for a live view (the dashboard, ``rig preview``).

:data:`FRAMES` is the process's tap. The acquisition offers every reduced frame
(:meth:`FrameTap.offer`); while nobody listens (``enabled`` False) that is one attribute test. When enabled
it keeps a *reference* to at most one frame per camera per ``min_interval_s`` of wall time (no copy and no
encoding in the acquisition's thread); the image is downscaled, annotated and JPEG-encoded only when a
client asks for it (:meth:`FrameTap.jpeg`), once per frame.

With ``keep_markers`` also set, every offered frame's markers (not its image) are appended to a bounded
queue (:meth:`FrameTap.drain_markers`; the oldest dropped when nobody drains it): what the dashboard's live
stereo estimate reads (:mod:`rig.dashboard.live_stereo`), in its own thread.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

__all__ = ["FRAMES", "FrameTap", "MarkerFrame", "TappedFrame"]


@dataclass(frozen=True)
class TappedFrame:
    """One offered frame: ``seq`` (1, 2, … per camera), the camera's ``frame_index``, ``image`` (2-D
    uint8), the markers' centres ``uv_px`` (n × 2) and their ``ids`` (the track numbers, n)."""

    camera: str
    seq: int
    frame_index: int
    image: np.ndarray
    uv_px: np.ndarray
    ids: np.ndarray


@dataclass(frozen=True)
class MarkerFrame:
    """One frame's markers: the recording's ``segment``, the camera's ``frame_index`` and ``timestamp_s``
    (its own clock), the centres ``uv_px`` (n × 2) and track ``ids`` (n)."""

    camera: str
    segment: str
    frame_index: int
    timestamp_s: float
    uv_px: np.ndarray
    ids: np.ndarray


class FrameTap:
    """Latest frame per camera (thread-safe); see the module docstring."""

    def __init__(self, min_interval_s: float = 0.1, max_marker_frames: int = 20_000) -> None:
        self.enabled = False
        self.keep_markers = False
        self.min_interval_s = float(min_interval_s)
        self._markers: deque[MarkerFrame] = deque(maxlen=max_marker_frames)
        self._lock = threading.Lock()
        self._latest: dict[str, TappedFrame] = {}
        self._offered_at: dict[str, float] = {}
        self._jpeg: dict[str, tuple[int, int, bytes]] = {}  # camera → (seq, max_width_px, bytes)

    def offer(self, camera: str, frame_index: int, image: np.ndarray, uv_px: np.ndarray,
              ids: np.ndarray, *, timestamp_s: float = float("nan"), segment: str = "") -> None:
        """Keep this frame as ``camera``'s latest unless one was kept less than ``min_interval_s`` ago;
        with ``keep_markers``, queue its markers."""
        if not self.enabled:
            return
        now = time.monotonic()
        with self._lock:
            if self.keep_markers:
                self._markers.append(MarkerFrame(camera, segment, int(frame_index), float(timestamp_s),
                                                 np.asarray(uv_px, float).reshape(-1, 2), np.asarray(ids)))
            if now - self._offered_at.get(camera, -1e9) < self.min_interval_s:
                return
            self._offered_at[camera] = now
            seq = self._latest[camera].seq + 1 if camera in self._latest else 1
            self._latest[camera] = TappedFrame(camera, seq, int(frame_index), image,
                                               np.asarray(uv_px, float).reshape(-1, 2), np.asarray(ids))

    def latest(self, camera: str) -> TappedFrame | None:
        with self._lock:
            return self._latest.get(camera)

    def seqs(self) -> dict[str, int]:
        """``{camera: seq}`` of the latest frames (what a client compares to know a new frame is there)."""
        with self._lock:
            return {name: f.seq for name, f in self._latest.items()}

    def jpeg(self, camera: str, max_width_px: int = 480) -> bytes | None:
        """The latest frame of ``camera`` downscaled to at most ``max_width_px`` wide, markers circled and
        numbered, as JPEG bytes (cached per frame); None when there is none yet."""
        frame = self.latest(camera)
        if frame is None:
            return None
        with self._lock:
            cached = self._jpeg.get(camera)
            if cached is not None and cached[:2] == (frame.seq, max_width_px):
                return cached[2]
        data = annotate_jpeg(frame.image, frame.uv_px, frame.ids, max_width_px)
        with self._lock:
            self._jpeg[camera] = (frame.seq, max_width_px, data)
        return data

    def drain_markers(self) -> list[MarkerFrame]:
        """The markers queued since the last call, oldest first."""
        with self._lock:
            drained = list(self._markers)
            self._markers.clear()
        return drained

    def reset(self) -> None:
        with self._lock:
            self._markers.clear()
            self._latest.clear()
            self._offered_at.clear()
            self._jpeg.clear()


def annotate_jpeg(image: np.ndarray, uv_px: np.ndarray, ids: np.ndarray, max_width_px: int) -> bytes:
    """Downscale ``image`` (2-D uint8) to ≤ ``max_width_px`` wide, draw each marker (circle, id), JPEG."""
    import cv2

    scale = min(1.0, max_width_px / max(1, image.shape[1]))
    small = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA) if scale < 1 else image
    colour = cv2.cvtColor(small, cv2.COLOR_GRAY2BGR)
    for (u, v), marker_id in zip(uv_px, ids, strict=False):
        if not (np.isfinite(u) and np.isfinite(v)):
            continue
        centre = (round(float(u) * scale), round(float(v) * scale))
        cv2.circle(colour, centre, 6, (0, 200, 255), 1, cv2.LINE_AA)
        cv2.putText(colour, str(int(marker_id)), (centre[0] + 7, centre[1] - 5), cv2.FONT_HERSHEY_SIMPLEX,
                    0.35, (0, 255, 0), 1, cv2.LINE_AA)
    ok, buf = cv2.imencode(".jpg", colour, [cv2.IMWRITE_JPEG_QUALITY, 80])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()


FRAMES = FrameTap()
