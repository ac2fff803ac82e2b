"""Marker observations of the run folder: crash-safe Parquet part files, one folder per camera.

Layout (the choice and why)::

    observations/<camera>/part-00000.parquet
    observations/<camera>/part-00001.parquet
    ...

A Parquet file is only readable once its footer is written, so one long-lived ``ParquetWriter`` per
camera would lose *everything* if the process is killed (``kill -9``, power cut). Instead the writer
buffers rows and writes each chunk as a complete, self-contained Parquet file: written to
``part-NNNNN.parquet.tmp``, fsync'ed, then atomically renamed. A crash loses at most the chunk in
memory or in flight (a ``.tmp`` file, ignored by readers). Chunks are flushed when the buffer holds
``chunk_rows`` rows, when ``flush_interval_s`` of wall time has passed since the last flush (checked on
each append), and on :meth:`ObservationWriter.flush` / :meth:`ObservationWriter.close` — the runner
closes every writer at the end of each step, so completed steps are always complete on disk.

Columns (``OBSERVATION_COLUMNS``; units in the names): ``frame_index`` (int64), ``timestamp_s``
(float64, camera clock), ``row_time_s`` (float64, NaN until analysis knows the line time), ``u_px``,
``v_px``, ``area_px``, ``roundness``, ``contrast`` (float64), ``flags`` (uint8, the stereo core's
``FLAG_*`` bits), ``segment`` (str, the step that recorded it) and ``session`` (int64: 0 for the first
start of the run, 1 after the first ``--resume``, …). Extra columns are allowed and kept.
"""

from __future__ import annotations

import os
import re
import time
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

# pandas and pyarrow are imported where rows are written or read: the runner (through the record writer)
# loads this module without them, so a run refused before it records does without (tests/test_cli_start.py)
if TYPE_CHECKING:
    import pandas as pd
    import pyarrow as pa

OBSERVATIONS_DIR = "observations"
OBSERVATION_COLUMNS: dict[str, str] = {
    "frame_index": "int64", "timestamp_s": "float64", "row_time_s": "float64",
    "u_px": "float64", "v_px": "float64", "area_px": "float64", "roundness": "float64",
    "contrast": "float64", "flags": "uint8", "segment": "object", "session": "int64",
}
_DEFAULTS: dict[str, Any] = {"row_time_s": np.nan, "area_px": np.nan, "roundness": np.nan,
                             "contrast": np.nan, "flags": 0}
_PART_RE = re.compile(r"^part-(\d{5,})\.parquet$")
_CAMERA_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")


