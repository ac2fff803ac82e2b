"""The record's typed documents: truth and device events, and the start, stop and interlock documents.

Writers (the procedures, the acquisition, the runner) build these and record ``to_dict()``; readers (the
analysis, the reports) decode a document's ``data`` once with ``from_dict``. Every event's ``data``
carries ``schema_version`` (:data:`EVENT_SCHEMA_VERSION`); data without it was written before the schema
was versioned (version 0, same fields) and decodes the same way. A version newer than this code knows,
a missing required field or a value of the wrong type raises :class:`EventSchemaError` naming the stream
and the field. Fields a newer writer added are kept in ``extra`` (and written back by ``to_dict``).

Units are in the field names; times are on the rig (controller) clock unless the name says otherwise
(``first_timestamp_s``: the camera's own clock).
"""

from __future__ import annotations

import dataclasses
import types
import typing
from dataclasses import dataclass, field
from typing import Any, ClassVar, TypeVar, get_type_hints

EVENT_SCHEMA_VERSION = 1
VERSION_KEY = "schema_version"

E = TypeVar("E", bound="Document")


class EventSchemaError(ValueError):
    """A record document does not match its schema (the message names the stream and the field)."""


def _check(value: Any, hint: Any, where: str) -> Any:
    """``value`` converted to the field's type ``hint`` (float, int, str, bool, lists/dicts of them,
    ``X | None``); raises :class:`EventSchemaError` naming ``where``."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None:
            return None
        errors = []
        for arg in (a for a in typing.get_args(hint) if a is not type(None)):
            try:
                return _check(value, arg, where)
            except EventSchemaError as exc:
                errors.append(str(exc))
        raise EventSchemaError("; or ".join(errors))
    if hint is Any:
        return value
    if origin is list:
        if not isinstance(value, list | tuple):
            raise EventSchemaError(f"{where}: expected a list, got {value!r:.80}")
        (item,) = typing.get_args(hint)
        return [_check(v, item, f"{where}[{i}]") for i, v in enumerate(value)]
    if origin is dict:
        if not isinstance(value, dict):
            raise EventSchemaError(f"{where}: expected an object, got {value!r:.80}")
        _, item = typing.get_args(hint)
        return {str(k): _check(v, item, f"{where}.{k}") for k, v in value.items()}
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise EventSchemaError(f"{where}: expected a number, got {value!r:.80}")
        return float(value)
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int | float) or not float(value).is_integer():
            raise EventSchemaError(f"{where}: expected an integer, got {value!r:.80}")
        return int(value)
    if hint is bool:
        if not isinstance(value, bool):
            raise EventSchemaError(f"{where}: expected true or false, got {value!r:.80}")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise EventSchemaError(f"{where}: expected a string, got {value!r:.80}")
        return value
    raise TypeError(f"{where}: unsupported field type {hint!r}")


@dataclass(frozen=True)
class Document:
    """Base of the typed documents: generic ``to_dict`` / ``from_dict`` over the dataclass fields."""

    KIND: ClassVar[str] = ""
    extra: dict[str, Any] = field(default_factory=dict, kw_only=True, repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        """The JSON-ready fields (``None`` optional fields left out) plus ``extra`` and the version."""
        out: dict[str, Any] = dict(self.extra)
        for f in dataclasses.fields(self):
            if f.name == "extra":
                continue
            value = getattr(self, f.name)
            if value is not None:
                out[f.name] = value
        out[VERSION_KEY] = EVENT_SCHEMA_VERSION
        return out

    @classmethod
    def from_dict(cls: type[E], data: dict[str, Any]) -> E:
        """Decode ``data`` (see the module docstring for versions and errors)."""
        if not isinstance(data, dict):
            raise EventSchemaError(f"{cls.KIND}: expected an object, got {type(data).__name__}")
        version = data.get(VERSION_KEY, 0)
        if not isinstance(version, int) or isinstance(version, bool) or version > EVENT_SCHEMA_VERSION:
            raise EventSchemaError(f"{cls.KIND}: {VERSION_KEY} {version!r} is not one this code reads "
                                   f"(0 … {EVENT_SCHEMA_VERSION}); update rig-controller")
        hints = get_type_hints(cls)
        kwargs: dict[str, Any] = {}
        for f in dataclasses.fields(cls):
            if f.name == "extra":
                continue
            if f.name not in data or data[f.name] is None:
                required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
                if required:
                    raise EventSchemaError(f"{cls.KIND}: missing field '{f.name}'")
                continue
            kwargs[f.name] = _check(data[f.name], hints[f.name], f"{cls.KIND}.{f.name}")
        names = {f.name for f in dataclasses.fields(cls)} | {VERSION_KEY}
        return cls(**kwargs, extra={k: v for k, v in data.items() if k not in names})


@dataclass(frozen=True)
class Event(Document):
    """An ``event`` document's ``data``; ``STREAM`` is the stream it is recorded in."""

    STREAM: ClassVar[str] = ""


