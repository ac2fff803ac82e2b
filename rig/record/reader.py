"""Read a run folder back: ``load_run(run_dir) -> Run`` with pandas frames (no hardware, no writer state).

Tolerance: a run killed at any instant leaves ``record.jsonl`` whose last line may be cut short. Such a
line is dropped, :attr:`Run.truncated_last_line` is set and a :class:`TruncatedRecordWarning` names the
file and the byte count. A bad line anywhere *else* is corruption, not a crash, and raises
:class:`RecordError` naming the line number.

Resumed runs: each ``start`` document opens a *session* (0, 1, …). A step that began in one session
and was completed in a later one was superseded; by default its earlier partial events and observations
are left out (``include_superseded=True`` keeps them). Rows of steps that never completed are kept.
"""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rig.record.observations import observation_cameras, read_observations

if TYPE_CHECKING:  # imported by load_run: the runner loads this module (through the writer) without pandas
    import pandas as pd

RECORD_NAME = "record.jsonl"
_META_COLUMNS = ["seq", "time_s", "wall_utc", "session", "step"]


class RecordError(Exception):
    """The run record is missing, corrupt, or cannot be written or resumed as asked."""


class TruncatedRecordWarning(UserWarning):
    """The record's last line was cut short (the writer died mid-line); it was dropped."""


@dataclass
class ParsedRecord:
    """The documents of a record file and what was wrong with its end."""

    documents: list[dict[str, Any]]
    truncated_last_line: bool
    partial_bytes: bytes = b""
    valid_length: int = 0  # byte offset just after the last complete, parsable line


def parse_record(path: str | os.PathLike[str]) -> ParsedRecord:
    """Parse ``record.jsonl``; drop (and report) a truncated last line; raise on damage elsewhere."""
    path = Path(path)
    if not path.is_file():
        raise RecordError(f"no run record at {path}")
    raw = path.read_bytes()
    documents: list[dict[str, Any]] = []
    *terminated, tail = raw.split(b"\n")
    offset = 0
    for number, line in enumerate(terminated, start=1):
        last = number == len(terminated) and not tail.strip()
        if line.strip():
            try:
                documents.append(_parse_line(line))
            except ValueError as exc:
                if last:
                    return ParsedRecord(documents, True, raw[offset:], offset)
                raise RecordError(f"{path}: line {number} is not a valid record document ({exc})") from exc
        offset += len(line) + 1
    if tail.strip():
        try:
            documents.append(_parse_line(tail))
        except ValueError:
            return ParsedRecord(documents, True, tail, offset)
    return ParsedRecord(documents, False, b"", len(raw))


