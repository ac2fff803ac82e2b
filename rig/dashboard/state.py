"""What the live dashboard shows, folded from the run record's documents and the runner's progress.

:class:`DashboardState` is fed in the run's own threads (:meth:`on_document` is a
:meth:`rig.record.writer.RunRecord.add_observer` observer, :meth:`on_progress` the runner's progress
callback); each
call only updates a few fields under a lock and returns. Clients read it in their own threads with
:meth:`patch`: the scalar fields plus, per plot, the points appended since the client's cursor. Plots are
:class:`Series` of at most ``max_points`` rows (the oldest dropped), so memory is bounded whatever the run
length and a slow client just gets a larger patch next time (nothing queues per client).

Times are rig-clock seconds (``time_s`` of the documents; virtual on the simulated rig). The time remaining
is the plan's estimate (:mod:`rig.run.plan`): the durations of the steps not yet begun, plus the current
step's duration × (1 − its progress fraction) (or minus the rig time spent in it when no fraction is
reported); while the current step reports the work it does after a motion
(:class:`rig.run.progress.Processing`, e.g. reducing a recording's frames), which the plan does not time, the
step counts with the last fraction its motion reported (a sweep reducing after its last frequency: 0 s).
Device states are what the procedures recorded (``arm``, ``exciter``, ``rotor``, ``generator`` events,
``interlock`` documents, the ``stop``'s read-back): the dashboard sends nothing to a device.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from rig.run.progress import Processing

__all__ = ["PLOTS", "DashboardState", "Overview", "Series"]

# plot name → its columns (the first is the x axis: rig time, s)
PLOTS: dict[str, tuple[str, ...]] = {
    "arm": ("t_s", "x_mm", "y_mm", "z_mm", "position_error_mm"),
    # commanded_hz: what the drive is commanded to reach (see commanded_hz()), lag_hz = polled − commanded
    "exciter": ("t_s", "commanded_hz", "frequency_hz", "lag_hz"),
    "rotor": ("t_s", "commanded_hz", "frequency_hz", "lag_hz"),
    # the rotor's phase as its drive reports it, unwrapped, in turns: ∫ polled frequency dt (trapezoids
    # between polls) since the spin began; the sync step's truth. Not wrapped to 360°: the drive is polled a
    # few times a second and the rotor turns up to tens of times a second, so a wrapped phase would alias
    "rotor_phase": ("t_s", "turns"),
    # the live stereo preview (rig.dashboard.live_stereo), against the recording's time (the cameras' clock
    # from the recording's first frame, s), not the rig time: per sweep window the fitted frequency and
    # amplitude and its error against the commanded amplitude; the rotor's turns as the cameras see them
    "sweep_amplitude": ("recording_s", "frequency_hz", "amplitude_mm", "amplitude_error_mm"),
    "rotor_phase_cameras": ("recording_s", "turns"),
}
DEVICE_STREAMS = ("exciter", "rotor", "generator")
# a drive's states (rig.run.readback, drivers.exciter.vfd.DriveStatus) whose run command is active: it drives
# towards its frequency reference; in any other ("stopped", "decelerating" after a stop command, "fault N"
# after a trip) it ramps or coasts to 0 whatever the reference register still holds
RUN_COMMANDED = ("running", "standby")


def commanded_hz(setpoint_hz: float, status: object) -> float:
    """The frequency a drive is commanded to reach (Hz): its reference ``setpoint_hz`` while the run command
    is active, 0 after a stop command or a trip (the reference register keeps the last frequency written);
    the reference when the status is unknown (not recorded)."""
    if status is None or str(status) in RUN_COMMANDED:
        return setpoint_hz
    return 0.0


class Series:
    """Append-only rows with absolute indices (0, 1, …); holds the last ``max_points`` rows."""

    def __init__(self, columns: tuple[str, ...], max_points: int = 2000) -> None:
        if max_points < 1:
            raise ValueError(f"max_points {max_points!r} not allowed; allowed: ≥ 1")
        self.columns = columns
        self.rows: deque[list[float]] = deque(maxlen=max_points)
        self.total = 0  # rows ever appended

    def append(self, row: list[float]) -> None:
        self.rows.append(row)
        self.total += 1

    def since(self, cursor: int) -> tuple[int, list[list[float]]]:
        """(absolute index of the first row returned, the rows after ``cursor`` still held)."""
        first_held = self.total - len(self.rows)
        start = max(cursor, first_held)
        return start, list(self.rows)[start - first_held:]


@dataclass(frozen=True)
class Overview:
    """Where the run is, as the page's progress section shows it (the terminal draws the same)."""

    step: str | None  # the running step (None between steps and after the stop)
    step_number: int | None  # 1-based position of ``step`` among the plan's steps
    step_names: tuple[str, ...]  # the plan's steps in order (and any step it did not time, as it began)
    step_durations_s: tuple[float, ...]  # the plan's estimate of each (rig time; 0 for an untimed step)
    fraction: float | None  # of ``step``, as reported by the procedure (None: not reported)
    message: str
    # (done, total) of the work ``step`` does after a motion (reducing a recording), which the plan does not
    # time: ``remaining_s`` then counts the step as its motion last reported it (None: no such work now)
    processing: tuple[int, int] | None
    remaining_s: float | None  # the plan's estimate (see the module docstring); None without a plan
    total_s: float  # the plan's whole duration

    @property
    def step_count(self) -> int:
        return len(self.step_names)

    def number_of(self, step: str) -> int | None:
        """The 1-based position of ``step`` in the plan (None: not a step of it)."""
        return self.step_names.index(step) + 1 if step in self.step_names else None

    def duration_of(self, step: str) -> float | None:
        """The plan's estimate of ``step`` (s of rig time; None: not a step of it)."""
        number = self.number_of(step)
        return None if number is None else self.step_durations_s[number - 1]

    @property
    def overall_fraction(self) -> float | None:
        """The share of the plan's duration done (0–1), None without a plan."""
        if self.remaining_s is None or self.total_s <= 0:
            return None
        return min(1.0, max(0.0, 1.0 - self.remaining_s / self.total_s))


