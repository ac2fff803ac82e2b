"""The dashboard's live stereo preview: the markers the acquisition found, triangulated with the run's own
calibration in short windows, plotted as the recording is reduced.

:class:`LiveStereo` runs in its own daemon thread. It drains the frame tap's marker queue
(:meth:`rig.run.frame_tap.FrameTap.drain_markers`: the acquisition only appends a reference there) and keeps
the markers of the recordings its plan names (:func:`segments_of`): a rotor's (``sync``, ``rotation``) and
the sweep's. Per window of the recording (the cameras' clocks related by the run's ``timing.json`` when it
has one, else by the recordings' first frames) it pairs and triangulates the markers
(:mod:`rig.analysis.live_estimate`) and adds to the state's plots:

- the sweep: per window the fitted frequency and amplitude of the moving markers (their median) and the
  amplitude's error against the plan's commanded amplitude (``sweep_amplitude``);
- a rotor: the marker's angle about its circle in turns, continued from window to window
  (``rotor_phase_cameras``).

It computes at most one window per ``tick_s`` of wall time; when it falls behind, the sweep skips to the
newest complete window (each window stands alone) and a rotor's turns restart after a gap. Any error is put
in the state (shown on the page) and the preview goes on with the next window: it never raises into the
run. The plots are a preview: the certificate's numbers come from the full analysis afterwards.
"""

from __future__ import annotations

import logging
import math
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from rig.dashboard.state import DashboardState
from rig.run.frame_tap import FRAMES, FrameTap, MarkerFrame

if TYPE_CHECKING:
    from rig.analysis.live_estimate import MarkerPath
    from rig.run.plan import Plan
    from rig.stereo import DLTCamera, TimingResult

__all__ = ["LiveStereo", "SegmentPlan", "segments_of"]

log = logging.getLogger("rig.dashboard.live_stereo")
ROTOR_WINDOW_S = 0.5
SWEEP_WINDOW_S = (0.25, 2.0)  # a sweep window spans 4 periods of the last fitted frequency, within these
SWEEP_PERIODS = 4.0
OTHER_MARGIN_S = 0.05  # the other camera's samples beyond the window (its spline is poor at its ends)
MOVING_SHARE = 0.2  # a marker moves when its RMS motion exceeds this share of the commanded amplitude
MAX_KEPT_FRAMES = 3600  # per camera (a minute at 60 fps): the memory bound when the preview falls behind
MAX_FITTED = 4  # the sweep's moving markers fitted per window (those moving most)


@dataclass(frozen=True)
class SegmentPlan:
    """What the preview computes for a recording: ``kind`` "sweep" or "rotor", and the plan's commanded
    ``amplitude_mm`` (the sweep's peak displacement; the rotor marker's radius)."""

    kind: str
    amplitude_mm: float


def segments_of(plan: Plan) -> dict[str, SegmentPlan]:
    """The recordings (segment = step name) of ``plan`` the preview follows: every rotor step, the sweep."""
    found = {}
    for step in plan.steps:
        vibration = step.vibration
        if vibration is None:
            continue
        if vibration.device == "rotor":
            found[step.name] = SegmentPlan("rotor", vibration.amplitude_mm)
        elif step.name == "sweep":
            found[step.name] = SegmentPlan("sweep", vibration.amplitude_mm)
    return found


# a frame kept: its time (s, common clock), the markers' pixels (n × 2), track ids (n) and times (n, the row
# each was exposed at when timing.json gives the line time)
_Frame = tuple[float, np.ndarray, np.ndarray, np.ndarray]


@dataclass
class _Recording:
    """The markers of one recording so far: per camera, per frame (common time s, uv_px, ids)."""

    name: str
    plan: SegmentPlan
    frames: dict[str, list[_Frame]] = field(default_factory=dict)
    first_stamp_s: dict[str, float] = field(default_factory=dict)
    window_start_s: float | None = None
    frequency_hz: float | None = None  # the last window's fitted frequency (sweep)
    turns: float | None = None  # the rotor's turns at the last window's end (None: after a gap)
    windows: int = 0