def _parse_line(line: bytes) -> dict[str, Any]:
    try:
        doc = json.loads(line.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise ValueError(str(exc)) from exc
    if not isinstance(doc, dict) or "type" not in doc:
        raise ValueError("not a JSON object with a 'type'")
    return doc


@dataclass
class Run:
    """A run folder read back. Frames carry time in seconds on the rig clock (``time_s``).

    Attributes:
        run_dir: the folder.
        documents: every document, in order.
        starts / stops: the ``start`` and ``stop`` documents (one per session; the last stop may be missing).
        events: per stream, one row per event: ``seq, time_s, wall_utc, session, step`` then the ``data``
            fields flattened with ``.`` (``{"a": {"b": 1}}`` → column ``a.b``; lists stay lists).
        steps: every ``step`` document (``name, status, session, time_s, outputs``).
        steps_completed: step name → its outputs (relative paths) for every completed step.
        interlocks / logs: frames of those documents.
        observations: per camera, the rows of ``observations/<camera>/``.
        truncated_last_line: True when the last line of the record was cut short and dropped.
    """

    run_dir: Path
    documents: list[dict[str, Any]]
    starts: list[dict[str, Any]]
    stops: list[dict[str, Any]]
    events: dict[str, pd.DataFrame]
    steps: pd.DataFrame
    steps_completed: dict[str, Any]
    interlocks: pd.DataFrame
    logs: pd.DataFrame
    observations: dict[str, pd.DataFrame] = field(repr=False)
    truncated_last_line: bool = False

    @property
    def start(self) -> dict[str, Any]:
        """The first start document (procedure, parameters, rig snapshot, versions)."""
        return self.starts[0]

    @property
    def stop(self) -> dict[str, Any] | None:
        """The stop document of the last session, or None when that session never stopped (crash)."""
        last_session = len(self.starts) - 1
        for doc in reversed(self.stops):
            if doc.get("session", 0) == last_session:
                return doc
        return None

    @property
    def exit_status(self) -> str | None:
        """``success`` / ``abort`` / ``fail`` of the last session, or None when it never stopped."""
        stop = self.stop
        return None if stop is None else stop.get("exit_status")

    @property
    def procedure(self) -> str:
        return str(self.start.get("procedure"))

    @property
    def parameters(self) -> dict[str, Any]:
        return dict(self.start.get("parameters") or {})

    def event_documents(self, stream: str) -> list[dict[str, Any]]:
        """The raw ``event`` documents of ``stream`` (unflattened ``data``), superseded ones included."""
        return [d for d in self.documents if d.get("type") == "event" and d.get("stream") == stream]


def _superseded(steps: list[dict[str, Any]]) -> set[tuple[str | None, int]]:
    """(step, session) pairs whose work was redone and completed in a later session."""
    done_in: dict[str | None, set[int]] = {}
    begun_in: dict[str | None, set[int]] = {}
    for doc in steps:
        target = done_in if doc.get("status") == "done" else begun_in
        target.setdefault(str(doc.get("name")), set()).add(int(doc.get("session", 0)))
    out = set()
    for name, sessions in begun_in.items():
        done = done_in.get(name, set())
        for s in sessions:
            if s not in done and any(d > s for d in done):
                out.add((name, s))
    return out


def load_run(run_dir: str | os.PathLike[str], *, include_superseded: bool = False) -> Run:
    """Read the run folder ``run_dir`` into a :class:`Run` (see the module docstring for tolerance)."""
    import pandas as pd

    run_dir = Path(run_dir)
    parsed = parse_record(run_dir / RECORD_NAME)
    if parsed.truncated_last_line:
        warnings.warn(f"{run_dir / RECORD_NAME}: last line truncated ({len(parsed.partial_bytes)} bytes) "
                      "— the writer died mid-line; it was dropped", TruncatedRecordWarning, stacklevel=2)
    docs = parsed.documents
    starts = [d for d in docs if d["type"] == "start"]
    if not starts:
        raise RecordError(f"{run_dir / RECORD_NAME}: no start document")
    step_docs = [d for d in docs if d["type"] == "step"]
    dropped = set() if include_superseded else _superseded(step_docs)

    def keep(doc: dict[str, Any]) -> bool:
        return (doc.get("step"), int(doc.get("session", 0))) not in dropped

    events: dict[str, pd.DataFrame] = {}
    by_stream: dict[str, list[dict[str, Any]]] = {}
    for d in docs:
        if d["type"] == "event" and keep(d):
            by_stream.setdefault(str(d.get("stream")), []).append(d)
    for stream, items in by_stream.items():
        meta = pd.DataFrame([{k: d.get(k) for k in _META_COLUMNS} for d in items])
        data = pd.json_normalize([d.get("data") or {} for d in items], sep=".")
        data = data.drop(columns=[c for c in data.columns if c in meta.columns])
        events[stream] = pd.concat([meta, data], axis=1)
    completed: dict[str, Any] = {}
    for d in step_docs:
        if d.get("status") == "done":
            completed[d["name"]] = d.get("outputs") or []
    observations = {}
    for camera in observation_cameras(run_dir):
        frame = read_observations(run_dir, camera)
        if dropped and len(frame):
            pairs = list(zip(frame["segment"], frame["session"], strict=True))
            frame = frame[[p not in dropped for p in pairs]].reset_index(drop=True)
        observations[camera] = frame
    return Run(
        run_dir=run_dir, documents=docs, starts=starts, stops=[d for d in docs if d["type"] == "stop"],
        events=events,
        steps=_frame(step_docs, ["name", "status", "session", "time_s", "wall_utc", "outputs"]),
        steps_completed=completed,
        interlocks=_frame([d for d in docs if d["type"] == "interlock"],
                          ["time_s", "wall_utc", "session", "device", "reason"]),
        logs=_frame([d for d in docs if d["type"] == "log"],
                    ["time_s", "wall_utc", "session", "level", "message"]),
        observations=observations, truncated_last_line=parsed.truncated_last_line,
    )


def _frame(docs: list[dict[str, Any]], columns: list[str]) -> pd.DataFrame:
    import pandas as pd

    return pd.DataFrame([{c: d.get(c) for c in columns} for d in docs], columns=columns)
