"""Record the cameras during a motion and reduce every frame to marker observations as it is read.

``Acquirer(ctx, options)`` is used once per procedure step::

    acq = Acquirer(ctx, ReduceOptions(mode="track", window_px=51))
    rec = acq.record("sweep", lambda: exciter.sweep(profile, on_sample=...))   # or a duration in s
    rec.observations["left"]          # DataFrame of what was appended to observations/left/
    acq.close()

:meth:`Acquirer.record` starts every camera (``FrameSource.start``), runs the motion (a callable, or waits
a duration with checkpoints), stops the cameras, and reduces each camera's frames in its own reader thread
to marker rows as they are read (the image is dropped) with
:class:`rig.analysis.frame_reduction.MarkerReducer`:
the first frame of a segment is searched whole (:func:`rig.stereo.detect_markers`), later frames only near
the markers' last positions (:func:`rig.stereo.track_markers`), with a whole-frame detection again when a
marker is lost and every ``redetect_every`` frames (to pick up markers that entered the view).
``mode="detect"`` searches every frame whole (for fast motion such as the rotor, ≈ 100 px per frame).

When a camera is read depends on the source (:attr:`drivers.roles.Camera.live`):

- a **live** device (``live = True``, e.g. :class:`drivers.camera.opencv_device.OpenCVCamera`) streams
  into a bounded queue (120 frames = 2 s at 60 fps) that overflows when nobody reads it; its reader starts
  right after its ``start()`` and reduces frames *during* the motion, so a recording of any length loses
  nothing as long as the reduction keeps up with the frame rate (what it cannot keep up with the device
  counts in ``stats.overflow``). An error of the stream (device unplugged) is raised when the motion ends.
- any other source (``live`` False: the simulated camera, which renders its recording after
  ``stop()``, or a video file) is read after ``stop()``, by the same kind of reader, all cameras in parallel.

While the readers finish after ``stop()``, the procedure's checkpoint is polled (every 0.2 s) and the frames
reduced are reported as progress (:class:`rig.run.progress.Processing`, "sweep: reducing frames 1,234/≈2,880":
the plan does not time this work); an abort, or an error of any reader, stops all of them (frames not yet
reduced are dropped, nothing is written). A live camera's reader that delivers no frame for one frame period
plus ``station.heartbeat_timeout_s`` (wall time: how long a device may stay silent before the watchdog trips)
is a hung camera: :class:`CameraStalledError` names it and the run's safe stop proceeds (its daemon thread is
left behind, blocked in the driver). A source that is not live (rendered or decoded by this process) delivers
at the host's speed, seconds per frame on a loaded machine: no bound there, its wait stays abortable. Readers
stopped by an abort or an error get the same bound to end, each.

Rows go to the run folder's observations (``segment`` = the name given to ``record``) with an extra
column ``track_2d`` (int: the same marker in consecutive frames of one camera and segment keeps its
number). Each recording writes two ``camera`` events per camera relating the clocks: ``start`` with the
rig time ``t_s`` of ``start()``, the first frame's index and camera time stamp; ``stop`` with ``t_s`` of
``stop()``, the last frame's index and time stamp and the number of frames; a camera that maps its own
clock onto the host's (:meth:`drivers.roles.Camera.clock_mapping`) adds that mapping to its ``start`` event
(and to :attr:`Recording.clock_mappings`).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Generic, TypeVar, overload

import numpy as np

from drivers.camera.base import ClockMapping
from drivers.roles import Camera
from rig.analysis.reduce_options import ReduceOptions
from rig.record.events import CameraEvent
from rig.run.fiducial import FiducialRecording
from rig.run.frame_tap import FRAMES
from rig.run.procedure import Context
from rig.run.progress import Processing

# pandas, pyarrow and the stereo core are imported where a recording uses them: a dry run loads this module
# (through the procedures) without them (tests/test_cli_start.py)
if TYPE_CHECKING:
    import pandas as pd

    from rig.analysis.frame_reduction import MarkerReducer
    from rig.record.observations import ObservationWriter

__all__ = ["Acquirer", "CameraStalledError", "Recording", "ReduceOptions"]

T = TypeVar("T")
_FIELDS = ("u_px", "v_px", "area_px", "roundness", "contrast")


_POLL_S = 0.2  # (wall s) how often the wait for the readers checkpoints and reports progress


class CameraStalledError(RuntimeError):
    """A camera's reader delivered no frame within its bound (the driver is blocked in a read): a fault."""


