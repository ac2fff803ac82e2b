"""The catalogue of runs: an SQLite index of the run folders under a runs directory.

``<runs_dir>/catalogue.sqlite`` lists every run folder (one with a ``record.jsonl``): its setup (the rig's
``station.name``), procedure, start and stop, exit status, the issued certificate's result and criteria.
It is an index, never the only copy of anything: every row is read from a folder, :func:`sync` brings the
index up to date with the folders (new, changed and removed runs) and rebuilds it from scratch when its
schema is older than this module's. The runner's command indexes a run when it ends; ``rig runs`` syncs
before it lists.

A folder is read again only when its ``record.jsonl`` or ``certificate.json`` changed (size and
modification time), so syncing a large runs directory costs one ``stat`` per folder.
"""

from __future__ import annotations

import json
import os
import sqlite3
from collections.abc import Iterator
from contextlib import closing, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rig.record.reader import RECORD_NAME, RecordError, parse_record

CATALOGUE_NAME = "catalogue.sqlite"
SCHEMA_VERSION = 1
CERTIFICATE_NAME = "certificate.json"
BUSY_TIMEOUT_S = 30.0  # another process indexing its run holds the write lock for milliseconds

_SCHEMA = """
CREATE TABLE runs (
    run_id TEXT PRIMARY KEY,
    folder TEXT NOT NULL,
    setup TEXT,
    procedure TEXT,
    started_utc TEXT,
    stopped_utc TEXT,
    exit_status TEXT,
    stop_reason TEXT,
    result TEXT,
    simulated INTEGER NOT NULL,
    freshness TEXT NOT NULL
);
CREATE TABLE criteria (
    run_id TEXT NOT NULL REFERENCES runs(run_id) ON DELETE CASCADE,
    criterion TEXT NOT NULL,
    description TEXT,
    unit TEXT,
    value REAL,
    expanded_uncertainty REAL,
    limit_value REAL,
    comparison TEXT,
    status TEXT,
    PRIMARY KEY (run_id, criterion)
);
CREATE INDEX runs_by_setup ON runs(setup, started_utc);
"""


@dataclass(frozen=True)
class Criterion:
    """One criterion of an issued certificate, as indexed."""

    criterion: str
    description: str
    unit: str
    value: float | None
    expanded_uncertainty: float | None
    limit_value: float | None
    comparison: str
    status: str


@dataclass(frozen=True)
class RunEntry:
    """One run folder, as the catalogue knows it (``result`` None: no certificate issued)."""

    run_id: str
    folder: str
    setup: str | None
    procedure: str | None
    started_utc: str | None
    stopped_utc: str | None
    exit_status: str | None
    stop_reason: str | None
    result: str | None
    simulated: bool
    criteria: tuple[Criterion, ...] = ()


@dataclass
class SyncReport:
    """What :func:`sync` did: runs added or read again, removed, and folders it could not read (why)."""

    indexed: list[str] = field(default_factory=list)
    removed: list[str] = field(default_factory=list)
    unreadable: dict[str, str] = field(default_factory=dict)


def catalogue_path(runs_dir: str | os.PathLike[str]) -> Path:
    """Where the catalogue of ``runs_dir`` lives."""
    return Path(runs_dir) / CATALOGUE_NAME


@contextmanager
def open_catalogue(runs_dir: str | os.PathLike[str]) -> Iterator[sqlite3.Connection]:
    """The catalogue's connection (created with its schema; emptied when its schema version is older)."""
    Path(runs_dir).mkdir(parents=True, exist_ok=True)
    with closing(sqlite3.connect(catalogue_path(runs_dir), timeout=BUSY_TIMEOUT_S)) as conn:
        conn.execute("PRAGMA foreign_keys = ON")
        version = conn.execute("PRAGMA user_version").fetchone()[0]
        if version != SCHEMA_VERSION:
            with conn:
                conn.executescript("DROP TABLE IF EXISTS criteria; DROP TABLE IF EXISTS runs;" + _SCHEMA)
                conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
        yield conn


def _freshness(run_dir: Path) -> str:
    """Size and modification time of the files a catalogue row is read from."""
    parts = []
    for name in (RECORD_NAME, CERTIFICATE_NAME):
        try:
            st = (run_dir / name).stat()
            parts.append(f"{name}:{st.st_size}:{st.st_mtime_ns}")
        except FileNotFoundError:
            parts.append(f"{name}:-")
    return ";".join(parts)


def _section(document: dict[str, Any], key: str) -> dict[str, Any]:
    """``document[key]`` when it is a JSON object, else an empty one."""
    value = document.get(key)
    return value if isinstance(value, dict) else {}


def _number(value: Any) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def read_entry(run_dir: str | os.PathLike[str]) -> RunEntry:
    """The catalogue entry of one run folder, read from its record and issued certificate.

    Raises RecordError when the record cannot be read (a damaged line before the last) or has no start.
    """
    run_dir = Path(run_dir)
    documents = parse_record(run_dir / RECORD_NAME).documents
    starts = [d for d in documents if d.get("type") == "start"]
    stops = [d for d in documents if d.get("type") == "stop"]
    if not starts:
        raise RecordError(f"{run_dir / RECORD_NAME} has no start document")
    first, last_stop = starts[0], (stops[-1] if stops else {})
    rig = _section(starts[-1], "rig")
    station = _section(rig, "station")
    certificate = _certificate(run_dir)
    criteria = tuple(
        Criterion(criterion=str(c.get("id")), description=str(c.get("description", "")),
                  unit=str(c.get("unit", "")), value=_number(c.get("value")),
                  expanded_uncertainty=_number(c.get("expanded_uncertainty")),
                  limit_value=_number(c.get("limit")), comparison=str(c.get("comparison", "")),
                  status=str(c.get("status", "")))
        for c in certificate.get("criteria", []) if isinstance(c, dict) and c.get("id")
    )
    cameras = _section(rig, "cameras")
    simulated = bool(certificate.get("simulated", station.get("simulated")) or any(
        isinstance(c, dict) and c.get("driver") == "sim" for c in cameras.values()))
    return RunEntry(
        run_id=run_dir.name, folder=str(run_dir.resolve()), setup=station.get("name"),
        procedure=first.get("procedure"), started_utc=first.get("wall_utc"),
        stopped_utc=last_stop.get("wall_utc"), exit_status=last_stop.get("exit_status"),
        stop_reason=last_stop.get("reason"), result=certificate.get("result"), simulated=simulated,
        criteria=criteria,
    )


