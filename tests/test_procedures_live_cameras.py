"""Acquirer with live cameras: frames are reduced while recording, so a bounded device queue never overflows.

No camera is attached here, so the device is the real :class:`OpenCVCamera` (grabbing thread, host time
stamps, bounded queue that discards the oldest frame when full) over an injected capture object that
delivers frames in real time at its frame rate, as a USB camera does: ``grab()`` returns at the next frame
instant. The queue is made small (30 frames) so that a recording of 2 s (200 frames at 100 fps) would lose
170 frames per camera if the frames were read only after ``stop()``.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np
import pytest

from drivers.camera.opencv_device import OpenCVCamera
from drivers.clock import WallClock
from rig.record.events import Event
from rig.run.acquire import Acquirer, CameraStalledError, ReduceOptions
from rig.run.procedure import Abort

FPS = 100.0
WIDTH_PX, HEIGHT_PX = 160, 120
QUEUE_FRAMES = 30


def centre_px(index: int) -> tuple[float, float]:
    """Truth: the marker centre in frame ``index`` (a 1 Hz sine of ±20 px along u)."""
    return 80.0 + 20.0 * math.sin(2 * math.pi * index / FPS), 60.0 + 0.25 * (index % 8)


class RealTimeCapture:
    """A ``cv2.VideoCapture`` stand-in: a frame every 1/FPS s of wall time, the marker at ``centre_px``."""

    def __init__(self, source: Any, api: int) -> None:
        self.props = {cv2.CAP_PROP_FRAME_WIDTH: WIDTH_PX, cv2.CAP_PROP_FRAME_HEIGHT: HEIGHT_PX,
                      cv2.CAP_PROP_FPS: FPS}
        self.t0 = time.monotonic()
        self.index = -1

    def isOpened(self) -> bool:  # noqa: N802 — cv2's name
        return True

    def set(self, prop: int, value: float) -> bool:
        self.props[prop] = value
        return True

    def get(self, prop: int) -> float:
        return float(self.props.get(prop, 0.0))

    def grab(self) -> bool:
        self.index += 1
        delay = self.t0 + self.index / FPS - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        return True

    def retrieve(self) -> tuple[bool, np.ndarray]:
        img = np.full((HEIGHT_PX, WIDTH_PX), 30, np.uint8)
        u, v = centre_px(self.index)
        cv2.circle(img, (round(u * 16), round(v * 16)), 6 * 16, 220, -1, lineType=cv2.LINE_AA, shift=4)
        return True, cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)

    def release(self) -> None:
        pass


class Writer:
    def __init__(self) -> None:
        self.appended: list[Any] = []

    def append(self, frame: Any, *, segment: str) -> None:
        self.appended.append((segment, frame))

    def close(self) -> None:
        pass


class Ctx:
    """The part of a procedure context the Acquirer uses (station cameras, clock, events, writers)."""

    def __init__(self, cameras: dict[str, Any]) -> None:
        self.station = SimpleNamespace(cameras=cameras)
        # no timing fiducial configured; the heartbeat timeout bounds a reader's wait for a frame
        self.config = SimpleNamespace(fiducial=None, station=SimpleNamespace(heartbeat_timeout_s=2.0))
        self.clock = WallClock()
        self.log = logging.getLogger("test")
        self.events: list[dict[str, Any]] = []
        self.writers: dict[str, Writer] = {}
        self.progress_reports: list[tuple[float | None, str]] = []
        self.on_checkpoint: list[Any] = []

    def checkpoint(self) -> None:
        for hook in self.on_checkpoint:
            hook()

    def progress(self, fraction: float | None, message: str = "") -> None:
        self.progress_reports.append((fraction, message))

    def sleep_s(self, duration_s: float) -> None:
        time.sleep(duration_s)

    def event(self, stream: str, data: dict[str, Any] | Event) -> int:
        self.events.append({"stream": stream, **(data.to_dict() if isinstance(data, Event) else data)})
        return len(self.events)

    def observation_writer(self, camera: str) -> Writer:
        return self.writers.setdefault(camera, Writer())


def cameras(cls: type[OpenCVCamera] = OpenCVCamera) -> dict[str, OpenCVCamera]:
    return {name: cls(name, 0, fps=FPS, width_px=WIDTH_PX, height_px=HEIGHT_PX, queue_frames=QUEUE_FRAMES,
                      capture_factory=RealTimeCapture) for name in ("left", "right")}


def test_a_recording_longer_than_the_queue_loses_no_frame() -> None:
    cams = cameras()
    assert all(cam.live for cam in cams.values())
    ctx = Ctx(cams)
    duration_s = 2.0
    with Acquirer(ctx, ReduceOptions(mode="track", window_px=25)) as acq:
        rec = acq.record("sweep", duration_s)
    expected = duration_s * FPS
    for name, cam in cams.items():
        obs = rec.observations[name]
        assert cam.stats.overflow == [], f"{name}: frames discarded by the full queue"
        # every delivered frame reduced once, in order, one marker each
        assert list(obs["frame_index"]) == list(range(cam.stats.delivered))
        assert cam.stats.delivered > QUEUE_FRAMES + 0.8 * expected
        truth = np.array([centre_px(i) for i in obs["frame_index"]])
        # noise-free antialiased disc drawn at 1/16 px: centre error ≤ 1/32 px per axis from the drawing,
        # plus the centroid's edge bias of a few hundredths of a px
        assert np.max(np.abs(obs[["u_px", "v_px"]].to_numpy() - truth)) < 0.1
        assert obs["track_2d"].nunique() == 1
        stop = next(e for e in ctx.events if e["camera"] == name and e["action"] == "stop")
        assert stop["n_frames"] == cam.stats.delivered
        assert ctx.writers[name].appended[0][0] == "sweep"
    assert acq.frames_processed == sum(cam.stats.delivered for cam in cams.values())


class ReadAfterStop(OpenCVCamera):
    live = False  # the Acquirer then reads the frames only after stop(): what the old Acquirer did


def test_control_reading_after_stop_overflows_the_queue() -> None:
    # the same device read only after stop(): the test above would fail on it
    cams = cameras(ReadAfterStop)

    def until_overflowed() -> None:
        # as long as the grabbing threads need on this machine (not a wall-clock second: on a loaded machine
        # a starved grabber delivers fewer frames per second); bounded, so a queue that never overflows fails
        deadline_s = time.monotonic() + 120.0
        while any(len(cam.stats.overflow) <= 0.5 * FPS for cam in cams.values()):
            assert time.monotonic() < deadline_s, "the queues never overflowed"
            time.sleep(0.01)

    with Acquirer(Ctx(cams), ReduceOptions(mode="track", window_px=25)) as acq:
        rec = acq.record("sweep", until_overflowed)
    for name, cam in cams.items():
        assert len(cam.stats.overflow) > 0.5 * FPS
        assert len(rec.observations[name]) == QUEUE_FRAMES


def test_a_failing_motion_stops_cameras_and_readers_and_writes_nothing() -> None:
    cams = cameras()
    ctx = Ctx(cams)

    def motion() -> None:
        time.sleep(0.3)
        raise RuntimeError("exciter fault")

    with Acquirer(ctx, ReduceOptions()) as acq, pytest.raises(RuntimeError, match="exciter fault"):
        acq.record("sweep", motion)
    assert not any(cam.recording for cam in cams.values())
    assert all(not w.appended for w in ctx.writers.values()) and ctx.events == []
    assert not [t for t in threading.enumerate() if t.name.startswith("acquire-")]


class GatedCamera:
    """A camera read after ``stop()`` whose second frame waits until ``gate`` is set: the test sets it at the
    first checkpoint after the Acquirer reported its reduction, so it is then still reducing after the
    motion, deterministically."""

    live = False

    def __init__(self, name: str, gate: threading.Event) -> None:
        self.name, self.width_px, self.height_px, self.fps, self.gate = name, WIDTH_PX, HEIGHT_PX, FPS, gate

    def start(self) -> None:
        pass

    def clock_mapping(self) -> None:
        return None

    def stop(self) -> None:
        pass

    def frames(self) -> Any:
        from drivers.camera.base import Frame

        for index in range(3):
            if index == 1:
                assert self.gate.wait(timeout=60.0), "the Acquirer never checkpointed while reducing"
            yield Frame(index, index / FPS, np.full((HEIGHT_PX, WIDTH_PX), 30, np.uint8))


def test_the_reduction_after_the_motion_is_reported_as_frames_reduced_of_those_expected() -> None:
    from rig.run.progress import Processing

    gate = threading.Event()
    cams = {name: GatedCamera(name, gate) for name in ("left", "right")}
    ctx = Ctx(cams)
    # not at record()'s own first checkpoint (before the cameras start): the readers would then reduce all
    # six frames before the Acquirer first looks, on a machine fast enough (CI 7: no report)
    ctx.on_checkpoint.append(lambda: gate.set() if any(isinstance(m, Processing)
                                                       for _, m in ctx.progress_reports) else None)
    with Acquirer(ctx, ReduceOptions()) as acq:
        rec = acq.record("sweep", 0.05)
    reducing = [m for f, m in ctx.progress_reports if isinstance(m, Processing)]
    assert reducing and all(f is None for f, _ in ctx.progress_reports)
    expected = 2 * round(FPS * (rec.t_stop_s - rec.t_start_s))  # fps × the recording, both cameras
    first = reducing[0]
    assert first.done < 6 and first.total == max(expected, first.done)
    assert str(first) == f"sweep: reducing frames {first.done:,}/≈{first.total:,}"
    assert ctx.progress_reports[-1] == (None, "sweep: 6 frames reduced")


class HungCamera(GatedCamera):
    """A live camera whose driver blocks in its read after frame 0 until ``release`` is set (the test sets it
    at its end, so the reader thread ends): a device that stopped delivering."""

    live = True

    def __init__(self, name: str, release: threading.Event) -> None:
        super().__init__(name, release)

    def frames(self) -> Any:
        from drivers.camera.base import Frame

        yield Frame(0, 0.0, np.full((HEIGHT_PX, WIDTH_PX), 30, np.uint8))
        self.gate.wait()  # no time limit: the driver is hung
        yield Frame(1, 1 / FPS, np.full((HEIGHT_PX, WIDTH_PX), 30, np.uint8))


class SteppedClock:
    """An injected monotonic clock: each reading is ``step_s`` after the previous one."""

    def __init__(self, step_s: float) -> None:
        self.t_s, self.step_s, self.readings = 0.0, step_s, 0

    def __call__(self) -> float:
        self.t_s += self.step_s
        self.readings += 1
        return self.t_s


def test_a_hung_camera_reader_is_a_named_fault_after_its_bound_and_nothing_is_written() -> None:
    release = threading.Event()
    cams = {"left": HungCamera("left", release), "right": GatedCamera("right", threading.Event())}
    cams["right"].gate.set()  # right delivers its 3 frames
    ctx = Ctx(cams)
    clock = SteppedClock(0.25)
    try:
        with Acquirer(ctx, ReduceOptions(), monotonic_s=clock) as acq, \
                pytest.raises(CameraStalledError) as err:
            acq.record("sweep", 0.01)
        bound_s = 1 / FPS + 2.0  # one frame period + station.heartbeat_timeout_s
        message = str(err.value)
        assert "camera 'left'" in message and f"bound {bound_s:g} s" in message
        assert "after 1 frame(s) of segment 'sweep'" in message
        stalled_for_s = float(message.split("no frame for ")[1].split(" s", maxsplit=1)[0])
        assert bound_s < stalled_for_s <= bound_s + 2 * clock.step_s  # given up at its bound, not later
        assert all(not w.appended for w in ctx.writers.values()) and ctx.events == []
        # the hung reader is left behind (blocked in its driver), the other one ended
        assert [t.name for t in threading.enumerate() if t.name.startswith("acquire-")] == ["acquire-left"]
    finally:
        release.set()


class SlowSource(GatedCamera):
    """A source that is not live (rendered by this process) taking ``per_frame_readings`` readings of the
    injected clock per frame: seconds per frame, as the twin's rendering on a loaded machine."""

    def __init__(self, name: str, clock: SteppedClock, per_frame_readings: int) -> None:
        super().__init__(name, threading.Event())
        self.clock, self.per_frame_readings = clock, per_frame_readings

    def frames(self) -> Any:
        from drivers.camera.base import Frame

        for index in range(3):
            start = self.clock.readings
            while self.clock.readings < start + self.per_frame_readings:
                time.sleep(0.01)
            yield Frame(index, index / FPS, np.full((HEIGHT_PX, WIDTH_PX), 30, np.uint8))