@dataclass
class Recording(Generic[T]):
    """One recording: the motion's return value, rig-clock start/stop of the cameras, the rows written, and
    the clock mappings of the cameras that gave one (:meth:`drivers.roles.Camera.clock_mapping`)."""

    segment: str
    result: T
    t_start_s: float
    t_stop_s: float
    observations: dict[str, pd.DataFrame]
    clock_mappings: dict[str, ClockMapping] = field(default_factory=dict)


def _rows_frame(parts: list[tuple[int, float, np.ndarray, np.ndarray]]) -> pd.DataFrame:
    import pandas as pd

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

    def __init__(self, ctx: Context, options: ReduceOptions | None = None, *,
                 monotonic_s: Callable[[], float] = time.monotonic) -> None:
        self.ctx = ctx
        self._monotonic_s = monotonic_s  # wall clock of the readers' stall bound (injected by tests)
        self.options = options or ReduceOptions()
        self.cameras: dict[str, Camera] = dict(ctx.station.cameras)
        if len(self.cameras) < 2:
            raise RuntimeError(f"the station has {len(self.cameras)} camera(s); a stereo recording needs 2")
        self._writers: dict[str, ObservationWriter] = {name: ctx.observation_writer(name)
                                                       for name in self.cameras}
        self._next_ids: dict[tuple[str, str], int] = {}
        self.frames_processed = 0
        fiducial = ctx.config.fiducial
        self.fiducial = FiducialRecording(ctx, fiducial) if fiducial is not None else None
        self._regions: dict[str, tuple[int, int, int, int]] = {}  # of the recording in progress
        # the reduction (SciPy, numba, OpenCV) is imported by a recording, not by a procedure's module
        from rig.analysis.frame_reduction import warm_up

        warm_up(self.options)  # the kernels' first call must not happen while a camera fills its queue

    def close(self) -> None:
        for writer in self._writers.values():
            writer.close()

    def __enter__(self) -> Acquirer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _reader(self, name: str, segment: str, cancel: threading.Event) -> _Reader:
        # track numbers continue over the recordings of one segment (a stopped camera may see a moved scene,
        # so every recording starts with a whole-frame detection)
        from rig.analysis.frame_reduction import MarkerReducer

        reducer = MarkerReducer(self.options, self._next_ids.get((name, segment), 0))
        reader = _Reader(self.cameras[name], reducer, cancel, self._regions.get(name), segment)
        reader.thread.start()
        return reader

    def _stall_bound_s(self, name: str) -> float:
        """(wall s) How long camera ``name``'s reader may go without a frame before it counts as hung (a live
        camera) or is left behind when cancelled: one frame period plus the station's heartbeat timeout
        (how long any device may stay silent)."""
        return 1.0 / self.cameras[name].fps + self.ctx.config.station.heartbeat_timeout_s

    def _finish(self, readers: dict[str, _Reader], cancel: threading.Event, segment: str,
                recorded_s: float) -> None:
        """Wait for the readers, checkpointing and reporting the frames reduced of those expected (fps ×
        ``recorded_s`` per camera: an estimate); a reader's error, a live camera's stalled reader
        (:meth:`_stall_bound_s`) or an abort stops all of them and raises."""
        expected = sum(round(cam.fps * recorded_s) for cam in self.cameras.values())
        reported = -1
        now_s = self._monotonic_s()
        last_frame = {name: (len(r.parts), now_s) for name, r in readers.items()}  # (frames, when counted)
        try:
            while True:
                for reader in readers.values():
                    if reader.error is not None:
                        raise reader.error
                alive = [r for r in readers.values() if r.thread.is_alive()]
                done = sum(len(r.parts) for r in readers.values())
                if not alive:
                    self.ctx.progress(None, f"{segment}: {done:,} frames reduced")
                    return
                if done != reported:
                    reported = done
                    self.ctx.progress(None, Processing(f"{segment}: reducing frames", done,
                                                       max(expected, done), approximate=True))
                self._check_stalls(readers, last_frame)
                alive[0].thread.join(timeout=_POLL_S)
                self.ctx.checkpoint()
        except BaseException:
            cancel.set()
            self._join(readers)
            raise

    def _check_stalls(self, readers: dict[str, _Reader], last_frame: dict[str, tuple[int, float]]) -> None:
        """Raise :class:`CameraStalledError` for a running reader of a live camera without a new frame within
        its bound."""
        now_s = self._monotonic_s()
        for name, reader in readers.items():
            n, since_s = last_frame[name]
            if len(reader.parts) != n:
                last_frame[name] = (len(reader.parts), now_s)
            elif (reader.camera.live and reader.thread.is_alive()
                  and now_s - since_s > self._stall_bound_s(name)):
                reader.stalled = True
                raise CameraStalledError(
                    f"camera {name!r}: no frame for {now_s - since_s:.1f} s after {n} frame(s) of segment "
                    f"{reader.segment!r} (bound {self._stall_bound_s(name):g} s = one frame period + "
                    "station.heartbeat_timeout_s): the camera's driver is blocked in a read; its reader is "
                    "abandoned")

    def _join(self, readers: dict[str, _Reader]) -> None:
        """Wait for cancelled readers to end, each at most its stall bound (a stalled one not at all): a
        reader blocked in its driver is left behind (a daemon thread) and logged."""
        for name, reader in readers.items():
            if reader.stalled:
                continue
            deadline_s = self._monotonic_s() + self._stall_bound_s(name)
            while reader.thread.is_alive() and self._monotonic_s() < deadline_s:
                reader.thread.join(timeout=_POLL_S)
            if reader.thread.is_alive():
                self.ctx.log.warning("camera %s: its reader did not end within %g s of the cancel (blocked "
                                     "in the driver); left behind", name, self._stall_bound_s(name))

    @overload
    def record(self, segment: str, motion: float) -> Recording[None]: ...

    @overload
    def record(self, segment: str, motion: Callable[[], T]) -> Recording[T]: ...

    def record(self, segment: str, motion: Callable[[], T] | float) -> Recording[Any]:
        """Record all cameras while ``motion()`` runs (or for ``motion`` seconds), reduce and write."""
        if "#" in segment:
            raise ValueError(f"segment {segment!r}: '#' is not allowed in a segment name")
        ctx, clock = self.ctx, self.ctx.clock
        ctx.checkpoint()
        started: list[Camera] = []
        cancel = threading.Event()
        readers: dict[str, _Reader] = {}
        fiducial_on = self.fiducial is not None and self.fiducial.start(segment)
        self._regions = self.fiducial.regions if fiducial_on and self.fiducial is not None else {}
        t_start = clock.now_s()
        result: Any = None
        completed = False
        try:
            for name, cam in self.cameras.items():
                cam.start()
                started.append(cam)
                if cam.live:  # its bounded queue must be read while it records
                    readers[name] = self._reader(name, segment, cancel)
            if callable(motion):
                result = motion()
            else:
                ctx.sleep_s(float(motion))
            completed = True
        finally:
            t_stop = clock.now_s()
            for cam in started:
                try:
                    cam.stop()
                except Exception as exc:  # keep the original error; a camera stop must not hide it
                    ctx.log.warning("stopping camera %s failed: %s", cam.name, exc)
            if not completed:
                cancel.set()
                self._join(readers)
        for name in self.cameras:
            if name not in readers:
                readers[name] = self._reader(name, segment, cancel)
        self._finish(readers, cancel, segment, t_stop - t_start)
        observations, mappings = {}, {}
        for name, cam in self.cameras.items():
            parts = readers[name].parts
            self._next_ids[(name, segment)] = readers[name].reducer.next_id
            frame = _rows_frame(parts)
            self._writers[name].append(frame, segment=segment)
            observations[name] = frame.assign(segment=segment)
            self.frames_processed += len(parts)
            first, last = (parts[0], parts[-1]) if parts else ((None, None), (None, None))
            mapping = cam.clock_mapping() if parts else None
            if mapping is not None:
                mappings[name] = mapping
            ctx.event("camera", CameraEvent(
                name, "start", segment, t_start, first_index=first[0], first_timestamp_s=first[1],
                host_minus_camera_s=None if mapping is None else mapping.host_minus_camera_s,
                lag_spread_s=None if mapping is None else mapping.lag_spread_s,
                start_camera_s=None if mapping is None else mapping.start_camera_s))
            ctx.event("camera", CameraEvent(name, "stop", segment, t_stop, last_index=last[0],
                                            last_timestamp_s=last[1], n_frames=len(parts)))
        if fiducial_on and self.fiducial is not None:
            self.fiducial.finish(segment, {name: readers[name].led_rows for name in self._regions})
        # result: None for a duration
        return Recording(segment, result, t_start, t_stop, observations, mappings)


