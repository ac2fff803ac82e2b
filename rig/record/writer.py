"""The append-only run record: ``record.jsonl`` in a run folder, plus observations and the reader.

Writing::

    rec = RunRecord.create(runs_dir, "sweep", {"max_hz": 30.0}, config.snapshot(), clock)
    rec.step_begin("ramp");  seq = rec.event("exciter", {"frequency_hz": 9.98, "setpoint_hz": 10.0})
    with rec.observation_writer("left") as obs: obs.append(detections, frame_index=n, timestamp_s=t)
    rec.step_done("ramp", outputs=["timing.json"]);  rec.stop("success", "")
    rec.close()

Folder: ``<runs_dir>/YYYYmmdd-HHMMSS_<procedure>_<uid8>/`` (UTC wall time of creation; ``uid8`` = first
8 hex digits of the run's UUID4). ``run_id`` is the folder name.

Every document is one line of strict JSON (see :mod:`rig.record.jsonenc` for numpy types; NaN → null) with
``type``, ``time_s`` (the rig clock: virtual on the simulated rig), ``wall_utc`` (ISO 8601) and
``session`` (0 for the first start, +1 per ``--resume``). Types and fields are those of
``docs/contracts.md``; in addition every ``event`` carries ``step`` (the step running when it was
recorded, or null) and ``start`` documents of a resumed session carry ``resume: true``.

Durability: each document is written with one ``write`` call and flushed at once (a crash loses at
most the line in flight); the file is ``fsync``'ed after ``start`` and ``stop``, after ``interlock``
and ``step`` documents, and whenever ``fsync_interval_s`` (default 2 s of wall time) has passed since
the last fsync (a background thread syncs a record that went quiet). Writing is thread-safe (the
runner's watchdog writes ``interlock`` documents).

Resume: :meth:`RunRecord.resume` reopens a folder, drops a truncated last line (its bytes are kept in
a ``log`` document), continues each stream's ``seq``, and writes a new ``start`` with ``resume: true``.

Reading: :func:`load_run` (re-exported from :mod:`rig.record.reader`) returns pandas frames.
:func:`record_is_open`: whether a live process still writes a folder's record (a run still going, not a
killed one): each :class:`RunRecord` holds a shared ``flock`` on ``record.jsonl`` until closed.
"""

from __future__ import annotations

import datetime as _dt
import fcntl
import json
import logging
import os
import platform
import subprocess
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

from rig.record.events import Event, InterlockDocument, StartDocument, StopDocument
from rig.record.jsonenc import to_jsonable
from rig.record.observations import ObservationWriter, read_observations
from rig.record.reader import (
    RECORD_NAME,
    RecordError,
    Run,
    TruncatedRecordWarning,
    load_run,
    parse_record,
)

__all__ = [
    "EXIT_STATUSES",
    "RECORD_NAME",
    "ObservationWriter",
    "RecordError",
    "Run",
    "RunRecord",
    "TruncatedRecordWarning",
    "collect_versions",
    "load_run",
    "parse_record",
    "read_observations",
    "record_is_open",
]

EXIT_STATUSES = ("success", "abort", "fail")
LOG_LEVELS = ("debug", "info", "warning", "error", "critical")


class _Clock(Protocol):
    def now_s(self) -> float: ...

    @property
    def is_virtual(self) -> bool: ...


def collect_versions() -> dict[str, Any]:
    """Versions of Python, the key libraries and the code revision (git commit, dirty flag) if known."""
    import numpy
    import pandas
    import pyarrow

    versions: dict[str, Any] = {"python": platform.python_version(), "numpy": numpy.__version__,
                                "pandas": pandas.__version__, "pyarrow": pyarrow.__version__}
    try:
        from importlib.metadata import version

        versions["rig-controller"] = version("rig-controller")
    except Exception:  # not installed (running from a source tree)
        versions["rig-controller"] = None
    root = Path(__file__).resolve().parents[2]
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                                timeout=5, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, timeout=5, check=True).stdout.strip()
        versions["git_commit"], versions["git_dirty"] = commit, bool(dirty)
    except (OSError, subprocess.SubprocessError):
        versions["git_commit"], versions["git_dirty"] = None, None
    return versions


