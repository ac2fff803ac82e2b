"""Record the cameras during a motion and reduce every frame to marker observations as it is read.

``Acquirer(ctx, options)`` is used once per procedure step::

    acq = Acquirer(ctx, ReduceOptions(mode="track", window_px=51))
    rec = acq.record("sweep", lambda: exciter.sweep(profile, on_sample=...))   # or a duration in s
    rec.observations["left"]          # DataFrame of what was appended to observations/left/
    acq.close()

:meth:`Acquirer.record` starts every camera (``FrameSource.start``), runs the motion (a callable, or waits
a duration with checkpoints), stops the cameras, then reads each camera's frames — in parallel, one worker
thread per camera — and reduces each frame to marker rows at once (the image is dropped) with
:class:`rig.frame_reduction.MarkerReducer`: the first frame of a segment is searched whole
(:func:`rig.stereo.detect_markers`), later frames only near the markers' last positions
(:func:`rig.stereo.track_markers`), with a whole-frame detection again when a marker is lost and every
``redetect_every`` frames (to pick up markers that entered the view). ``mode="detect"`` searches every
frame whole (for fast motion such as the rotor, ≈ 100 px per frame).

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
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import numpy as np
import pandas as pd

from rig.frame_reduction import MarkerReducer, ReduceOptions
from rig.stereo import FLAG_LOST

__all__ = ["Acquirer", "MarkerReducer", "Recording", "ReduceOptions"]

T = TypeVar("T")
_FIELDS = ("u_px", "v_px", "area_px", "roundness", "contrast")


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