def test_a_source_that_is_not_live_may_take_longer_than_the_bound_per_frame() -> None:
    clock = SteppedClock(0.25)
    # 3 s of the injected clock per frame: over the live bound of 2.01 s
    cams = {name: SlowSource(name, clock, per_frame_readings=12) for name in ("left", "right")}
    ctx = Ctx(cams)
    with Acquirer(ctx, ReduceOptions(), monotonic_s=clock) as acq:
        acq.record("sweep", 0.01)
    assert [e["n_frames"] for e in ctx.events if e["action"] == "stop"] == [3, 3]
    assert clock.t_s >= 3 * 3.0  # each reader waited 3 s of the clock (12 readings) for each frame


def test_an_abort_while_a_reader_is_hung_is_not_held_up_by_it() -> None:
    release = threading.Event()
    cams = {name: HungCamera(name, release) for name in ("left", "right")}
    ctx = Ctx(cams)
    clock = SteppedClock(0.25)

    def abort_once_reducing() -> None:
        from rig.run.progress import Processing

        if any(isinstance(m, Processing) for _, m in ctx.progress_reports):
            raise Abort("operator abort")

    ctx.on_checkpoint.append(abort_once_reducing)
    logged: list[str] = []
    handler = logging.Handler()
    handler.emit = lambda record: logged.append(record.getMessage())  # type: ignore[method-assign]
    ctx.log.addHandler(handler)
    try:
        with Acquirer(ctx, ReduceOptions(), monotonic_s=clock) as acq, pytest.raises(Abort, match="operator"):
            acq.record("sweep", 0.01)
        # each hung reader waited for up to its bound on the injected clock, then left behind and logged
        left_behind = sorted(m.split(":")[0] for m in logged if "left behind" in m)
        assert left_behind == ["camera left", "camera right"]
        assert all(not w.appended for w in ctx.writers.values()) and ctx.events == []
    finally:
        ctx.log.removeHandler(handler)
        release.set()