class LiveStereo:
    """See the module docstring. ``run_dir``: the run folder (its ``calibration.json`` and ``timing.json``
    are read when they appear); ``segments``: :func:`segments_of` the run's plan."""

    def __init__(self, state: DashboardState, run_dir: Path, segments: dict[str, SegmentPlan], *,
                 tap: FrameTap = FRAMES, tick_s: float = 0.1) -> None:
        self.state, self.run_dir, self.segments, self.tap = state, Path(run_dir), segments, tap
        self.tick_s = tick_s
        self._recording: _Recording | None = None
        self._cameras: dict[str, DLTCamera] | None = None
        self._timing: TimingResult | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="live-stereo", daemon=True)

    # ---------------------------------------------------------------- the thread
    def start(self) -> None:
        self.tap.keep_markers = True
        self._thread.start()

    def close(self) -> None:
        self.tap.keep_markers = False
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)

    def _loop(self) -> None:
        while not self._stop.wait(self.tick_s):
            self.step(self.tap.drain_markers())

    # ---------------------------------------------------------------- one tick (tests call it directly)
    def step(self, frames: list[MarkerFrame]) -> None:
        """Fold ``frames`` in and compute at most one window; errors go to the state, never raised."""
        name = self._recording.name if self._recording else None
        try:
            self.feed(frames)
            recording = self._recording
            if recording is not None:
                name = recording.name
                self._window(recording)
        except Exception as exc:  # a preview must not fail the run: shown on the page, logged at debug
            log.debug("live stereo preview failed", exc_info=True)
            self.state.set_live_stereo(name, "error", f"{type(exc).__name__}: {exc}")
            if self._recording is not None:
                self._recording.turns = None
                self._recording.window_start_s = None  # start again at the newest data

    def feed(self, frames: list[MarkerFrame]) -> None:
        """Keep the frames of the recordings the plan names; a new segment starts a new recording."""
        for frame in frames:
            plan = self.segments.get(frame.segment)
            if plan is None:
                continue
            if self._recording is None or self._recording.name != frame.segment:
                self._begin(frame.segment, plan)
            recording = self._recording
            assert recording is not None
            if self._cameras is None or frame.camera not in self._cameras:
                continue  # nothing to triangulate with
            first = recording.first_stamp_s.setdefault(frame.camera, frame.timestamp_s)
            t_frame_s, t_markers_s = self._common_times(frame.camera, frame.timestamp_s, first, frame.uv_px)
            kept = recording.frames.setdefault(frame.camera, [])
            kept.append((t_frame_s, frame.uv_px, frame.ids, t_markers_s))
            if len(kept) > MAX_KEPT_FRAMES:  # far behind: drop the oldest half, start again at the newest
                del kept[:MAX_KEPT_FRAMES // 2]
                recording.turns = recording.window_start_s = None

    def _begin(self, segment: str, plan: SegmentPlan) -> None:
        from rig.record.folder import read_calibration, read_timing
        from rig.stereo import DLTCamera

        self._recording = _Recording(segment, plan)
        if self._cameras is None:
            calibration = read_calibration(self.run_dir)
            if calibration is not None:
                self._cameras = {k: DLTCamera.from_dict(v) for k, v in sorted(calibration.cameras.items())}
        self._timing = read_timing(self.run_dir)  # written by sync: present for the recordings after it
        clocks = "timing.json" if self._timing is not None else "the recordings' first frames (±1 frame)"
        status = (f"{segment}: waiting for frames; clocks related by {clocks}" if self._cameras is not None
                  else f"{segment}: no calibration.json yet, nothing to triangulate")
        self.state.set_live_stereo(segment, status)

    def _common_times(self, camera: str, stamp_s: float, first_s: float,
                      uv_px: np.ndarray) -> tuple[float, np.ndarray]:
        """The frame's and its markers' times on the common clock, s: with ``timing.json`` each marker at
        its row's exposure (offset, drift, line time); else the frame's stamp from the recording's first."""
        timing = self._timing
        if timing is not None and camera in timing.offset_s:
            rows = np.concatenate([[0.0], uv_px[:, 1]])
            times = timing.times(camera, np.full(len(rows), stamp_s), rows)
            return float(times[0]), times[1:]
        return stamp_s - first_s, np.full(len(uv_px), stamp_s - first_s)

    # ---------------------------------------------------------------- windows
    def _reference_pair(self) -> tuple[str, str] | None:
        if self._cameras is None or len(self._cameras) < 2:
            return None
        names = list(self._cameras)
        ref = self._timing.reference_camera if self._timing and self._timing.reference_camera in names \
            else names[0]
        return ref, next(n for n in names if n != ref)

    def _window_length_s(self, recording: _Recording) -> float:
        if recording.plan.kind == "rotor":
            return ROTOR_WINDOW_S
        if recording.frequency_hz is None:
            return SWEEP_WINDOW_S[1]
        return min(SWEEP_WINDOW_S[1], max(SWEEP_WINDOW_S[0], SWEEP_PERIODS / recording.frequency_hz))

    def _window(self, recording: _Recording) -> None:
        """Compute the next complete window of ``recording``, if both cameras have passed its end."""
        pair = self._reference_pair()
        if pair is None or any(not recording.frames.get(c) for c in pair):
            return
        newest = min(recording.frames[c][-1][0] for c in pair)  # both cameras have reached this time
        oldest = max(recording.frames[c][0][0] for c in pair)
        length_s = self._window_length_s(recording)
        start = oldest if recording.window_start_s is None else recording.window_start_s
        if start + length_s + OTHER_MARGIN_S > newest:
            return
        skipped = 0
        if recording.plan.kind == "sweep":  # each sweep window stands alone: skip to the newest complete one
            skipped = int((newest - OTHER_MARGIN_S - start) // length_s) - 1
            start += skipped * length_s
        end = start + length_s
        tracks = (_tracks(recording.frames[pair[0]], start, end),
                  _tracks(recording.frames[pair[1]], start - OTHER_MARGIN_S, end + OTHER_MARGIN_S))
        for c in pair:  # what is before the window's end is no longer needed (a rotor's next window may
            # begin at this one's last sample)
            recording.frames[c] = [f for f in recording.frames[c]
                                   if f[0] >= end - length_s * 0.5 - OTHER_MARGIN_S]
        recording.window_start_s = end
        recording.windows += 1
        from rig.analysis.live_estimate import paired_paths

        assert self._cameras is not None
        paths = paired_paths((self._cameras[pair[0]], self._cameras[pair[1]]), tracks)
        if recording.plan.kind == "sweep":
            self._sweep_window(recording, paths, skipped)
        else:
            self._rotor_window(recording, paths, start, skipped)

    def _sweep_window(self, recording: _Recording, paths: list[MarkerPath], skipped: int) -> None:
        from rig.analysis.live_estimate import vibration_estimate

        commanded_mm = recording.plan.amplitude_mm
        moving = sorted((p for p in paths if p.motion_mm > MOVING_SHARE * commanded_mm),
                        key=lambda p: -p.motion_mm)[:MAX_FITTED]
        if not moving:
            self._status(recording, f"{len(paths)} markers paired, none moving", skipped)
            return
        fits = [vibration_estimate(p) for p in moving]
        frequency_hz = float(np.median([f.frequency_hz for f in fits]))
        amplitude_mm = float(np.median([f.amplitude_mm for f in fits]))
        recording.frequency_hz = frequency_hz
        self.state.add_rows("sweep_amplitude", [[float(np.median([f.t_mid_s for f in fits])), frequency_hz,
                                                 amplitude_mm, amplitude_mm - commanded_mm]])
        self._status(recording, f"{len(moving)} moving markers; {frequency_hz:.2f} Hz, amplitude "
                                f"{amplitude_mm:.3f} mm (commanded {commanded_mm:g} mm)", skipped)

    def _rotor_window(self, recording: _Recording, paths: list[MarkerPath], start_s: float,
                      skipped: int) -> None:
        from rig.analysis.live_estimate import rotor_turns

        if not paths:
            recording.turns = None
            self._status(recording, "no marker paired between the cameras", skipped)
            return
        path = max(paths, key=lambda p: p.motion_mm)
        turns = rotor_turns(path)
        rows = []
        if recording.turns is not None and path.t_s[0] == start_s:
            # the window begins at the last window's last sample (plotted already): the count goes on
            base, first = recording.turns, 1
        else:  # the first window, or a gap: the line breaks and the count starts again from 0
            rows.append([float(path.t_s[0]), math.nan])
            base, first = 0.0, 0
        rows += [[float(t), base + float(n)] for t, n in zip(path.t_s[first:], turns[first:], strict=True)]
        recording.turns = base + float(turns[-1])
        recording.window_start_s = float(path.t_s[-1])  # the next window shares this sample
        self.state.add_rows("rotor_phase_cameras", rows)
        rate = float(turns[-1] / (path.t_s[-1] - path.t_s[0])) if path.t_s[-1] > path.t_s[0] else math.nan
        self._status(recording, f"rotor marker seen turning at {rate:.2f} rev/s", skipped)

    def _status(self, recording: _Recording, text: str, skipped: int) -> None:
        clocks = "timing.json" if self._timing is not None else "first frames (±1 frame)"
        behind = f"; {skipped} windows skipped to keep up" if skipped else ""
        self.state.set_live_stereo(recording.name, f"{recording.name}, window {recording.windows}: {text} "
                                                   f"(clocks by {clocks}{behind})")


def _tracks(frames: list[_Frame], start_s: float, end_s: float) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Per track id, its times and pixels within [start_s, end_s]."""
    times: dict[int, list[float]] = {}
    pixels: dict[int, list[np.ndarray]] = {}
    for _, uv_px, ids, t_markers_s in frames:
        for uv, marker, t_s in zip(uv_px, ids, t_markers_s, strict=True):
            if start_s <= t_s <= end_s:
                times.setdefault(int(marker), []).append(float(t_s))
                pixels.setdefault(int(marker), []).append(uv)
    return {k: (np.asarray(times[k]), np.asarray(pixels[k])) for k in times}
