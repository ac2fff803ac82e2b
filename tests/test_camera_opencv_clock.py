"""A stream-stamped camera's clock mapping (:class:`OpenCVCamera`, ``timestamps = "stream"``) and the sync's
offset guess made from it, on synthetic streams: frames skipped in a burst at a recording's start and frames
arriving late (a catch-up) do not move the mapping, so two cameras' mappings give their clocks' offset where
their first recorded frames are a burst apart (what failed the lab's sync on a loaded host).

The streams are real Matroska over loopback HTTP (:func:`test_camera_stream_stamps.serve_stamps`); the host
clock is injected: each grabbed frame arrives at its scripted host instant (exposure + latency), whenever the
host actually reads it, so nothing depends on the machine's load.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_camera_stream_stamps import H, W, serve_stamps

from drivers.camera.base import Frame
from drivers.camera.opencv_device import OpenCVCamera, clock_mapping_of
from procedures import sync

PERIOD_S = 1 / 60
N_FRAMES = 240
START_FRAME = 150  # the recording starts just before this frame's mapped exposure
FLOOR_S = 0.020  # both cameras' lowest latency (readout, encoding, transport)
WAIT_S = 60.0  # bounded waits on a loaded host


def _latency_s(k: int) -> float:
    """Frame k's arrival latency: the floor, a jitter of 0..16 ms, a catch-up burst (frames 60..90 late)."""
    return FLOOR_S + 0.004 * (k % 5) + (0.3 if 60 <= k <= 90 else 0.0)


def _record(exposed_host_s: Callable[[int], float], served: list[int], start_host_s: float,
            stop_host_s: float) -> tuple[OpenCVCamera, list[Frame]]:
    """Record a stream of the frames ``served`` (frame k stamped k periods after frame 0 on the camera's
    clock, exposed at host ``exposed_host_s(k)``) on a kept connection, from ``start_host_s`` to
    ``stop_host_s`` (host s)."""
    camera: OpenCVCamera | None = None
    grabbed = iter(served)
    asked = iter((start_host_s, stop_host_s))  # start() reads the host's clock, then stop()
    stopped = threading.Event()

    def clock() -> float:
        if not threading.current_thread().name.startswith("grab-"):
            now_s = next(asked)
            if now_s == stop_host_s:
                stopped.set()
            return now_s
        k = next(grabbed)
        if k >= START_FRAME - 10:  # the host reads on once start() is done (stop() may follow at once)
            deadline_s = time.monotonic() + WAIT_S
            while not stopped.is_set() and not (camera is not None and camera.recording) \
                    and time.monotonic() < deadline_s:
                time.sleep(0.005)
        return exposed_host_s(k) + _latency_s(k)

    with serve_stamps([50.0 + k * PERIOD_S for k in served]) as url:
        camera = OpenCVCamera("cam", url, fps=60, width_px=W, height_px=H, timestamps="stream", clock=clock)
        camera.connect()
        camera.start()
        camera.stop()
        frames: list[Frame] = []
        with contextlib.suppress(Exception):  # the synthetic stream ends after its last frame
            frames.extend(camera.frames())
        camera.close()
    return camera, frames


def test_a_burst_skipped_at_the_start_shifts_the_first_frame_not_the_clock_mapping() -> None:
    host_a_s, host_b_s = 1000.0, 1000.0061  # frame 0's exposure: B's clock is 6.1 ms behind A's
    start_s = host_a_s + FLOOR_S + START_FRAME * PERIOD_S - 0.001
    stop_s = start_s + 1.0  # (frame 210 of 240)
    every = list(range(N_FRAMES))
    skipped = list(range(START_FRAME, START_FRAME + 32))  # the lab fell behind: 32 frames never sent
    cam_a, frames_a = _record(lambda k: host_a_s + k * PERIOD_S, every, start_s, stop_s)
    cam_b, frames_b = _record(lambda k: host_b_s + k * PERIOD_S, [k for k in every if k not in skipped],
                              start_s, stop_s)
    map_a, map_b = cam_a.clock_mapping(), cam_b.clock_mapping()
    assert map_a is not None and map_b is not None
    # host = camera clock (from the connection's first frame) + the lowest latency: the late burst did not
    # raise it; the jitter and the burst show in the spread (median − lowest of the frames up to the start)
    assert map_a.host_minus_camera_s == pytest.approx(host_a_s + FLOOR_S, abs=2e-6)
    assert map_b.host_minus_camera_s == pytest.approx(host_b_s + FLOOR_S, abs=2e-6)
    spread_s = float(np.median([_latency_s(k) for k in range(START_FRAME + 1)])) - FLOOR_S
    assert map_a.lag_spread_s == pytest.approx(spread_s, abs=2e-6) and spread_s > 0.004
    # the start on each camera's clock: sub-frame, whatever was skipped (the first frame: a burst later)
    assert map_a.start_camera_s == pytest.approx(start_s - host_a_s - FLOOR_S, abs=2e-6)
    assert map_b.start_camera_s == pytest.approx(start_s - host_b_s - FLOOR_S, abs=2e-6)
    # A's recording starts at the frame exposed at the start; B's first frames were skipped: its stamps date
    # the gap (32 frames dropped after the start) — B's first recorded frame is a burst later
    first_a = round(frames_a[0].timestamp_s / PERIOD_S)
    first_b = round(frames_b[0].timestamp_s / PERIOD_S)
    assert first_a == START_FRAME and first_b == START_FRAME + 32
    events = [{"camera": name, "action": "start", "first_timestamp_s": frames[0].timestamp_s,
               "host_minus_camera_s": mapping.host_minus_camera_s, "lag_spread_s": mapping.lag_spread_s}
              for name, frames, mapping in (("a", frames_a, map_a), ("b", frames_b, map_b))]
    truth_s = host_b_s - host_a_s  # A's clock minus B's at one instant
    assert sync.offset_guess_s(events, "a", "b") == pytest.approx(truth_s, abs=5e-6)
    assert sync.guess_source(events, "a", "b")["lag_spread_s"]["a"] == map_a.lag_spread_s
    first_frames_only = [{k: v for k, v in e.items() if k != "host_minus_camera_s"} for e in events]
    off_s = sync.offset_guess_s(first_frames_only, "a", "b") - truth_s
    assert off_s == pytest.approx(-32 * PERIOD_S, abs=PERIOD_S)  # the old guess: 0.53 s off, no overlap
    assert "first frames" in sync.guess_source(first_frames_only, "a", "b")["source"]


@settings(max_examples=50, deadline=None)
@given(floor_s=st.floats(-1e4, 1e4), lags=st.lists(st.floats(0.0, 5.0), min_size=1, max_size=200))
def test_the_mapping_is_the_lowest_latency_and_late_frames_only_widen_the_spread(
        floor_s: float, lags: list[float]) -> None:
    mapping = clock_mapping_of([floor_s + x for x in lags])
    assert mapping.host_minus_camera_s == pytest.approx(floor_s + min(lags), abs=1e-9)
    assert mapping.lag_spread_s == pytest.approx(float(np.median(lags)) - min(lags), abs=1e-9)
    assert mapping.window_frames == len(lags)
    late = clock_mapping_of([floor_s + x for x in lags] + [floor_s + max(lags) + 1.0] * len(lags))
    assert late.host_minus_camera_s == mapping.host_minus_camera_s  # a catch-up burst: later, never lower
    assert late.lag_spread_s >= mapping.lag_spread_s - 1e-9


def test_a_mapping_of_nothing_is_refused() -> None:
    with pytest.raises(ValueError, match="need at least one"):
        clock_mapping_of([])
