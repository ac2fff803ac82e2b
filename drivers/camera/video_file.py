"""A recorded video file as a camera device: frames by decode index with the container's time stamps.

Consumer cameras record to files with no common clock, and their frame times cannot be taken for granted
(metrology notes §3: duplicated frames and variable frame rates shifted cameras by whole frames in other
tools). :class:`VideoFile` therefore

- decodes frames **in order, by index** (never by seeking to a time), and gives each frame the container's
  presentation time stamp (``CAP_PROP_POS_MSEC``, converted to seconds);
- detects **duplicated frames**: a repeated presentation time stamp, or an image identical or nearly
  identical to the previous one (mean absolute difference on a 4×-subsampled image below
  ``duplicate_ratio`` × the running median of that difference — relative, because compression smooths the
  sensor noise by different amounts in different codecs);
- detects **dropped frames**: a gap between consecutive time stamps longer than (1 + ``gap_tolerance``)
  frame periods (``round(gap / period) − 1`` frames missing);
- reports all of them in a :class:`FrameTimeReport` (``.report``), and never shifts a time silently. A
  duplicate whose time stamp advanced (a constant-frame-rate container) is ambiguous: either the camera
  repeated the last image in place of a frame it missed (``duplicate_policy="replace"``, the default: later
  time stamps are right) or it inserted the copy (``"insert"``: every later time stamp is one period late
  and is corrected). The policy used and the corrections made are in the report;
- raises :class:`VideoTruncatedError` (with the report and the number of frames read; the frames were
  already delivered) when decoding stops before the frame count the container declares, and
  :class:`VideoOpenError` when the file cannot be opened at all.

Images are 2-D uint8: the decoder's luma plane when it delivers one (verified on the first frame against
OpenCV's colour → grey conversion; about twice as fast), else the BGR image converted to grey.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from drivers.camera.base import Frame

__all__ = ["DUPLICATE_POLICIES", "FrameTimeReport", "VideoFile", "VideoFileError", "VideoOpenError",
           "VideoTruncatedError", "find_gaps"]

DUPLICATE_POLICIES = ("replace", "insert")
_SUB = 4  # subsampling of the duplicate test


class VideoFileError(RuntimeError):
    """A video file cannot be read as a camera record."""


class VideoOpenError(VideoFileError):
    """The file does not exist or no decoder can open it."""


class VideoTruncatedError(VideoFileError):
    """Decoding stopped before the declared end; ``frames_read`` frames were delivered (see ``report``)."""

    def __init__(self, message: str, report: FrameTimeReport) -> None:
        super().__init__(message)
        self.report = report
        self.frames_read = report.frames_read


@dataclass
class FrameTimeReport:
    """What reading a video file found about its frames (times in s, on the file's clock).

    ``duplicated``: frames repeating the previous image and/or its time stamp, each as
    ``{"index", "pts_s", "pts_repeated", "image_repeated", "difference_dn"}``; ``dropped``: gaps as
    ``{"after_index", "gap_s", "missing_frames"}``; ``corrections``: ``{"from_index", "shift_s"}`` applied
    under ``duplicate_policy="insert"``; ``truncated``: decoding stopped before ``frames_declared``.
    """

    path: str
    frames_read: int = 0
    frames_declared: int | None = None
    fps_nominal: float | None = None
    frame_period_s: float | None = None
    width_px: int = 0
    height_px: int = 0
    duration_s: float = 0.0
    duplicate_policy: str = "replace"
    luma_plane: bool = False
    duplicated: list[dict[str, Any]] = field(default_factory=list)
    dropped: list[dict[str, Any]] = field(default_factory=list)
    corrections: list[dict[str, Any]] = field(default_factory=list)
    non_monotonic: list[int] = field(default_factory=list)
    truncated: bool = False
    error: str | None = None

    @property
    def duplicate_indices(self) -> list[int]:
        return [int(d["index"]) for d in self.duplicated]

    @property
    def missing_frames(self) -> int:
        return int(sum(d["missing_frames"] for d in self.dropped))

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["missing_frames"] = self.missing_frames
        return out

    def summary(self) -> str:
        """One line for a console or a report."""
        parts = [f"{Path(self.path).name}: {self.frames_read} frames, {self.duration_s:.3f} s"]
        if self.duplicated:
            parts.append(f"{len(self.duplicated)} duplicated (indices {self.duplicate_indices[:8]}"
                         f"{' …' if len(self.duplicated) > 8 else ''})")
        if self.dropped:
            parts.append(f"{self.missing_frames} dropped in {len(self.dropped)} gap(s) after indices "
                         f"{[d['after_index'] for d in self.dropped[:8]]}")
        if self.corrections:
            parts.append(f"time stamps corrected after {len(self.corrections)} inserted duplicate(s)")
        if self.non_monotonic:
            parts.append(f"{len(self.non_monotonic)} non-increasing time stamps")
        if self.truncated:
            parts.append(f"TRUNCATED ({self.error})")
        return "; ".join(parts)


_quiet_lock = threading.Lock()
_quiet_state = {"readers": 0, "level": 0}


def _quiet(step: int) -> None:
    """OpenCV's log level is process-wide: lowered while any file is being read, restored after the last."""
    with _quiet_lock:
        if step > 0 and _quiet_state["readers"] == 0:
            _quiet_state["level"] = cv2.utils.logging.getLogLevel()
            cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
        _quiet_state["readers"] += step
        if step < 0 and _quiet_state["readers"] == 0:
            cv2.utils.logging.setLogLevel(_quiet_state["level"])


def find_gaps(timestamps_s: np.ndarray, period_s: float, gap_tolerance: float = 0.5) -> list[dict[str, Any]]:
    """Gaps longer than (1 + gap_tolerance) periods in increasing time stamps: after which index, how long,
    how many frames are missing (``round(gap/period) − 1``, at least 1)."""
    t = np.asarray(timestamps_s, dtype=float)
    if not (period_s > 0 and math.isfinite(period_s)):
        raise ValueError(f"period_s must be a positive finite number of seconds, got {period_s!r}")
    if not 0.0 < gap_tolerance < 1.0:
        raise ValueError(f"gap_tolerance must be within (0, 1) frame periods, got {gap_tolerance!r}")
    gaps = np.diff(t)
    out = []
    for i in np.nonzero(gaps > (1.0 + gap_tolerance) * period_s)[0]:
        missing = max(1, round(gaps[i] / period_s) - 1)
        out.append({"after_index": int(i), "gap_s": float(gaps[i]), "missing_frames": missing})
    return out


class VideoFile:
    """A video file as a ``FrameSource`` (see the module docstring).

    ``name``: camera name (default: the file stem). ``fps``: nominal frame rate if the container's is wrong
    or missing (Hz). ``duplicate_ratio``: an image is a duplicate when its difference to the previous one is
    below this fraction of the running median difference (0 < r < 1). ``gap_tolerance``: a time-stamp gap
    longer than (1 + tolerance) periods is a drop. ``duplicate_policy``: ``"replace"`` or ``"insert"``.
    """

    def __init__(self, path: str | Path, *, name: str | None = None, fps: float | None = None,
                 duplicate_ratio: float = 0.3, gap_tolerance: float = 0.5,
                 duplicate_policy: str = "replace", luma: bool = True) -> None:
        self.path = Path(path)
        self.name = str(name) if name is not None else self.path.stem
        if duplicate_policy not in DUPLICATE_POLICIES:
            raise ValueError(f"duplicate_policy={duplicate_policy!r}; allowed: {DUPLICATE_POLICIES}")
        if not 0.0 < duplicate_ratio < 1.0:
            raise ValueError(f"duplicate_ratio={duplicate_ratio!r}; allowed: within (0, 1)")
        if not 0.0 < gap_tolerance < 1.0:
            raise ValueError(f"gap_tolerance={gap_tolerance!r}; allowed: within (0, 1) frame periods")
        if fps is not None and not (math.isfinite(fps) and 0 < fps <= 10000):
            raise ValueError(f"fps={fps!r}; allowed: a frame rate within (0, 10000] Hz")
        self.duplicate_ratio, self.gap_tolerance = float(duplicate_ratio), float(gap_tolerance)
        self.duplicate_policy, self.luma = duplicate_policy, bool(luma)
        cap = self._open()
        try:
            self.width_px = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
            self.height_px = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
            container_fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
            declared = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        finally:
            cap.release()
        if fps is None and not (math.isfinite(container_fps) and 0 < container_fps <= 10000):
            raise VideoOpenError(f"{self.path}: the container states no usable frame rate "
                                 f"({container_fps!r}); pass fps= (the camera's nominal rate, Hz)")
        self.fps = float(fps) if fps is not None else container_fps
        self.frames_declared = declared if declared > 0 else None
        self.report = FrameTimeReport(str(self.path), frames_declared=self.frames_declared,
                                      fps_nominal=self.fps, frame_period_s=1.0 / self.fps,
                                      width_px=self.width_px, height_px=self.height_px,
                                      duplicate_policy=duplicate_policy)
        self.duplicate_indices: set[int] = set()
        self._first_pts_s = 0.0

    def _open(self) -> cv2.VideoCapture:
        if not self.path.is_file():
            raise VideoOpenError(f"{self.path}: no such video file")
        if self.path.stat().st_size == 0:
            raise VideoOpenError(f"{self.path}: the file is empty (0 bytes)")
        cap = cv2.VideoCapture(str(self.path), cv2.CAP_FFMPEG)
        if not cap.isOpened():
            cap.release()
            raise VideoOpenError(
                f"{self.path}: no decoder can open it — a corrupt file, or a recording cut short before its "
                "container index was written (MP4/MOV written by a camera that lost power); no frames "
                "could be read")
        return cap

    # FrameSource: a file is already recorded
    def start(self) -> None:
        """Nothing to start: the file was recorded by the camera (kept for the ``FrameSource`` protocol)."""

    def stop(self) -> None:
        """Nothing to stop (``FrameSource`` protocol)."""

    def _gray(self, cap: cv2.VideoCapture) -> np.ndarray | None:
        ok, img = cap.retrieve()
        if not ok or img is None:
            return None
        if img.ndim == 2 and img.shape == (self.height_px, self.width_px):
            return img
        if img.ndim == 3:
            return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        return None

    def _luma_capture(self) -> tuple[cv2.VideoCapture, bool]:
        """A capture delivering the luma plane if that plane is verified equal (up to a linear range change)
        to OpenCV's grey conversion of the first frame; else one delivering BGR."""
        if self.luma:
            probe_bgr, probe_raw = self._open(), self._open()
            try:
                probe_raw.set(cv2.CAP_PROP_CONVERT_RGB, 0)
                ok_a, bgr = probe_bgr.read()
                ok_b, raw = probe_raw.read()
            finally:
                probe_bgr.release()
                probe_raw.release()
            if (ok_a and ok_b and raw is not None and raw.ndim == 2 and raw.dtype == np.uint8
                    and raw.shape == (self.height_px, self.width_px) and bgr is not None and bgr.ndim == 3):
                g = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)[::_SUB, ::_SUB].ravel().astype(float)
                y = raw[::_SUB, ::_SUB].ravel().astype(float)
                if g.std() > 0 and y.std() > 0 and np.corrcoef(g, y)[0, 1] > 0.995:
                    cap = self._open()
                    cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
                    return cap, True
        return self._open(), False

    def frames(self) -> Iterator[Frame]:
        """Every decodable frame in order (see the module docstring); ``.report`` is filled as they go."""
        rep = self.report = FrameTimeReport(
            str(self.path), frames_declared=self.frames_declared, fps_nominal=self.fps,
            frame_period_s=1.0 / self.fps, width_px=self.width_px, height_px=self.height_px,
            duplicate_policy=self.duplicate_policy)
        self.duplicate_indices = set()
        period = 1.0 / self.fps
        _quiet(+1)  # the luma plane makes OpenCV warn once a frame
        try:
            cap, rep.luma_plane = self._luma_capture()
            yield from self._decode(cap, rep, period)
        finally:
            _quiet(-1)
        # a container's frame count may be an estimate (duration × rate, e.g. Matroska) that dropped frames
        # undercut: the file is truncated when its frames also end early in time
        end_expected_s = self._first_pts_s + (self.frames_declared or 0) * period
        if (self.frames_declared is not None and rep.frames_read < self.frames_declared
                and rep.duration_s < end_expected_s - 1.5 * period):
            rep.truncated = True
            rep.error = (f"decoding stopped after {rep.frames_read} of the {self.frames_declared} frames the "
                         "container declares (truncated or corrupt file)")
            raise VideoTruncatedError(f"{self.path}: {rep.error}; the {rep.frames_read} frames read are kept",
                                      rep)

    def _decode(self, cap: cv2.VideoCapture, rep: FrameTimeReport, period: float) -> Iterator[Frame]:
        prev_small: np.ndarray | None = None
        prev_pts = -math.inf
        recent: deque[float] = deque(maxlen=31)
        shift_s = 0.0
        index = 0
        self._first_pts_s = 0.0
        try:
            while cap.grab():
                pts = float(cap.get(cv2.CAP_PROP_POS_MSEC)) / 1000.0
                img = self._gray(cap)
                if img is None:
                    rep.error = f"frame {index} could not be decoded"
                    break
                if index == 0:
                    self._first_pts_s = pts
                small = img[::_SUB, ::_SUB].astype(np.int16)
                diff = float(np.mean(np.abs(small - prev_small))) if prev_small is not None else math.inf
                repeated = pts <= prev_pts + 1e-6 * period
                if repeated and pts < prev_pts - 1e-6 * period:
                    rep.non_monotonic.append(index)
                    repeated = False
                similar = (prev_small is not None and len(recent) >= 3
                           and diff < self.duplicate_ratio * float(np.median(recent)))
                if similar or (repeated and prev_small is not None):
                    self.duplicate_indices.add(index)
                    rep.duplicated.append({"index": index, "pts_s": pts, "pts_repeated": bool(repeated),
                                           "image_repeated": bool(similar), "difference_dn": diff})
                    if not repeated and self.duplicate_policy == "insert":
                        shift_s -= period
                        rep.corrections.append({"from_index": index + 1, "shift_s": shift_s})
                    stamp = pts + shift_s if not repeated else prev_pts
                else:
                    if prev_small is not None and not repeated:
                        recent.append(diff)
                    if prev_pts > -math.inf and not repeated:
                        gap = pts - prev_pts
                        if gap > (1.0 + self.gap_tolerance) * period:
                            rep.dropped.append({"after_index": index - 1, "gap_s": gap,
                                                "missing_frames": max(1, round(gap / period) - 1)})
                    stamp = pts + shift_s
                prev_small, prev_pts = small, max(prev_pts, pts)
                rep.frames_read = index + 1
                rep.duration_s = max(rep.duration_s, pts + period)
                yield Frame(index=index, timestamp_s=stamp, image=img)
                index += 1
        finally:
            cap.release()