class ObservationWriter:
    """Append marker observations of one camera to ``run_dir/observations/<camera>/``.

    Args:
        run_dir: the run folder.
        camera: camera name (letters, digits, ``_ . -``; 1–64 characters).
        session: the record's session number (stamped into every row).
        segment: default ``segment`` for rows that do not carry one (the runner passes the current step).
        chunk_rows: rows buffered before a part file is written (≥ 1).
        flush_interval_s: wall-clock seconds after which a non-empty buffer is written on the next append.
    """

    def __init__(self, run_dir: str | os.PathLike[str], camera: str, *, session: int = 0, segment: str = "",
                 chunk_rows: int = 50_000, flush_interval_s: float = 5.0) -> None:
        if not _CAMERA_RE.match(camera):
            raise ValueError(f"camera name {camera!r} not allowed: use 1-64 letters, digits, '_', '.', '-'")
        if chunk_rows < 1:
            raise ValueError(f"chunk_rows={chunk_rows} must be >= 1")
        self.camera = camera
        self.session = int(session)
        self.segment = segment
        self.directory = Path(run_dir) / OBSERVATIONS_DIR / camera
        self.directory.mkdir(parents=True, exist_ok=True)
        self._chunk_rows = int(chunk_rows)
        self._flush_interval_s = float(flush_interval_s)
        self._columns: dict[str, list[np.ndarray]] = {}  # column → buffered chunks
        self._buffered_rows = 0
        self._last_flush = time.monotonic()
        existing = [int(m.group(1)) for p in self.directory.iterdir() if (m := _PART_RE.match(p.name))]
        self._next_part = max(existing, default=-1) + 1
        self.rows_written = 0
        self._closed = False

    def append(self, rows: pd.DataFrame | Mapping[str, Any] | np.ndarray, *, segment: str | None = None,
               frame_index: int | None = None, timestamp_s: float | None = None) -> None:
        """Buffer observation rows.

        ``rows`` is a DataFrame, a mapping of equal-length columns, or a structured array (e.g. the
        stereo core's ``MARKER_DTYPE``). ``frame_index`` / ``timestamp_s`` / ``segment`` given here fill
        (or override) those columns for every row — handy for one frame's detections.
        """
        if self._closed:
            raise RuntimeError(f"observation writer for camera {self.camera!r} is closed")
        columns = _as_columns(rows)
        n = len(next(iter(columns.values()))) if columns else 0
        if any(len(v) != n for v in columns.values()):
            lengths = {k: len(v) for k, v in columns.items()}
            raise ValueError(f"observation columns differ in length: {lengths}")
        if frame_index is not None:
            columns["frame_index"] = np.full(n, int(frame_index), dtype=np.int64)
        if timestamp_s is not None:
            columns["timestamp_s"] = np.full(n, float(timestamp_s))
        if segment is not None or "segment" not in columns:
            columns["segment"] = np.full(n, self.segment if segment is None else segment, dtype=object)
        missing = [c for c in ("frame_index", "timestamp_s", "u_px", "v_px") if c not in columns]
        if missing:
            raise ValueError(f"observation rows lack required column(s) {missing}; required: frame_index, "
                             "timestamp_s, u_px, v_px")
        if n == 0:
            return
        for name, default in _DEFAULTS.items():
            if name not in columns:
                columns[name] = np.full(n, default)
        columns["session"] = np.full(n, self.session, dtype=np.int64)
        for name in set(self._columns) | set(columns):
            if name not in self._columns:  # a new (extra) column: earlier rows of the chunk get "no value"
                self._columns[name] = [np.full(self._buffered_rows, None, dtype=object)] \
                    if self._buffered_rows else []
            if name in columns:
                dtype = OBSERVATION_COLUMNS.get(name)
                value = np.asarray(columns[name])
                self._columns[name].append(value.astype(dtype) if dtype not in (None, "object") else value)
            else:
                self._columns[name].append(np.full(n, None, dtype=object))
        self._buffered_rows += n
        if self._buffered_rows >= self._chunk_rows or (
                time.monotonic() - self._last_flush >= self._flush_interval_s):
            self.flush()

    def _table(self) -> pa.Table:
        import pyarrow as pa

        arrays, names = [], []
        ordered = list(OBSERVATION_COLUMNS) + sorted(c for c in self._columns if c not in OBSERVATION_COLUMNS)
        for name in ordered:
            parts = self._columns[name]
            if name == "segment":
                arrays.append(pa.array([str(v) for p in parts for v in p], type=pa.string()))
            else:
                value = np.concatenate(parts)
                if value.dtype == object:  # an extra column, possibly with gaps
                    arrays.append(pa.array(value.tolist()))
                else:
                    arrays.append(pa.array(value))
            names.append(name)
        return pa.Table.from_arrays(arrays, names=names)

    def flush(self) -> Path | None:
        """Write the buffered rows as one new part file (atomic rename); return its path or None."""
        import pyarrow.parquet as pq

        self._last_flush = time.monotonic()
        if not self._buffered_rows:
            return None
        table = self._table()
        final = self.directory / f"part-{self._next_part:05d}.parquet"
        tmp = final.with_name(final.name + ".tmp")
        with open(tmp, "wb") as fh:
            pq.write_table(table, fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, final)
        _fsync_dir(self.directory)
        self._next_part += 1
        self.rows_written += self._buffered_rows
        self._columns = {}
        self._buffered_rows = 0
        return final

    def close(self) -> None:
        """Flush what is buffered; further appends raise."""
        if not self._closed:
            self.flush()
            self._closed = True

    def __enter__(self) -> ObservationWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _as_columns(rows: pd.DataFrame | Mapping[str, Any] | np.ndarray) -> dict[str, np.ndarray]:
    if isinstance(rows, np.ndarray):
        if rows.dtype.names is None:
            raise TypeError("observation rows as an array must be a structured array with named fields")
        return {name: rows[name] for name in rows.dtype.names}
    if isinstance(rows, Mapping):
        return {str(k): np.atleast_1d(np.asarray(v)) for k, v in rows.items()}
    import pandas as pd  # last: a DataFrame is neither an array nor a Mapping

    if isinstance(rows, pd.DataFrame):
        return {str(c): rows[c].to_numpy() for c in rows.columns}
    raise TypeError("observation rows must be a DataFrame, mapping or structured array, "
                    f"not {type(rows).__name__}")


def _fsync_dir(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def observation_cameras(run_dir: str | os.PathLike[str]) -> list[str]:
    """Return the names of the cameras that have an observations folder in ``run_dir`` (sorted)."""
    root = Path(run_dir) / OBSERVATIONS_DIR
    if not root.is_dir():
        return []
    return sorted(p.name for p in root.iterdir() if p.is_dir())


def read_observations(run_dir: str | os.PathLike[str], camera: str) -> pd.DataFrame:
    """Return every complete part file of ``camera`` concatenated, in part order.

    Left-over ``.tmp`` files (a chunk in flight when the writer died) are ignored; a part file that
    cannot be read is skipped with a :class:`RuntimeWarning` naming it. An empty frame with the
    standard columns is returned when there is nothing.
    """
    import pandas as pd
    import pyarrow as pa
    import pyarrow.parquet as pq

    directory = Path(run_dir) / OBSERVATIONS_DIR / camera
    parts = sorted((int(m.group(1)), p) for p in directory.glob("part-*.parquet")
                   if (m := _PART_RE.match(p.name))) if directory.is_dir() else []
    frames = []
    for _, path in parts:
        try:
            frames.append(pq.read_table(path).to_pandas())
        except (OSError, pa.ArrowInvalid) as exc:
            warnings.warn(f"skipping unreadable observation part {path}: {exc}", RuntimeWarning, stacklevel=2)
    if not frames:
        return pd.DataFrame({name: pd.Series(dtype=dtype) for name, dtype in OBSERVATION_COLUMNS.items()})
    return pd.concat(frames, ignore_index=True)