# ------------------------------------------------------------------------------------------ truth events
@dataclass(frozen=True)
class SweepEvent(Event):
    """A frequency sweep of the column (crank exciter or shaker): the commanded profile ``[[t_s, f_hz], …]``
    (rig clock), the peak displacement ``amplitude_mm`` along ``axis``, the markers that move."""

    KIND: ClassVar[str] = "sweep"
    STREAM: ClassVar[str] = "sweep"
    t_start_s: float
    t_stop_s: float
    amplitude_mm: float
    axis: list[float]
    profile: list[list[float]]
    marker_ids: list[str] = field(default_factory=list)
    segment: str | None = None
    recording: list[float] | None = None  # [t_start_s, t_stop_s] of the cameras' recording
    body: str = "exciter"  # "exciter" (crank) or "shaker" (generator)
    amplitude_vpp: float | list[float] | None = None  # shaker: the generator's amplitude (per step: a list)
    spacing: str | None = None  # shaker: "linear", "log" or "steps"
    profile_source: str | None = None  # how the profile was obtained (shaker: the commanded law)
    # a generator's phase restart (PHASe:SYNChronize) at the first profile time: [sent, confirmed] and how
    # that instant relates to the cameras' clocks; None: the phase origin is not known (the crank)
    phase_origin_s: list[float] | None = None
    phase_origin: str = ""
    step_brackets_s: list[list[float]] | None = None  # shaker steps: each FREQ change's [sent, returned]


@dataclass(frozen=True)
class BandSweepEvent(SweepEvent):
    """Certify's shaker sweep beyond the crank's limit (its own stream, apart from the crank's ``sweep``):
    the generator's own sweep restarted at phase 0 by ``PHASe:SYNChronize`` at the first profile time (the
    command's bracket midpoint, ``phase_origin_s`` = [sent, confirmed]); ``phase_origin`` says how that
    instant relates to the cameras' clocks (the timing fiducial on the generator's other channel, or the
    bracket alone)."""

    KIND: ClassVar[str] = "band_sweep"
    STREAM: ClassVar[str] = "band_sweep"


@dataclass(frozen=True)
class AccuracyPoseEvent(Event):
    """One static pose of the accuracy test: the commanded marker positions (mm, rig frame) while the
    cameras recorded from ``t_start_s`` to ``t_stop_s``."""

    KIND: ClassVar[str] = "accuracy_pose"
    STREAM: ClassVar[str] = "accuracy_pose"
    index: int
    t_start_s: float
    t_stop_s: float
    markers: dict[str, list[float]]
    cycle: int = 0
    target: str | None = None
    pose: list[float] | None = None
    segment: str | None = None


@dataclass(frozen=True)
class CalibrationPositionEvent(Event):
    """One position of the slid calibration plate: its control points (mm) while recorded."""

    KIND: ClassVar[str] = "calibration_position"
    STREAM: ClassVar[str] = "calibration_position"
    index: int
    t_start_s: float
    t_stop_s: float
    points: dict[str, list[float]]
    pose: list[float] | None = None
    slide_mm: float | None = None


@dataclass(frozen=True)
class PlateEvent(Event):
    """A steady plate vibration: mean polled frequency, tip amplitude and per-marker amplitudes (mm)."""

    KIND: ClassVar[str] = "plate"
    STREAM: ClassVar[str] = "plate"
    t_start_s: float
    t_stop_s: float
    frequency_hz: float
    amplitude_mm: float
    axis: list[float]
    marker_ids: list[str]
    setpoint_hz: float | None = None
    marker_amplitudes_mm: dict[str, float] | None = None
    segment: str | None = None
    body: str | None = None
    amplitude_vpp: float | None = None


