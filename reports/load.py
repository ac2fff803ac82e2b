"""Load a run folder into tidy pandas frames for the reports (units in column names).

The reports read only the run folder (DESIGN.md): ``record.jsonl`` (start, events, stop),
``calibration.json`` and ``timing.json``, read once and decoded (:mod:`rig.record.folder`). The 3D
tracks come from ``rig.analysis.analyse`` (given the folder as read) and are passed in separately, so
every table function here and in the sibling modules is a pure function of frames and decoded files.

Truth streams become one row per commanded item:

* :func:`accuracy_poses` — one row per (pose event, marker): ``index``, ``cycle``, ``target``,
  ``marker_id``, ``t_start_s``, ``t_stop_s``, ``x_cmd_mm``, ``y_cmd_mm``, ``z_cmd_mm``;
* :func:`stream_events` — the ``data`` dicts of one stream, in ``seq`` order.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import pandas as pd

from reports.errors import RunFolderError
from rig.record.events import AccuracyPoseEvent, Event, EventSchemaError
from rig.record.folder import Calibration, RunFolder, SideFileError, load_folder
from rig.record.reader import RECORD_NAME as RECORD_FILE
from rig.record.reader import RecordError
from rig.stereo.timing import TimingResult

EventT = TypeVar("EventT", bound=Event)


@dataclass(frozen=True)
class RunData:
    """The parsed run record: start/stop documents, the event table and the decoded side files.

    ``events`` has columns ``stream`` (str), ``seq`` (int), ``time_s`` (float, rig clock) and ``data``
    (dict), sorted by ``(stream, seq)``. ``folder``: the run folder as read once (record, observations,
    calibration, timing), which the analysis takes. ``calibration`` / ``timing`` are ``None`` when the file
    is absent.
    """

    folder: RunFolder
    start: dict[str, Any]
    stop: dict[str, Any] | None
    events: pd.DataFrame
    documents: list[dict[str, Any]] = field(default_factory=list)
    truncated_last_line: bool = False

    @property
    def run_dir(self) -> Path:
        return self.folder.run_dir

    @property
    def calibration(self) -> Calibration | None:
        return self.folder.calibration

    @property
    def timing(self) -> TimingResult | None:
        return self.folder.timing

    @property
    def run_id(self) -> str:
        return str(self.start.get("run_id", self.run_dir.name))

    @property
    def exit_status(self) -> str | None:
        return None if self.stop is None else self.stop.get("exit_status")

    @property
    def rig(self) -> dict[str, Any]:
        """The rig configuration snapshot of the start document (``{}`` when absent)."""
        rig = self.start.get("rig") or {}
        return rig if isinstance(rig, dict) else {}


def load_record(run_dir: str | Path) -> RunData:
    """Read a run folder once (:func:`rig.record.folder.load_folder`): record, calibration and timing.

    Events of steps that were superseded by a resumed session are left out (``load_run``'s default);
    the event ``data`` dicts are kept unflattened. A truncated last line is tolerated by ``load_run``
    (it warns) and flagged in ``truncated_last_line``.
    """
    run_dir = Path(run_dir)
    if not (run_dir / RECORD_FILE).is_file():
        raise RunFolderError(f"{run_dir}: not a run folder (no {RECORD_FILE})")
    try:
        folder = load_folder(run_dir)
    except (RecordError, SideFileError) as exc:
        raise RunFolderError(str(exc)) from exc
    run = folder.run
    rows = []
    for stream, frame in sorted(run.events.items()):
        kept = {(int(s), int(ss)) for s, ss in zip(frame["seq"], frame["session"].fillna(0), strict=True)}
        for doc in run.event_documents(stream):
            if (int(doc.get("seq", -1)), int(doc.get("session", 0) or 0)) in kept:
                rows.append(
                    {
                        "stream": stream,
                        "seq": int(doc["seq"]),
                        "time_s": _float(doc.get("time_s")),
                        "data": doc.get("data") or {},
                    }
                )
    events = pd.DataFrame(rows, columns=["stream", "seq", "time_s", "data"])
    events = events.sort_values(["stream", "seq"], kind="stable").reset_index(drop=True)
    return RunData(
        folder=folder,
        start=run.start,
        stop=run.stop,
        events=events,
        documents=run.documents,
        truncated_last_line=run.truncated_last_line,
    )


def _float(value: Any) -> float:
    return float("nan") if value is None else float(value)


def stream_events(events: pd.DataFrame, stream: str) -> list[dict[str, Any]]:
    """The ``data`` dicts of one event stream, in ``seq`` order (empty list when the stream is absent)."""
    sel = events[events["stream"] == stream].sort_values("seq", kind="stable")
    return [dict(d) for d in sel["data"]]


def typed_events(events: pd.DataFrame, kind: type[EventT]) -> list[EventT]:
    """The events of ``kind``'s stream decoded (:mod:`rig.record.events`), in ``seq`` order; a document that
    does not match the schema raises :class:`RunFolderError` naming it."""
    sel = events[events["stream"] == kind.STREAM].sort_values("seq", kind="stable")
    out = []
    for seq, data in zip(sel["seq"], sel["data"], strict=True):
        try:
            out.append(kind.from_dict(dict(data)))
        except EventSchemaError as exc:
            raise RunFolderError(f"{kind.STREAM} event {seq}: {exc}") from exc
    return out


def accuracy_poses(events: pd.DataFrame) -> pd.DataFrame:
    """One row per (``accuracy_pose`` event, commanded marker), commanded coordinates in mm."""
    rows = []
    for ev in typed_events(events, AccuracyPoseEvent):
        for marker_id, xyz in sorted(ev.markers.items()):
            if len(xyz) != 3:
                raise RunFolderError(
                    f"accuracy_pose event {ev.index}: markers[{marker_id!r}] must be [x, y, z] mm, "
                    f"got {xyz!r}"
                )
            rows.append(
                {
                    "index": ev.index,
                    "cycle": ev.cycle,
                    "target": ev.target if ev.target is not None else str(ev.index),
                    "marker_id": str(marker_id),
                    "segment": ev.segment or "",
                    "t_start_s": ev.t_start_s,
                    "t_stop_s": ev.t_stop_s,
                    "x_cmd_mm": xyz[0],
                    "y_cmd_mm": xyz[1],
                    "z_cmd_mm": xyz[2],
                }
            )
    cols = [
        "index",
        "cycle",
        "target",
        "marker_id",
        "segment",
        "t_start_s",
        "t_stop_s",
        "x_cmd_mm",
        "y_cmd_mm",
        "z_cmd_mm",
    ]
    return pd.DataFrame(rows, columns=cols)


def camera_centres_mm(calibration: Calibration | None) -> dict[str, np.ndarray]:
    """Projection centres of the calibrated cameras, from each DLT matrix P (3×4): C = −M⁻¹·p₄, in mm."""
    centres: dict[str, np.ndarray] = {}
    for name, cam in sorted((calibration.cameras if calibration else {}).items()):
        P = np.asarray(cam.get("P"), dtype=float) if isinstance(cam, dict) and "P" in cam else None
        if P is None or P.shape != (3, 4):
            continue
        M = P[:, :3]
        scale = float(np.abs(M).max())
        if not np.isfinite(scale) or scale == 0 or abs(np.linalg.det(M)) <= 1e-12 * scale**3:
            continue  # not a finite camera: no centre
        centres[name] = -np.linalg.solve(M, P[:, 3])
    return centres


def calibration_residuals(calibration: Calibration | None) -> pd.DataFrame:
    """Per-camera calibration summary: ``camera``, ``n_points``, ``rms_px``, ``max_px`` (NaN: unknown)."""
    rows = []
    for name, cam in sorted((calibration.cameras if calibration else {}).items()):
        res = (
            np.asarray(cam.get("residuals_px", []), dtype=float).reshape(-1, 2)
            if isinstance(cam, dict)
            else None
        )
        norms = np.hypot(res[:, 0], res[:, 1]) if res is not None and len(res) else np.array([])
        rms = cam.get("rms_px") if isinstance(cam, dict) else None
        if rms is None and len(norms):
            rms = float(np.sqrt(np.mean(norms**2)))
        rows.append(
            {
                "camera": name,
                "n_points": len(norms),
                "rms_px": float("nan") if rms is None else float(rms),
                "max_px": float(norms.max()) if len(norms) else float("nan"),
            }
        )
    return pd.DataFrame(rows, columns=["camera", "n_points", "rms_px", "max_px"])
