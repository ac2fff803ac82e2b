"""Video file → marker observations (one row per marker per frame), with the file's frame-time report.

Frames are decoded in order by :class:`drivers.camera.video_file.VideoFile` (container time stamps,
duplicated and dropped frames reported, never shifted silently). Each frame is reduced at once to marker
rows and its image dropped, by :class:`rig.analysis.frame_reduction.MarkerReducer` (the reduction the rig's
own
recordings use): the first frame is searched whole (:func:`rig.stereo.detect_markers`), later frames only
in a window around each marker's last position (:func:`rig.stereo.track_markers`), with a whole-frame
search again when a marker is lost and every ``redetect_every`` frames (markers entering the view).
``mode="detect"`` searches every frame whole.

Duplicated frames carry no new instant: their rows are kept with ``duplicate = True`` so that what was
seen stays inspectable, and the analysis leaves them out. Columns (contracts.md, run-folder observations):
``frame_index``, ``timestamp_s`` (the file's clock), ``u_px``, ``v_px``, ``area_px``, ``roundness``,
``contrast``, ``flags``, ``duplicate``. Time spent decoding and extracting is measured (``timings_s``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

from drivers.camera.video_file import FrameTimeReport, VideoFile, VideoTruncatedError
from rig.analysis.frame_reduction import MarkerReducer, ReduceOptions
from rig.stereo import MARKER_DTYPE

__all__ = ["ExtractOptions", "VideoObservations", "extract_video", "window_note"]

_FIELDS = ("u_px", "v_px", "area_px", "roundness", "contrast")


@dataclass(frozen=True)
class ExtractOptions:
    """How frames become marker rows.

    ``mode``: "track" (search whole once, then near the last positions) or "detect" (whole frame every time).
    ``window_px``: tracking window side (px): marker diameter + 8 px + twice the largest motion per frame.
    ``redetect_every``: frames between whole-frame searches in "track" mode. ``detect``: keyword options of
    :func:`rig.stereo.detect_markers` (polarity, min_area_px, min_contrast, …; the tracker gets only those
    it takes, see :class:`rig.analysis.frame_reduction.ReduceOptions`). ``duplicate_policy``, ``fps`` and
    ``decoder_threads`` (None: OpenCV's default; ``rig measure`` shares the cores among its two videos) go to
    :class:`VideoFile`.
    """

    mode: str = "track"
    window_px: int = 41
    redetect_every: int = 60
    detect: dict[str, Any] = field(default_factory=dict)
    duplicate_policy: str = "replace"
    fps: float | None = None
    decoder_threads: int | None = None
    # only frames with start_s ≤ time stamp ≤ stop_s (the file's clock, s; None: from the start, to the end)
    # are reduced; decoding starts by a verified seek shortly before start_s (VideoFile.frames), stops after
    # stop_s
    start_s: float | None = None
    stop_s: float | None = None

    def __post_init__(self) -> None:
        if self.start_s is not None and self.stop_s is not None and not self.start_s < self.stop_s:
            raise ValueError(f"start_s={self.start_s!r}, stop_s={self.stop_s!r}; allowed: start_s < stop_s")
        self.reduce_options()  # checks mode, window_px, redetect_every and the detect options

    def reduce_options(self) -> ReduceOptions:
        """The frame-reduction part of these options."""
        return ReduceOptions(mode=self.mode, window_px=self.window_px, redetect_every=self.redetect_every,
                             detect=dict(self.detect))


@dataclass
class VideoObservations:
    """Marker rows of one video, its frame-time report, its size, and where the time went (s)."""

    camera: str
    observations: pd.DataFrame
    report: FrameTimeReport
    width_px: int
    height_px: int
    fps: float
    timings_s: dict[str, float]
    error: str | None = None  # set when decoding stopped early (the rows read so far are kept)


def _frame(parts: list[tuple[int, float, bool, np.ndarray]]) -> pd.DataFrame:
    """The rows of every frame's markers (``MARKER_DTYPE``) in one table. Their bytes are joined:
    ``np.concatenate`` of a structured dtype promotes its fields array by array (≈ 20 µs a frame)."""
    counts = [len(p[3]) for p in parts]
    rec = np.frombuffer(b"".join([p[3].astype(MARKER_DTYPE, copy=False).tobytes() for p in parts]),
                        MARKER_DTYPE)
    out: dict[str, Any] = {
        "frame_index": np.repeat(np.array([p[0] for p in parts], dtype=np.int64), counts),
        "timestamp_s": np.repeat(np.array([p[1] for p in parts], dtype=float), counts),
    }
    out.update({k: rec[k].astype(float) for k in _FIELDS})
    out["flags"] = rec["flags"].astype(np.uint8)
    out["duplicate"] = np.repeat(np.array([p[2] for p in parts], dtype=bool), counts)
    return pd.DataFrame(out)


def extract_video(path: str | Path, camera: str | None = None,
                  options: ExtractOptions | None = None) -> VideoObservations:
    """Marker observations of the video at ``path`` (see the module docstring).

    A truncated or corrupt file does not raise here: the rows read so far are returned with ``error`` set
    and ``report.truncated``; the caller decides (``rig measure`` keeps the partial result and says so).
    Raises :class:`drivers.camera.video_file.VideoOpenError` when the file cannot be opened at all.
    """
    opts = options or ExtractOptions()
    video = VideoFile(path, name=camera, fps=opts.fps, duplicate_policy=opts.duplicate_policy,
                      decoder_threads=opts.decoder_threads)
    reducer = MarkerReducer(opts.reduce_options())
    parts: list[tuple[int, float, bool, np.ndarray]] = []
    t_extract = 0.0
    error = None
    t_all = time.perf_counter()
    frames = video.frames(opts.start_s)  # a verified seek to the window, when it has a start
    try:
        # each frame reduced as it comes (one compiled call measures all its windows; tracking runs of
        # frames in one call was slower, benchmarks/markers.py)
        for frame in frames:
            if opts.start_s is not None and frame.timestamp_s < opts.start_s:
                continue
            if opts.stop_s is not None and frame.timestamp_s > opts.stop_s:
                break
            t0 = time.perf_counter()
            found, _ = reducer.reduce(frame.image)
            t_extract += time.perf_counter() - t0
            parts.append((frame.index, frame.timestamp_s, frame.index in video.duplicate_indices, found))
    except VideoTruncatedError as exc:
        error = str(exc)
    total = time.perf_counter() - t_all
    obs = _frame(parts)
    return VideoObservations(
        camera=video.name, observations=obs, report=video.report, width_px=video.width_px,
        height_px=video.height_px, fps=video.fps, error=error,
        timings_s={"total": total, "extract": t_extract, "decode": total - t_extract,
                   "frames": float(video.report.frames_read)})


WINDOW_MARGIN_PX = 8.0  # background around a marker in its tracking window (ExtractOptions.window_px)


def window_note(obs: pd.DataFrame, window_px: int, camera: str) -> str | None:
    """A note when ``camera``'s markers are too large for the tracking window ``window_px`` (px): their major
    axis (from ``area_px`` and ``roundness``, 95th percentile of the rows measured) + ``WINDOW_MARGIN_PX``
    exceeds it. Such a marker is measured again in windows two ladder steps larger; one that still fills
    its window is measured from its cut-off support, its centre biased and unflagged (rendered markers of
    r 25–30 px in a 41 px window: up to 0.86 px; rig.stereo.markers.track_markers). None when they fit."""
    area, roundness = obs["area_px"].to_numpy(float), obs["roundness"].to_numpy(float)
    measured = np.isfinite(area) & np.isfinite(roundness) & (area > 0) & (roundness > 0)
    if not measured.any():
        return None
    major_px = float(np.percentile(2.0 * np.sqrt(area[measured] / (np.pi * roundness[measured])), 95))
    if major_px + WINDOW_MARGIN_PX <= window_px:
        return None
    return (f"camera {camera}: markers up to {major_px:.0f} px across (95th percentile of the major axis) do "
            f"not fit the tracking window of {window_px} px, which needs their size + "
            f"{WINDOW_MARGIN_PX:g} px + twice the largest motion per frame: a marker still filling a window "
            f"after two larger retries is measured from its cut-off part, its centre biased by up to ≈ 1 px "
            f"and not flagged; give --window-px {math.ceil(major_px + WINDOW_MARGIN_PX) | 1} or more (plus "
            f"twice the motion per frame)")


def associate(uv_prev: np.ndarray, uv_next: np.ndarray, gate_px: float) -> np.ndarray:
    """Index into ``uv_prev`` of each row of ``uv_next`` within ``gate_px`` (one-to-one), −1 otherwise."""
    out = np.full(len(uv_next), -1, dtype=np.int64)
    if len(uv_prev) and len(uv_next):
        cost = np.linalg.norm(uv_next[:, None, :] - uv_prev[None, :, :], axis=2)
        r, c = linear_sum_assignment(cost)
        ok = cost[r, c] <= gate_px
        out[r[ok]] = c[ok]
    return out
