"""Record the cameras during a motion and reduce every frame to marker observations as it is read.

``Acquirer(ctx, options)`` is used once per procedure step::

    acq = Acquirer(ctx, ReduceOptions(mode="track", window_px=51))
    rec = acq.record("sweep", lambda: exciter.sweep(profile, on_sample=...))   # or a duration in s
    rec.observations["left"]          # DataFrame of what was appended to observations/left/
    acq.close()

:meth:`Acquirer.record` starts every camera (``FrameSource.start``), runs the motion (a callable, or waits
a duration with checkpoints), stops the cameras, then reads each camera's frames — in parallel, one worker
thread per camera — and reduces each frame to marker rows at once (the image is dropped): the first frame
of a segment is searched whole (:func:`rig.stereo.detect_markers`), later frames only near the markers'
last positions (:func:`rig.stereo.track_markers`), with a whole-frame detection again when a marker is
lost and every ``redetect_every`` frames (to pick up markers that entered the view). ``mode="detect"``
searches every frame whole (for fast motion such as the rotor, ≈ 100 px per frame).

Rows go to the run folder's observations (``segment`` = the name given to ``record``) with an extra
column ``track_2d`` (int: the same marker in consecutive frames of one camera and segment keeps its
number). Each recording writes two ``camera`` events per camera relating the clocks: ``start`` with the
rig time ``t_s`` of ``start()``, the first frame's index and camera time stamp; ``stop`` with ``t_s`` of
``stop()``, the last frame's index and time stamp and the number of frames.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import FIRST_EXCEPTION, Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

from rig.stereo import FLAG_LOST, detect_markers, track_markers

__all__ = ["Acquirer", "MarkerReducer", "Recording", "ReduceOptions"]

T = TypeVar("T")
_FIELDS = ("u_px", "v_px", "area_px", "roundness", "contrast")


@dataclass(frozen=True)
class ReduceOptions:
    """How frames become marker rows.

    mode: "track" (detect once, then track; re-detect on loss) or "detect" (whole frame every time).
    window_px: tracking window side (px): twice the largest frame-to-frame motion plus a marker diameter.
    redetect_every: frames between whole-frame detections in "track" mode (≥ 1).
    detect: keyword options of :func:`rig.stereo.detect_markers` / :func:`track_markers` (polarity,
    min_area_px, max_area_px, min_roundness, min_contrast, centre).
    """

    mode: str = "track"
    window_px: int = 51
    redetect_every: int = 30
    detect: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.mode not in ("track", "detect"):
            raise ValueError(f"mode={self.mode!r} not allowed; allowed: 'track' or 'detect'")
        if int(self.window_px) != self.window_px or self.window_px < 7:
            raise ValueError(f"window_px={self.window_px!r}: allowed: an integer ≥ 7")
        if self.redetect_every < 1:
            raise ValueError(f"redetect_every={self.redetect_every!r}: allowed: an integer ≥ 1")


class MarkerReducer:
    """Per camera and segment: frame → marker rows (``MARKER_DTYPE``) and their ``track_2d`` numbers."""

    def __init__(self, options: ReduceOptions, first_id: int = 0) -> None:
        self.options = options
        self._uv = np.empty((0, 2))
        self._ids = np.empty(0, dtype=np.int64)
        self._next_id = int(first_id)
        self._since_detect = 0

    @property
    def next_id(self) -> int:
        """The number the next new marker gets (continue from it in a later recording of the segment)."""
        return self._next_id

    def _associate(self, found: np.ndarray) -> np.ndarray:
        """Track numbers for whole-frame detections: the previous marker within half a window, else new."""
        ids = np.full(len(found), -1, dtype=np.int64)
        uv = np.c_[found["u_px"], found["v_px"]]
        if len(self._uv) and len(uv):
            cost = np.linalg.norm(uv[:, None, :] - self._uv[None, :, :], axis=2)
            r, c = linear_sum_assignment(cost)
            ok = cost[r, c] <= self.options.window_px / 2
            ids[r[ok]] = self._ids[c[ok]]
        new = ids < 0
        ids[new] = np.arange(self._next_id, self._next_id + int(new.sum()))
        self._next_id += int(new.sum())
        return ids

    def reduce(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        opts = self.options
        found: np.ndarray | None = None
        ids: np.ndarray | None = None
        if opts.mode == "track" and len(self._uv) and self._since_detect < opts.redetect_every:
            tracked = track_markers(image, self._uv, window_px=opts.window_px, **opts.detect)
            if not np.any(tracked["flags"] & FLAG_LOST):
                found, ids = tracked, self._ids
                self._since_detect += 1
        if found is None:
            found = detect_markers(image, **opts.detect)
            ids = self._associate(found)
            self._since_detect = 1
        assert ids is not None
        self._uv = np.c_[found["u_px"], found["v_px"]]
        self._ids = ids
        return found, ids


@dataclass
class Recording(Generic[T]):
    """One recording: the motion's return value, rig-clock start/stop of the cameras, the rows written."""

    segment: str
    result: T
    t_start_s: float
    t_stop_s: float
    observations: dict[str, pd.DataFrame]