def _certificate(run_dir: Path) -> dict[str, Any]:
    """The issued certificate (empty when there is none or it is not a JSON object)."""
    try:
        loaded = json.loads((run_dir / CERTIFICATE_NAME).read_text(encoding="utf-8"))
    except FileNotFoundError:
        return {}
    except ValueError as exc:
        raise RecordError(f"{run_dir / CERTIFICATE_NAME} is not valid JSON ({exc})") from exc
    return loaded if isinstance(loaded, dict) else {}


def _store(conn: sqlite3.Connection, entry: RunEntry, freshness: str) -> None:
    conn.execute("DELETE FROM runs WHERE run_id = ?", (entry.run_id,))
    conn.execute(
        "INSERT INTO runs VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
        (entry.run_id, entry.folder, entry.setup, entry.procedure, entry.started_utc, entry.stopped_utc,
         entry.exit_status, entry.stop_reason, entry.result, int(entry.simulated), freshness),
    )
    conn.executemany(
        "INSERT INTO criteria VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
        [(entry.run_id, c.criterion, c.description, c.unit, c.value, c.expanded_uncertainty, c.limit_value,
          c.comparison, c.status) for c in entry.criteria],
    )


def run_folders(runs_dir: str | os.PathLike[str]) -> list[Path]:
    """The run folders directly under ``runs_dir`` (those holding a record), sorted by name."""
    root = Path(runs_dir)
    if not root.is_dir():
        return []
    return sorted(p for p in root.iterdir() if (p / RECORD_NAME).is_file())


def sync(runs_dir: str | os.PathLike[str]) -> SyncReport:
    """Bring the catalogue of ``runs_dir`` up to date with its run folders; what changed."""
    report = SyncReport()
    folders = {p.name: p for p in run_folders(runs_dir)}
    with open_catalogue(runs_dir) as conn:
        known = dict(conn.execute("SELECT run_id, freshness FROM runs").fetchall())
        with conn:
            for run_id in sorted(set(known) - set(folders)):
                conn.execute("DELETE FROM runs WHERE run_id = ?", (run_id,))
                report.removed.append(run_id)
            for run_id, folder in folders.items():
                freshness = _freshness(folder)
                if known.get(run_id) == freshness:
                    continue
                try:
                    _store(conn, read_entry(folder), freshness)
                except (RecordError, OSError) as exc:
                    conn.execute("DELETE FROM runs WHERE run_id = ?", (run_id,))
                    report.unreadable[run_id] = str(exc)
                    continue
                report.indexed.append(run_id)
    return report


def index_run(run_dir: str | os.PathLike[str]) -> None:
    """Index one run folder in the catalogue of the folder it lies in (at the end of a run)."""
    run_dir = Path(run_dir)
    entry = read_entry(run_dir)
    with open_catalogue(run_dir.parent) as conn, conn:
        _store(conn, entry, _freshness(run_dir))


def _entry(row: sqlite3.Row, criteria: tuple[Criterion, ...] = ()) -> RunEntry:
    return RunEntry(run_id=row["run_id"], folder=row["folder"], setup=row["setup"],
                    procedure=row["procedure"], started_utc=row["started_utc"],
                    stopped_utc=row["stopped_utc"], exit_status=row["exit_status"],
                    stop_reason=row["stop_reason"], result=row["result"], simulated=bool(row["simulated"]),
                    criteria=criteria)


def list_runs(runs_dir: str | os.PathLike[str], *, setup: str | None = None) -> list[RunEntry]:
    """The indexed runs (oldest first), of one setup when given, each with its certificate's criteria."""
    with open_catalogue(runs_dir) as conn:
        conn.row_factory = sqlite3.Row
        rows = conn.execute(
            "SELECT * FROM runs WHERE (? IS NULL OR setup = ?) ORDER BY started_utc, run_id", (setup, setup)
        ).fetchall()
        criteria: dict[str, list[Criterion]] = {}
        for c in conn.execute("SELECT * FROM criteria ORDER BY rowid"):
            criteria.setdefault(c["run_id"], []).append(Criterion(
                criterion=c["criterion"], description=c["description"], unit=c["unit"], value=c["value"],
                expanded_uncertainty=c["expanded_uncertainty"], limit_value=c["limit_value"],
                comparison=c["comparison"], status=c["status"]))
    return [_entry(row, tuple(criteria.get(row["run_id"], ()))) for row in rows]


def find_run(runs_dir: str | os.PathLike[str], run: str) -> RunEntry | None:
    """The indexed run whose id is ``run`` or whose folder is the path ``run``; None if not indexed."""
    wanted = Path(run).name
    return next((e for e in list_runs(runs_dir) if e.run_id == wanted), None)