class DashboardState:
    """The dashboard's model (thread-safe); see the module docstring.

    Args:
        title: what the page calls the run (the procedure, or "preview").
        plan_steps: ``(start document) -> [(step name, duration_s)]``, the plan of the run (None: unknown).
        max_points: rows held per plot.
    """

    def __init__(self, title: str, *, plan_steps: Callable[[dict[str, Any]], list[tuple[str, float]]] | None
                 = None, max_points: int = 2000) -> None:
        self._lock = threading.Condition()
        self._plan_steps = plan_steps
        self.version = 0
        self.fields: dict[str, Any] = {
            "title": title, "run_id": None, "simulated": None, "steps": [], "current_step": None,
            "progress": {"fraction": None, "message": "", "processing": None},
            "remaining_s": None, "time_s": None,
            "devices": {}, "interlocks": [], "messages": [], "stop": None, "hints": None,
            "live_stereo": None,  # {"segment", "status", "error"} of the live stereo preview
        }
        self.series = {name: Series(columns, max_points) for name, columns in PLOTS.items()}
        self._step_begin_s: float | None = None
        self._motion_fraction: float | None = None  # the running step's last reported fraction
        self._rotor_last: tuple[float, float] | None = None  # (t_s, frequency_hz) of the last rotor poll
        self._rotor_turns = 0.0

    # ---------------------------------------------------------------- writers (the run's threads)
    def _changed(self) -> None:
        self.version += 1
        self._lock.notify_all()

    def on_document(self, doc: dict[str, Any]) -> None:
        """Fold one record document in (a :meth:`RunRecord.add_observer` observer)."""
        handlers = {"start": self._on_start, "step": self._on_step, "event": self._on_event,
                    "interlock": self._on_interlock, "log": self._on_log, "stop": self._on_stop}
        handler = handlers.get(doc["type"])
        if handler is None:
            return
        with self._lock:
            self.fields["time_s"] = doc.get("time_s")
            handler(doc)
            self._update_remaining()
            self._changed()

    def on_progress(self, fraction: float | None, message: str) -> None:
        """The runner's progress callback: the current step's fraction (0–1 or None) and message."""
        with self._lock:
            processing = ({"done": message.done, "total": message.total}
                          if isinstance(message, Processing) else None)
            self.fields["progress"] = {"fraction": fraction, "message": str(message),
                                       "processing": processing}
            if fraction is not None:
                self._motion_fraction = fraction
            self._update_remaining()
            self._changed()

    def set_hints(self, hints: dict[str, Any]) -> None:
        """The preview's per-camera findings and hints (see :mod:`rig.preview`)."""
        with self._lock:
            self.fields["hints"] = hints
            self._changed()

    def add_rows(self, plot: str, rows: list[list[float]]) -> None:
        """Append ``rows`` to ``plot`` (one of :data:`PLOTS`; a NaN row breaks a drawn line)."""
        with self._lock:
            for row in rows:
                self.series[plot].append(row)
            self._changed()

    def set_live_stereo(self, segment: str | None, status: str, error: str | None = None) -> None:
        """The live stereo preview's state, shown beside its plots (an error is shown, never raised)."""
        with self._lock:
            self.fields["live_stereo"] = {"segment": segment, "status": status, "error": error}
            self._changed()

    def _on_start(self, doc: dict[str, Any]) -> None:
        f = self.fields
        f["run_id"], f["title"] = doc.get("run_id"), doc.get("procedure") or f["title"]
        f["simulated"] = bool(((doc.get("rig") or {}).get("station") or {}).get("simulated"))
        done = set(doc.get("completed_steps") or [])
        planned: list[tuple[str, float]] = []
        if self._plan_steps is not None:
            planned = self._plan_steps(doc)
        f["steps"] = [{"name": name, "duration_s": float(d), "status": "done" if name in done else "pending"}
                      for name, d in planned]

    def _step(self, name: str) -> dict[str, Any]:
        for step in self.fields["steps"]:
            if step["name"] == name:
                return step
        # a step the plan does not time (the calibration a procedure run alone does first): in the order it
        # runs, before the steps not yet begun
        step = {"name": name, "duration_s": 0.0, "status": "pending"}
        steps = self.fields["steps"]
        first_pending = next((i for i, s in enumerate(steps) if s["status"] == "pending"), len(steps))
        steps.insert(first_pending, step)
        return step

    def _on_step(self, doc: dict[str, Any]) -> None:
        step = self._step(str(doc["name"]))
        if doc.get("status") == "begin":
            step["status"] = "running"
            self.fields["current_step"] = step["name"]
            self.fields["progress"] = {"fraction": None, "message": "", "processing": None}
            self._motion_fraction = None
            self._step_begin_s = doc.get("time_s")
        else:
            step["status"] = "done"
            if self.fields["current_step"] == step["name"]:
                self.fields["current_step"] = None

    def _on_event(self, doc: dict[str, Any]) -> None:
        stream, data, t_s = doc.get("stream"), doc.get("data") or {}, float(doc.get("time_s") or 0.0)
        devices = self.fields["devices"]
        if stream == "arm":
            pose = data.get("reported_pose") or data.get("commanded_pose") or []
            devices["robot"] = {"pose": pose, "commanded_pose": data.get("commanded_pose"),
                                "position_error_mm": data.get("position_error_mm")}
            commanded = list(data.get("commanded_pose") or [math.nan] * 3)
            err = data.get("position_error_mm")
            self.series["arm"].append([t_s, *commanded[:3], math.nan if err is None else float(err)])
        elif stream in DEVICE_STREAMS:
            devices[stream] = {k: v for k, v in data.items() if not isinstance(v, dict | list)}
            if stream in self.series and data.get("frequency_hz") is not None:
                target_hz = commanded_hz(_num(data.get("setpoint_hz")), data.get("status"))
                polled_hz = float(data["frequency_hz"])
                self.series[stream].append([t_s, target_hz, polled_hz, polled_hz - target_hz])
                if stream == "rotor":
                    self._rotor_phase(t_s, polled_hz)
        elif stream == "devices":
            self.fields["devices_snapshot"] = sorted(k for k in data if k not in ("error",))

    def _rotor_phase(self, t_s: float, frequency_hz: float) -> None:
        """Advance the rotor's phase to ``t_s`` and plot it; a spin begins at the first poll after a stop."""
        last = self._rotor_last
        if last is None or (last[1] == 0.0 and frequency_hz == 0.0) or t_s < last[0]:
            self._rotor_turns = 0.0
        else:
            self._rotor_turns += 0.5 * (last[1] + frequency_hz) * (t_s - last[0])
        self._rotor_last = (t_s, frequency_hz)
        if frequency_hz != 0.0 or (last is not None and last[1] != 0.0):
            self.series["rotor_phase"].append([t_s, self._rotor_turns])

    def _on_interlock(self, doc: dict[str, Any]) -> None:
        self.fields["interlocks"].append({"device": doc.get("device"), "reason": doc.get("reason")})

    def _on_log(self, doc: dict[str, Any]) -> None:
        if doc.get("level") in ("warning", "error", "critical", "info"):
            self.fields["messages"] = [*self.fields["messages"][-19:],
                                       {"level": doc.get("level"), "message": doc.get("message")}]

    def _on_stop(self, doc: dict[str, Any]) -> None:
        self.fields["stop"] = {k: doc.get(k) for k in ("exit_status", "reason", "outcome", "exit_code",
                                                        "verdict", "safe_state", "safe_state_failures")}
        self.fields["current_step"] = None
        for step in self.fields["steps"]:
            if step["status"] == "running":
                step["status"] = "stopped"

    def _update_remaining(self) -> None:
        steps = self.fields["steps"]
        if not steps:
            self.fields["remaining_s"] = None
            return
        if self.fields["stop"] is not None:
            self.fields["remaining_s"] = 0.0
            return
        remaining = sum(s["duration_s"] for s in steps if s["status"] == "pending")
        current = next((s for s in steps if s["status"] == "running"), None)
        if current is not None:
            progress = self.fields["progress"]
            # after a motion (processing) the step stands where its motion's last report left it
            fraction = progress["fraction"] if progress["processing"] is None else self._motion_fraction
            if fraction is not None:
                remaining += current["duration_s"] * (1.0 - fraction)
            elif self._step_begin_s is not None and self.fields["time_s"] is not None:
                remaining += max(0.0, current["duration_s"] - (self.fields["time_s"] - self._step_begin_s))
            else:
                remaining += current["duration_s"]
        self.fields["remaining_s"] = remaining

    # ---------------------------------------------------------------- readers (the clients' threads)
    def overview(self) -> Overview:
        """The progress section's figures, consistent with each other (read under the lock)."""
        with self._lock:
            steps, current = self.fields["steps"], self.fields["current_step"]
            number = next((i + 1 for i, s in enumerate(steps) if s["name"] == current), None)
            progress, processing = self.fields["progress"], self.fields["progress"]["processing"]
            return Overview(step=current, step_number=number, step_names=tuple(s["name"] for s in steps),
                            step_durations_s=tuple(float(s["duration_s"]) for s in steps),
                            fraction=progress["fraction"] if current else None,
                            message=progress["message"] if current else "",
                            processing=(processing["done"], processing["total"]) if current and processing
                            else None,
                            remaining_s=self.fields["remaining_s"],
                            total_s=sum(s["duration_s"] for s in steps))

    def wait_change(self, seen_version: int, timeout_s: float) -> int:
        """Block until the version differs from ``seen_version`` or ``timeout_s`` passed; the version."""
        with self._lock:
            self._lock.wait_for(lambda: self.version != seen_version, timeout=timeout_s)
            return self.version

    def patch(self, cursors: dict[str, int]) -> tuple[dict[str, Any], dict[str, int]]:
        """The fields and, per plot, ``{"columns", "start", "rows"}`` after ``cursors`` (updated copy)."""
        with self._lock:
            out = {**self.fields, "version": self.version, "plots": {}}
            new_cursors = dict(cursors)
            for name, series in self.series.items():
                start, rows = series.since(cursors.get(name, 0))
                out["plots"][name] = {"columns": series.columns, "start": start, "rows": rows,
                                      "total": series.total}
                new_cursors[name] = series.total
            return _deep_copy(out), new_cursors


def _num(value: Any) -> float:
    return math.nan if value is None else float(value)


def _deep_copy(value: Any) -> Any:
    """A copy made of plain containers (the caller serialises it outside the lock); NaN → None."""
    if isinstance(value, dict):
        return {k: _deep_copy(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_deep_copy(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