@dataclass(frozen=True)
class RotationEvent(Event):
    """A steady rotor rotation: mean polled frequency, the rotor's radius, centre and axis (mm)."""

    KIND: ClassVar[str] = "rotation"
    STREAM: ClassVar[str] = "rotation"
    t_start_s: float
    t_stop_s: float
    frequency_hz: float
    radius_mm: float
    centre_mm: list[float]
    axis: list[float]
    setpoint_hz: float | None = None
    marker_ids: list[str] = field(default_factory=list)
    segment: str | None = None


@dataclass(frozen=True)
class ArmEvent(Event):
    """One arm move: commanded and reported pose, its start and end (rig clock) and the position error."""

    KIND: ClassVar[str] = "arm"
    STREAM: ClassVar[str] = "arm"
    commanded_pose: list[float]
    reported_pose: list[float] | None = None
    t_start_s: float | None = None
    t_end_s: float | None = None
    position_error_mm: float | None = None


@dataclass(frozen=True)
class CameraEvent(Event):
    """A camera's recording of a segment starts or stops. ``start``: controller time ``t_s`` and the camera
    time stamp of the first frame recorded after it (what relates the two clocks); ``stop``: the last. A
    camera that stamps its own frames also gives, at ``start``, its clock's mapping onto the host's
    (:class:`drivers.camera.base.ClockMapping`): ``host_minus_camera_s`` (the driver's host clock minus the
    camera's: the lowest arrival latency of its last frames, late by the camera's own lowest latency) and
    ``lag_spread_s`` (median − lowest latency: how far its frames queued) and ``start_camera_s`` (``t_s``'s
    instant on the camera's clock by that mapping: the first frame is exposed at or after it; both are
    early by the camera's own lowest latency, which the stream does not reveal)."""

    KIND: ClassVar[str] = "camera"
    STREAM: ClassVar[str] = "camera"
    camera: str
    action: str  # "start" or "stop"
    segment: str | None = None
    t_s: float | None = None
    first_index: int | None = None
    first_timestamp_s: float | None = None
    last_index: int | None = None
    last_timestamp_s: float | None = None
    n_frames: int | None = None
    host_minus_camera_s: float | None = None
    lag_spread_s: float | None = None
    start_camera_s: float | None = None


EVENT_TYPES: dict[str, type[Event]] = {
    t.STREAM: t for t in (SweepEvent, BandSweepEvent, AccuracyPoseEvent, CalibrationPositionEvent, PlateEvent,
                          RotationEvent, ArmEvent, CameraEvent)
}


# ------------------------------------------------------------------------------------------ documents
@dataclass(frozen=True)
class StartDocument(Document):
    """A session begins: the procedure and its parameters, the configuration snapshot (``rig``), the
    software versions, the kind of clock (``virtual`` on the simulated rig, else ``wall``); a resumed
    session says so and lists the steps already completed."""

    KIND: ClassVar[str] = "start"
    run_id: str
    procedure: str
    uid: str | None = None
    parameters: dict[str, Any] = field(default_factory=dict)
    rig: dict[str, Any] = field(default_factory=dict)
    versions: dict[str, Any] = field(default_factory=dict)
    clock: str | None = None
    resume: bool = False
    completed_steps: list[str] | None = None


@dataclass(frozen=True)
class StopDocument(Document):
    """How a session ended: ``exit_status`` success / abort / fail, why, and how many events it recorded."""

    KIND: ClassVar[str] = "stop"
    exit_status: str
    reason: str = ""
    num_events: int | None = None


@dataclass(frozen=True)
class InterlockDocument(Document):
    """An interlock trip: the device and why."""

    KIND: ClassVar[str] = "interlock"
    device: str
    reason: str


__all__ = ["EVENT_SCHEMA_VERSION", "EVENT_TYPES", "VERSION_KEY", "AccuracyPoseEvent", "ArmEvent",
           "BandSweepEvent", "CalibrationPositionEvent", "CameraEvent", "Document", "Event",
           "EventSchemaError", "InterlockDocument", "PlateEvent", "RotationEvent", "StartDocument",
           "StopDocument", "SweepEvent"]