def _rows_frame(parts: list[tuple[int, float, np.ndarray, np.ndarray]]) -> pd.DataFrame:
    if not parts:
        cols = {"frame_index": np.empty(0, np.int64), "timestamp_s": np.empty(0)}
        cols.update({k: np.empty(0) for k in _FIELDS})
        cols.update(flags=np.empty(0, np.uint8), track_2d=np.empty(0, np.int64))
        return pd.DataFrame(cols)
    counts = [len(p[2]) for p in parts]
    rec = np.concatenate([p[2] for p in parts])
    out = {"frame_index": np.repeat([p[0] for p in parts], counts).astype(np.int64),
           "timestamp_s": np.repeat([p[1] for p in parts], counts).astype(float)}
    out.update({k: rec[k].astype(float) for k in _FIELDS})
    out["flags"] = rec["flags"].astype(np.uint8)
    out["track_2d"] = np.concatenate([p[3] for p in parts]).astype(np.int64)
    return pd.DataFrame(out)


class Acquirer:
    """Camera recordings of one procedure step (see the module docstring)."""

    def __init__(self, ctx: Any, options: ReduceOptions | None = None) -> None:
        self.ctx = ctx
        self.options = options or ReduceOptions()
        self.cameras: dict[str, Any] = dict(ctx.station.cameras)
        if len(self.cameras) < 2:
            raise RuntimeError(f"the station has {len(self.cameras)} camera(s); a stereo recording needs 2")
        self._writers = {name: ctx.observation_writer(name) for name in self.cameras}
        self._pool = ThreadPoolExecutor(max_workers=len(self.cameras), thread_name_prefix="acquire")
        self._next_ids: dict[tuple[str, str], int] = {}
        self.frames_processed = 0

    def close(self) -> None:
        for writer in self._writers.values():
            writer.close()
        self._pool.shutdown(wait=True)

    def __enter__(self) -> Acquirer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _reduce(self, name: str, segment: str,
                cancel: threading.Event) -> list[tuple[int, float, np.ndarray, np.ndarray]]:
        # track numbers continue over the recordings of one segment (a stopped camera may see a moved scene,
        # so every recording starts with a whole-frame detection)
        reducer = MarkerReducer(self.options, self._next_ids.get((name, segment), 0))
        parts = []
        for frame in self.cameras[name].frames():
            if cancel.is_set():
                break
            found, ids = reducer.reduce(frame.image)
            keep = ~(found["flags"] & FLAG_LOST).astype(bool)
            parts.append((int(frame.index), float(frame.timestamp_s), found[keep], ids[keep]))
        self._next_ids[(name, segment)] = reducer.next_id
        return parts

    def record(self, segment: str, motion: Callable[[], T] | float) -> Recording[T]:
        """Record all cameras while ``motion()`` runs (or for ``motion`` seconds), then reduce and write."""
        if "#" in segment:
            raise ValueError(f"segment {segment!r}: '#' is not allowed in a segment name")
        ctx, clock = self.ctx, self.ctx.clock
        ctx.checkpoint()
        started: list[Any] = []
        t_start = clock.now_s()
        result: Any = None
        try:
            for cam in self.cameras.values():
                cam.start()
                started.append(cam)
            result = ctx.sleep_s(float(motion)) if not callable(motion) else motion()
        finally:
            t_stop = clock.now_s()
            for cam in started:
                try:
                    cam.stop()
                except Exception as exc:  # keep the original error; a camera stop must not hide it
                    ctx.log.warning("stopping camera %s failed: %s", cam.name, exc)
        cancel = threading.Event()
        futures: dict[str, Future] = {n: self._pool.submit(self._reduce, n, segment, cancel)
                                      for n in self.cameras}
        try:
            pending = set(futures.values())
            while pending:
                done, pending = wait(pending, timeout=0.2, return_when=FIRST_EXCEPTION)
                for f in done:
                    f.result()  # re-raise a worker's error
                ctx.checkpoint()
        except BaseException:
            cancel.set()
            raise
        observations = {}
        for name, fut in futures.items():
            parts = fut.result()
            frame = _rows_frame(parts)
            self._writers[name].append(frame, segment=segment)
            observations[name] = frame.assign(segment=segment)
            self.frames_processed += len(parts)
            first, last = (parts[0], parts[-1]) if parts else ((None, None), (None, None))
            ctx.event("camera", {"camera": name, "action": "start", "segment": segment, "t_s": t_start,
                                 "first_index": first[0], "first_timestamp_s": first[1]})
            ctx.event("camera", {"camera": name, "action": "stop", "segment": segment, "t_s": t_stop,
                                 "last_index": last[0], "last_timestamp_s": last[1], "n_frames": len(parts)})
        return Recording(segment, result, t_start, t_stop, observations)


def mean_positions(obs: pd.DataFrame, *, min_frames: int = 1) -> pd.DataFrame:
    """Per ``track_2d``: mean ``u_px``, ``v_px`` over the frames it was seen, and the frame count ``n``
    (still targets: the average over the still frames); tracks seen in fewer than ``min_frames`` dropped."""
    g = obs.groupby("track_2d", sort=True)
    out = g.agg(u_px=("u_px", "mean"), v_px=("v_px", "mean"), n=("u_px", "size"),
                u_std_px=("u_px", "std"), v_std_px=("v_px", "std")).reset_index()
    return out[out["n"] >= min_frames].reset_index(drop=True)