class _Reader:
    """One camera's ``frames()`` reduced to rows in a daemon thread (a hung device cannot block the exit)."""

    def __init__(self, camera: Camera, reducer: MarkerReducer, cancel: threading.Event,
                 led_region: tuple[int, int, int, int] | None = None, segment: str = "") -> None:
        self.camera, self.reducer, self.cancel, self.segment = camera, reducer, cancel, segment
        self.parts: list[tuple[int, float, np.ndarray, np.ndarray]] = []
        self.led_region = led_region  # the timing fiducial's rows are kept (rig.run.fiducial)
        self.led_rows: list[tuple[int, float, np.ndarray, np.ndarray]] = []
        self.error: BaseException | None = None
        self.stalled = False  # set by the Acquirer when it gave up on this reader (no frame within its bound)
        self.thread = threading.Thread(target=self._run, name=f"acquire-{camera.name}", daemon=True)

    def _run(self) -> None:
        # in the thread, yet no delay of its first frames: Acquirer() loaded the markers with the reduction,
        # and rig.stereo.fiducial then takes ≈ 2 ms (its SciPy part loaded by the reduction too)
        from rig.stereo.fiducial import row_profile
        from rig.stereo.markers import FLAG_LOST

        try:
            for frame in self.camera.frames():
                if self.cancel.is_set():
                    return
                found, ids = self.reducer.reduce(frame.image)
                keep = ~(found["flags"] & FLAG_LOST).astype(bool)
                self.parts.append((int(frame.index), float(frame.timestamp_s), found[keep], ids[keep]))
                if self.led_region is not None:
                    rows, mean = row_profile(frame.image, self.led_region)
                    self.led_rows.append((int(frame.index), float(frame.timestamp_s), rows, mean))
                if FRAMES.enabled:  # the live view's latest frame (a reference; see rig.run.frame_tap)
                    FRAMES.offer(self.camera.name, frame.index, frame.image,
                                 np.column_stack([found["u_px"][keep], found["v_px"][keep]]), ids[keep],
                                 timestamp_s=float(frame.timestamp_s), segment=self.segment)
        except BaseException as exc:  # handed to the recording's thread, which raises it
            self.error = exc