def _offer(observer: Callable[[dict[str, Any]], None], document: dict[str, Any]) -> None:
    try:
        observer(document)
    except Exception:  # a live view's failure never affects the record
        logging.getLogger("rig.record.writer").warning("record observer failed", exc_info=True)


def record_is_open(run_dir: str | os.PathLike[str]) -> bool:
    """True while a :class:`RunRecord` (of any process) has ``run_dir``'s record open for writing: the run is
    still going. False after it closed it or died (a killed run: the kernel drops the lock)."""
    with open(Path(run_dir) / RECORD_NAME, "rb") as fh:
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return True
        fcntl.flock(fh.fileno(), fcntl.LOCK_UN)
        return False


class RunRecord:
    """Writer of one run folder's ``record.jsonl``. Build with :meth:`create` or :meth:`resume`."""

    def __init__(self, run_dir: Path, clock: _Clock, *, session: int, fsync_interval_s: float,
                 seq: dict[str, int], num_events: int, completed: dict[str, list[str]],
                 procedure: str, parameters: dict[str, Any]) -> None:
        self.run_dir = run_dir
        self.path = run_dir / RECORD_NAME
        self.clock = clock
        self.session = session
        self.procedure = procedure
        self.parameters = parameters
        self.completed_steps: dict[str, list[str]] = completed  # from earlier sessions and this one
        self.current_step: str | None = None
        self.num_events = num_events
        self._seq = seq
        self._fsync_interval_s = float(fsync_interval_s)
        self._lock = threading.RLock()
        self._fh = open(self.path, "ab")  # noqa: SIM115 — lives as long as the record
        # "open for writing" for other processes (record_is_open); shared: a resume in the same process may
        # open it again; released by close() or by the kernel when the process dies (a killed run)
        fcntl.flock(self._fh.fileno(), fcntl.LOCK_SH)
        self._last_fsync = time.monotonic()
        self._dirty = False  # written but not yet fsync'ed
        self._closing = threading.Event()
        self._syncer = threading.Thread(target=self._sync_loop, name="record-fsync", daemon=True)
        self._syncer.start()
        self._stopped = False
        self._writers: list[ObservationWriter] = []
        self._observers: list[Callable[[dict[str, Any]], None]] = []
        self._start_document: dict[str, Any] | None = None

    @property
    def run_id(self) -> str:
        return self.run_dir.name

    # ---------------------------------------------------------------- construction
    @classmethod
    def create(cls, runs_dir: str | os.PathLike[str], procedure: str, parameters: dict[str, Any],
               rig_snapshot: dict[str, Any], clock: _Clock, *, versions: dict[str, Any] | None = None,
               fsync_interval_s: float = 2.0, **start_fields: Any) -> RunRecord:
        """Create ``runs_dir/YYYYmmdd-HHMMSS_<procedure>_<uid8>/`` and write its ``start`` document."""
        if not procedure or not all(c.isalnum() or c in "_-" for c in procedure):
            raise RecordError(f"procedure name {procedure!r} not allowed in a folder name: use letters, "
                              "digits, '_' and '-'")
        uid = uuid.uuid4().hex
        stamp = _dt.datetime.now(_dt.UTC).strftime("%Y%m%d-%H%M%S")
        run_dir = Path(runs_dir) / f"{stamp}_{procedure}_{uid[:8]}"
        run_dir.mkdir(parents=True, exist_ok=False)
        rec = cls(run_dir, clock, session=0, fsync_interval_s=fsync_interval_s, seq={}, num_events=0,
                  completed={}, procedure=procedure, parameters=dict(parameters))
        rec._write("start", StartDocument(
            run_id=rec.run_id, uid=uid, procedure=procedure, parameters=parameters, rig=rig_snapshot,
            versions=collect_versions() if versions is None else versions,
            clock="virtual" if clock.is_virtual else "wall", resume=False, extra=start_fields).to_dict(),
            sync=True)
        return rec

    @classmethod
    def resume(cls, run_dir: str | os.PathLike[str], clock: _Clock, *, rig_snapshot: dict[str, Any],
               versions: dict[str, Any] | None = None, fsync_interval_s: float = 2.0,
               **start_fields: Any) -> RunRecord:
        """Reopen ``run_dir`` to continue it: repair a cut last line, then write a ``start`` (resume)."""
        run_dir = Path(run_dir)
        parsed = parse_record(run_dir / RECORD_NAME)
        docs = parsed.documents
        starts = [d for d in docs if d.get("type") == "start"]
        if not starts:
            raise RecordError(f"{run_dir}: the record has no start document; nothing to resume")
        last_stop = [d for d in docs if d.get("type") == "stop"]
        if last_stop and last_stop[-1].get("session", 0) == len(starts) - 1 \
                and last_stop[-1].get("exit_status") == "success":
            raise RecordError(f"{run_dir}: the run already completed successfully; nothing to resume")
        with open(run_dir / RECORD_NAME, "r+b") as fh:  # drop a partial line, terminate a complete one
            fh.truncate(parsed.valid_length)
            if parsed.valid_length:
                fh.seek(parsed.valid_length - 1)
                if fh.read(1) != b"\n":
                    fh.write(b"\n")
            fh.flush()
            os.fsync(fh.fileno())
        seq: dict[str, int] = {}
        completed: dict[str, list[str]] = {}
        for d in docs:
            if d.get("type") == "event":
                seq[str(d.get("stream"))] = max(seq.get(str(d.get("stream")), 0), int(d.get("seq", -1)) + 1)
            elif d.get("type") == "step" and d.get("status") == "done":
                completed[str(d["name"])] = list(d.get("outputs") or [])
        first = starts[0]
        rec = cls(run_dir, clock, session=len(starts), fsync_interval_s=fsync_interval_s, seq=seq,
                  num_events=sum(1 for d in docs if d.get("type") == "event"), completed=completed,
                  procedure=str(first["procedure"]), parameters=dict(first.get("parameters") or {}))
        rec._write("start", StartDocument(
            run_id=rec.run_id, uid=first.get("uid"), procedure=rec.procedure, parameters=rec.parameters,
            rig=rig_snapshot, versions=collect_versions() if versions is None else versions,
            clock="virtual" if clock.is_virtual else "wall", resume=True, completed_steps=sorted(completed),
            extra=start_fields).to_dict(), sync=True)
        if parsed.truncated_last_line:
            rec.log("warning", "previous session ended mid-line; its truncated last line was removed: "
                    + parsed.partial_bytes.decode("utf-8", errors="replace"))
        return rec

    # ---------------------------------------------------------------- documents
    def _write(self, doc_type: str, fields: dict[str, Any], *, sync: bool = False) -> dict[str, Any]:
        with self._lock:
            if self._fh.closed:
                raise RecordError(f"{self.path}: record is closed; cannot write a {doc_type!r} document")
            doc = {"type": doc_type, "time_s": float(self.clock.now_s()),
                   "wall_utc": _dt.datetime.now(_dt.UTC).isoformat(timespec="microseconds"),
                   "session": self.session, **fields}
            clean: dict[str, Any] = to_jsonable(doc)
            text = json.dumps(clean, ensure_ascii=False, separators=(",", ":"), allow_nan=False)
            line = text.encode("utf-8") + b"\n"
            self._fh.write(line)
            self._fh.flush()
            now = time.monotonic()
            if sync or now - self._last_fsync >= self._fsync_interval_s:
                os.fsync(self._fh.fileno())
                self._last_fsync = now
                self._dirty = False
            else:
                self._dirty = True
            if doc_type == "start":
                self._start_document = clean
            for observer in self._observers:
                _offer(observer, clean)
            return clean

    def add_observer(self, observer: Callable[[dict[str, Any]], None]) -> None:
        """Offer every document written from now on to ``observer(document)`` (in the writing thread, after
        the line is written; it must return quickly, and an exception in it is logged, never raised), and at
        once this session's ``start`` document when it was already written. For live views."""
        with self._lock:
            self._observers.append(observer)
            if self._start_document is not None:
                _offer(observer, self._start_document)

    def _sync_loop(self) -> None:
        """fsync what was written but not yet synced, every ``fsync_interval_s`` (a quiet record too)."""
        while not self._closing.wait(self._fsync_interval_s):
            with self._lock:
                if self._dirty and not self._fh.closed:
                    os.fsync(self._fh.fileno())
                    self._last_fsync = time.monotonic()
                    self._dirty = False

    def step_begin(self, name: str) -> None:
        """Record that step ``name`` begins; events and observations are tagged with it until done."""
        with self._lock:
            self.current_step = name
            self._write("step", {"name": name, "status": "begin", "outputs": []}, sync=True)

    def step_done(self, name: str, outputs: list[str] | None = None) -> None:
        """Record that step ``name`` completed, with ``outputs`` (paths relative to the run folder)."""
        outs = [Path(o).as_posix() for o in (outputs or [])]
        with self._lock:
            for writer in self._writers:
                writer.flush()
            self._write("step", {"name": name, "status": "done", "outputs": outs}, sync=True)
            self.completed_steps[name] = outs
            if self.current_step == name:
                self.current_step = None

    def event(self, stream: str, data: dict[str, Any] | Event) -> int:
        """Record one event of ``stream`` with ``data`` (a typed :class:`rig.record.events.Event` of that
        stream, or a free-form dict for streams without a schema); return its ``seq`` (0, 1, … per stream)."""
        if isinstance(data, Event):
            if stream != data.STREAM:
                raise ValueError(f"a {type(data).__name__} is an event of stream {data.STREAM!r}, "
                                 f"not {stream!r}")
            data = data.to_dict()
        if not isinstance(data, dict):
            raise TypeError(f"event data for stream {stream!r} must be a dict, not {type(data).__name__}")
        with self._lock:
            seq = self._seq.get(stream, 0)
            self._write("event", {"stream": stream, "seq": seq, "step": self.current_step, "data": data})
            self._seq[stream] = seq + 1
            self.num_events += 1
            return seq

    def interlock(self, device: str, reason: str) -> None:
        """Record an interlock trip on ``device`` (fsync'ed at once)."""
        self._write("interlock", InterlockDocument(device, reason).to_dict(), sync=True)

    def log(self, level: str, message: str) -> None:
        """Record a log message; ``level`` is one of debug, info, warning, error, critical."""
        if level not in LOG_LEVELS:
            raise ValueError(f"log level {level!r} not allowed; allowed: {', '.join(LOG_LEVELS)}")
        self._write("log", {"level": level, "message": message})

    def stop(self, exit_status: str, reason: str = "", **fields: Any) -> None:
        """Write the ``stop`` document (once per session) and fsync; flushes observation writers first."""
        if exit_status not in EXIT_STATUSES:
            raise ValueError(f"exit_status {exit_status!r} not allowed; allowed: {', '.join(EXIT_STATUSES)}")
        with self._lock:
            if self._stopped:
                raise RecordError(f"{self.path}: stop already written for session {self.session}")
            for writer in self._writers:
                writer.close()
            self._write("stop", StopDocument(exit_status, reason, self.num_events, extra=fields).to_dict(),
                        sync=True)
            self._stopped = True

    @property
    def stopped(self) -> bool:
        return self._stopped

    # ---------------------------------------------------------------- side files
    def observation_writer(self, camera: str, **kwargs: Any) -> ObservationWriter:
        """Return a writer of ``observations/<camera>/`` stamped with this session and the current step."""
        writer = ObservationWriter(self.run_dir, camera, session=self.session,
                                   segment=kwargs.pop("segment", self.current_step or ""), **kwargs)
        self._writers.append(writer)
        return writer

    def path_for(self, relative: str | os.PathLike[str]) -> Path:
        """Absolute path of an output inside the run folder (refuses paths that leave it)."""
        target = (self.run_dir / relative).resolve()
        if not target.is_relative_to(self.run_dir.resolve()):
            raise RecordError(f"output path {relative!s} leaves the run folder {self.run_dir}")
        return target

    def close(self) -> None:
        """Flush observation writers, fsync and close the file (idempotent)."""
        self._closing.set()
        with self._lock:
            for writer in self._writers:
                writer.close()
            if not self._fh.closed:
                self._fh.flush()
                os.fsync(self._fh.fileno())
                self._fh.close()

    def __enter__(self) -> RunRecord:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
