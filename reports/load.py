"""Load a run folder into tidy pandas frames for the reports (units in column names).

The reports read only the run folder (DESIGN.md): ``record.jsonl`` (start, events, stop),
``calibration.json`` and ``timing.json``. The 3D tracks come from ``rig.analysis.analyse`` and are passed in
separately, so every table function here and in the sibling modules is a pure function of frames and
dicts.

Truth streams become one row per commanded item:

* :func:`accuracy_poses` — one row per (pose event, marker): ``index``, ``cycle``, ``target``,
  ``marker_id``, ``t_start_s``, ``t_stop_s``, ``x_cmd_mm``, ``y_cmd_mm``, ``z_cmd_mm``;
* :func:`stream_events` — the ``data`` dicts of one stream, in ``seq`` order.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from reports.errors import RunFolderError
from rig.record.writer import RecordError, load_run

RECORD_FILE = "record.jsonl"
CALIBRATION_FILE = "calibration.json"
TIMING_FILE = "timing.json"


@dataclass(frozen=True)
class RunData:
    """The parsed run record: start/stop documents, the event table and the side files.

    ``events`` has columns ``stream`` (str), ``seq`` (int), ``time_s`` (float, rig clock) and ``data``
    (dict), sorted by ``(stream, seq)``. ``calibration`` / ``timing`` are ``None`` when the file is absent.
    """

    run_dir: Path
    start: dict[str, Any]
    stop: dict[str, Any] | None
    events: pd.DataFrame
    calibration: dict[str, Any] | None = None
    timing: dict[str, Any] | None = None
    documents: list[dict[str, Any]] = field(default_factory=list)
    truncated_last_line: bool = False

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
    """Read a run folder's record, calibration and timing through :func:`rig.record.writer.load_run`.

    Events of steps that were superseded by a resumed session are left out (``load_run``'s default);
    the event ``data`` dicts are kept unflattened. A truncated last line is tolerated by ``load_run``
    (it warns) and flagged in ``truncated_last_line``.
    """
    run_dir = Path(run_dir)
    if not (run_dir / RECORD_FILE).is_file():
        raise RunFolderError(f"{run_dir}: not a run folder (no {RECORD_FILE})")
    try:
        run = load_run(run_dir)
    except RecordError as exc:
        raise RunFolderError(str(exc)) from exc
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
        run_dir=run_dir,
        start=run.start,
        stop=run.stop,
        events=events,
        calibration=_read_json(run_dir / CALIBRATION_FILE),
        timing=_read_json(run_dir / TIMING_FILE),
        documents=run.documents,
        truncated_last_line=run.truncated_last_line,
    )


def _read_json(path: Path) -> dict[str, Any] | None:
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise RunFolderError(f"{path}: not valid JSON ({exc.msg})") from exc
    if not isinstance(data, dict):
        raise RunFolderError(f"{path}: the top level must be a JSON object")
    return data


def _float(value: Any) -> float:
    return float("nan") if value is None else float(value)


def stream_events(events: pd.DataFrame, stream: str) -> list[dict[str, Any]]:
    """The ``data`` dicts of one event stream, in ``seq`` order (empty list when the stream is absent)."""
    sel = events[events["stream"] == stream].sort_values("seq", kind="stable")
    return [dict(d) for d in sel["data"]]


def accuracy_poses(events: pd.DataFrame) -> pd.DataFrame:
    """One row per (``accuracy_pose`` event, commanded marker), commanded coordinates in mm."""
    rows = []
    for ev in stream_events(events, "accuracy_pose"):
        for key in ("index", "t_start_s", "t_stop_s", "markers"):
            if key not in ev:
                raise RunFolderError(f"accuracy_pose event {ev.get('index', '?')}: missing field '{key}'")
        for marker_id, xyz in sorted(ev["markers"].items()):
            xyz_mm = np.asarray(xyz, dtype=float)
            if xyz_mm.shape != (3,):
                raise RunFolderError(
                    f"accuracy_pose event {ev['index']}: markers[{marker_id!r}] must be [x, y, z] mm, "
                    f"got {xyz!r}"
                )
            rows.append(
                {
                    "index": int(ev["index"]),
                    "cycle": int(ev.get("cycle", 0)),
                    "target": str(ev.get("target", ev["index"])),
                    "marker_id": str(marker_id),
                    "segment": str(ev.get("segment") or ""),
                    "t_start_s": float(ev["t_start_s"]),
                    "t_stop_s": float(ev["t_stop_s"]),
                    "x_cmd_mm": xyz_mm[0],
                    "y_cmd_mm": xyz_mm[1],
                    "z_cmd_mm": xyz_mm[2],
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


def camera_centres_mm(calibration: dict[str, Any] | None) -> dict[str, np.ndarray]:
    """Projection centres of the calibrated cameras, from each DLT matrix P (3×4): C = −M⁻¹·p₄, in mm."""
    centres: dict[str, np.ndarray] = {}
    for name, cam in sorted(((calibration or {}).get("cameras") or {}).items()):
        P = np.asarray(cam.get("P"), dtype=float) if isinstance(cam, dict) and "P" in cam else None
        if P is None or P.shape != (3, 4):
            continue
        M = P[:, :3]
        scale = float(np.abs(M).max())
        if not np.isfinite(scale) or scale == 0 or abs(np.linalg.det(M)) <= 1e-12 * scale**3:
            continue  # not a finite camera: no centre
        centres[name] = -np.linalg.solve(M, P[:, 3])
    return centres


def calibration_residuals(calibration: dict[str, Any] | None) -> pd.DataFrame:
    """Per-camera calibration summary: ``camera``, ``n_points``, ``rms_px``, ``max_px`` (NaN: unknown)."""
    rows = []
    for name, cam in sorted(((calibration or {}).get("cameras") or {}).items()):
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