SETTLED_PX = 1.0  # px: a still target's largest marker displacement from rest in a frame that is averaged


def settled_frames(obs: pd.DataFrame, *, still_px: float = SETTLED_PX, rest_frames: int = 3) -> pd.DataFrame:
    """The rows of ``obs`` (one recording of a target meant to be still) from the frames in which it was at
    rest: every track the frame shares with the recording's last ``rest_frames`` frames lies within
    ``still_px`` px of its rest position (its median over those frames); a frame sharing no track with them
    is left out too. A frame exposed while the target still moved (a camera clock mapped late on a loaded
    host, an arm still settling) would otherwise bias the average, or split a marker's track in two and
    show one marker as two."""
    if obs.empty:
        return obs
    frames = np.unique(obs["frame_index"].to_numpy())
    rest = (obs[obs["frame_index"].isin(frames[-rest_frames:])]
            .groupby("track_2d")[["u_px", "v_px"]].median().rename(columns=lambda c: f"rest_{c}"))
    shared = obs.join(rest, on="track_2d", how="inner")
    moved_px = np.hypot(shared["u_px"] - shared["rest_u_px"], shared["v_px"] - shared["rest_v_px"])
    worst_px = moved_px.groupby(shared["frame_index"]).max()
    return obs[obs["frame_index"].isin(worst_px.index[worst_px <= still_px])]


def mean_positions(obs: pd.DataFrame, *, min_frames: int = 1) -> pd.DataFrame:
    """Per ``track_2d``: mean ``u_px``, ``v_px`` over the frames it was seen, and the frame count ``n``
    (still targets: the average over the still frames); tracks seen in fewer than ``min_frames`` dropped."""
    g = obs.groupby("track_2d", sort=True)
    out = g.agg(u_px=("u_px", "mean"), v_px=("v_px", "mean"), n=("u_px", "size"),
                u_std_px=("u_px", "std"), v_std_px=("v_px", "std")).reset_index()
    return out[out["n"] >= min_frames].reset_index(drop=True)
