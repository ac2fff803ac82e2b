"""``rig batch``: the measurement of ``rig measure`` over a monitoring archive, as tasks on Dask.

One **task** per matched segment pair (:mod:`rig.deploy.batch_manifest`) runs
:func:`rig.deploy.measure.measure_videos`
on a worker — the same code as ``rig measure`` — and writes its results straight into the output folder;
only file paths and a small outcome dictionary travel through the scheduler, never frames:

``DIR/``
  ``segments/site=S/pair=P/date=YYYY-MM-DD/<task>.parquet``   per-target summary of each segment (amplitude,
      frequency, RMS, rest position, sine-fit uncertainty) with the segment's timing and quality columns
  ``displacement/site=S/pair=P/date=YYYY-MM-DD/<task>.parquet``  the displacement series, ``time_utc``
      = the segment's start (from its file name) + the reference video's time stamp
  ``tasks/<task>.json``   each task's outcome, written last: a task whose file says ``done`` is finished
  ``work/<task>/``        what ``rig measure`` wrote for the segment (timing.json, measure.json, tables)
  ``batch.jsonl``         the batch record: per run of the batch a start (manifest hash, versions), one
      document per task outcome and unmatched segment, the timing continuity per pair, a stop
  ``continuity.csv``, ``trend.csv``   timing continuity across segments; per target over the archive

A recording longer than two windows (``window_s`` of its pair in the manifest) is split into windows
``[k·window_s, (k + 1)·window_s)`` of the reference file's clock (the last one takes the tail), each a task:
``rig measure``'s code on the frames of the window ± ``overlap_s`` (reached by a verified frame-exact seek,
:mod:`drivers.camera.seek`, so a window late in a long file costs no more than an early one), the
summary over the window alone and the displacement series trimmed to it, so consecutive windows join
without a duplicate or a gap. Each window's timing is estimated on its own and checked for continuity with
the others like the segments' (below) — unless the pair gives a ``timing`` file, which then serves every
task of the pair (``rig measure --timing``), with no continuity check.

A task is named by the hash of its inputs (video names, sizes and modification times, the calibration's
and the timing file's bytes, the options, the software version): a rerun skips every task whose outcome
file says ``done`` for the same inputs, so a batch killed at any instant carries on where it stopped. A
failing task is retried ``max_retries`` times by Dask, then reported as failed (with the error) — never
silently dropped.

The engine is ``dask.distributed``: without ``scheduler`` a ``LocalCluster`` of one single-threaded worker
process per usable core (a container's CPU quota included) on 127.0.0.1; with
``scheduler="tcp://HOST:8786"`` the same tasks go to an existing cluster (``dask scheduler`` / ``dask
worker``, dask-jobqueue, Kubernetes), whose workers must see the same paths (a shared file system) and
have this package installed.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import hashlib
import json
import math
import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from drivers.cores import usable_cores
from rig.deploy.batch_manifest import BatchManifest, PairSpec, Segment, match_segments
from rig.record.atomic import atomic_path

SOFTWARE = "rig-controller batch 1"
TARGET_GATE_MM = 20.0  # rest positions of one target in different segments lie closer than this
JUMP_SIGMAS = 4.0  # a timing residual beyond this many standard uncertainties is reported as a jump
JUMP_FLOOR_S = 20e-6  # … and beyond this floor (the joint estimate's reach on a good segment)


@dataclass(frozen=True)
class Task:
    """One segment pair of one camera pair: what a worker measures."""

    task_id: str
    site: str
    pair: str
    start_utc: dt.datetime
    left: Path
    right: Path
    calibration: Path
    sync: str
    reference_markers: str | tuple[tuple[float, float, float], ...]
    static_mm: float
    # a window of a long recording: its core (start, end) on the reference file's clock (s; the last window's
    # end is inf), measured overlap_s longer at both ends and trimmed back to it; None: the whole files
    core_s: tuple[float, float] | None = None
    overlap_s: float = 0.0
    timing: Path | None = None  # the pair's timing.json (rig measure --timing); None: estimated per task

    @property
    def partition(self) -> str:
        """The hive partition path of this task's results."""
        return f"site={self.site}/pair={self.pair}/date={self.start_utc.date().isoformat()}"


@dataclass
class BatchReport:
    """What a run of the batch did (counts per outcome, unmatched segments, continuity, files)."""

    out_dir: Path
    done: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)
    unmatched: list[str] = field(default_factory=list)
    jumps: list[str] = field(default_factory=list)
    seconds: float = 0.0
    video_seconds: float = 0.0


# ---------------------------------------------------------------------------- planning
def _file_identity(path: Path) -> dict[str, Any]:
    st = path.stat()
    return {"name": path.name, "size": st.st_size, "mtime_ns": st.st_mtime_ns}


def task_id(pair: PairSpec, left: Segment, right: Segment,
            core_s: tuple[float, float] | None = None) -> str:
    """The hash of a task's inputs: equal ids ⇔ the same videos, window, calibration, options, software."""
    identity: dict[str, Any] = {
        "software": SOFTWARE, "site": pair.site, "pair": pair.name,
        "left": _file_identity(left.path), "right": _file_identity(right.path),
        "calibration": hashlib.sha256(pair.calibration.read_bytes()).hexdigest(),
        "sync": pair.sync, "reference_markers": pair.reference_markers, "static_mm": pair.static_mm,
    }
    if core_s is not None:
        identity["core_s"] = [core_s[0], str(core_s[1])]  # str: inf is no JSON number
        identity["overlap_s"] = pair.overlap_s
    if pair.timing is not None:
        identity["timing"] = hashlib.sha256(pair.timing.read_bytes()).hexdigest()
    return hashlib.sha256(json.dumps(identity, sort_keys=True).encode()).hexdigest()[:20]


def video_duration_s(path: Path) -> float:
    """The recording's length from its container (frame count / rate, s; 0 when unknown)."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    try:
        fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        frames = float(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0.0)
    finally:
        cap.release()
    return frames / fps if fps > 0 else 0.0


def windows(duration_s: float, window_s: float) -> list[tuple[float, float]]:
    """Cores of the windows of a recording of ``duration_s``: [k·window_s, (k + 1)·window_s), the last one
    open-ended ((k·window_s, inf): it takes the tail, so it lasts window_s to 2·window_s); one window
    (0, inf) when the recording is shorter than two windows or ``window_s`` is 0."""
    n = int(duration_s // window_s) if window_s > 0 else 1
    if n <= 1:
        return [(0.0, math.inf)]
    return [(k * window_s, (k + 1) * window_s if k < n - 1 else math.inf) for k in range(n)]


def plan(manifest: BatchManifest) -> tuple[list[Task], list[Segment]]:
    """Every task of the manifest (time order per pair) and the segments left without a partner; a pair
    with ``window_s`` gets a task per window of each recording longer than two windows."""
    tasks: list[Task] = []
    alone: list[Segment] = []
    for pair in manifest.pairs:
        matched, unmatched = match_segments(pair.left, pair.right, manifest.match_tolerance_s)
        alone += unmatched
        for left, right in matched:
            cores = windows(video_duration_s(left.path), pair.window_s) if pair.window_s else [None]
            tasks += [Task(task_id=task_id(pair, left, right, core), site=pair.site, pair=pair.name,
                           start_utc=left.start_utc + dt.timedelta(seconds=core[0] if core else 0.0),
                           left=left.path, right=right.path, calibration=pair.calibration, sync=pair.sync,
                           reference_markers=pair.reference_markers, static_mm=pair.static_mm,
                           core_s=core if core and len(cores) > 1 else None, overlap_s=pair.overlap_s,
                           timing=pair.timing)
                      for core in cores]
    return tasks, alone


# ---------------------------------------------------------------------------- one task (on a worker)
def _write_text(path: Path, text: str) -> None:
    path.write_text(text, encoding="utf-8")


def _write_atomic(path: Path, write: Callable[[Path], None]) -> None:
    """Write ``path`` through a temporary name in its folder, then rename
    (:func:`rig.record.atomic.atomic_path`)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        write(tmp)


def _timing_columns(timing: dict[str, Any], reference: str) -> dict[str, float]:
    """The second camera's offset, drift and line time (s, ppm), the offset's uncertainty, and
    ``offset_candidates``: how many offsets explain the motion equally well (1: decided; more: whole
    periods of a steady motion the videos cannot tell apart, the offset is one of them — see the task's
    timing.json; NaN: no coarse search on record, e.g. a timing given from elsewhere)."""
    other = next((c for c in timing.get("offset_s", {}) if c != reference), None)
    if other is None:
        return {}
    unc = timing.get("uncertainty", {}) or {}

    def value(table: Any) -> float:
        return float(table.get(other, np.nan)) if isinstance(table, dict) else np.nan

    return {"offset_s": value(timing["offset_s"]), "u_offset_s": value(unc.get("offset_s")),
            "offset_candidates": _offset_candidates(timing),
            "drift_ppm": value(timing.get("drift_ppm")), "u_drift_ppm": value(unc.get("drift_ppm")),
            "line_time_s": value(timing.get("line_time_s"))}


def _offset_candidates(timing: dict[str, Any]) -> float:
    """How many offsets of the coarse search explain the motion equally well (rig.deploy.video_timing)."""
    coarse = (timing.get("details") or {}).get("coarse")
    if not coarse:
        return np.nan
    if not coarse.get("ambiguous"):
        return 1.0
    return float(max(1, sum(1 for c in coarse["candidates"] if "error" not in c and not c["distinct"])))


def run_task(task: Task, out_dir: str) -> dict[str, Any]:
    """Measure one segment pair and write its results (runs on a Dask worker); the outcome dictionary.

    Raises what the measurement raises (Dask retries the task, then the batch reports it failed).
    """
    from rig.deploy.measure import MeasureOptions, measure_videos
    from rig.deploy.video_markers import ExtractOptions

    out = Path(out_dir)
    t0 = time.perf_counter()
    work = out / "work" / task.task_id
    options = MeasureOptions(sync=task.sync, reference_markers=task.reference_markers,
                             static_mm=task.static_mm)
    if task.core_s is not None:  # a window: frames of the core ± overlap; summary over the core alone
        start_s, end_s = task.core_s
        extract = ExtractOptions(start_s=start_s - task.overlap_s if start_s > 0 else None,
                                 stop_s=end_s + task.overlap_s if math.isfinite(end_s) else None)
        # the last window's summary to the end (the largest float: measure.json stays strict JSON)
        last_s = end_s if math.isfinite(end_s) else sys.float_info.max
        options = dataclasses.replace(options, extract=extract, window_s=(start_s, last_s))
    result = measure_videos({"left": task.left, "right": task.right}, task.calibration, work, options=options,
                            timing=task.timing, force=True)  # its own work folder: a retry replaces it
    timing = _timing_columns(result.timing, "left")
    displacement = result.displacement
    if task.core_s is not None:  # trimmed to the core: windows join without a duplicate or a gap
        t_s = displacement["time_s"].to_numpy(float)
        displacement = displacement[(t_s >= task.core_s[0]) & (t_s < task.core_s[1])].reset_index(drop=True)
    video_s = float(displacement["time_s"].max() - displacement["time_s"].min()) \
        if not displacement.empty else 0.0
    summary = result.summary.copy()
    summary.insert(0, "task_id", task.task_id)
    summary.insert(1, "segment_start_utc", pd.Timestamp(task.start_utc))
    for key, value in timing.items():
        summary[key] = value
    summary["problems"] = len(result.problems)
    summary["duration_s"] = video_s
    series = displacement.copy()
    file_start = pd.Timestamp(task.start_utc) - pd.Timedelta(seconds=task.core_s[0] if task.core_s else 0.0)
    series.insert(0, "time_utc", file_start + pd.to_timedelta(series["time_s"], unit="s"))
    series.insert(0, "task_id", task.task_id)
    name = f"{task.task_id}.parquet"
    _write_atomic(out / "segments" / task.partition / name, lambda p: summary.to_parquet(p, index=False))
    _write_atomic(out / "displacement" / task.partition / name, lambda p: series.to_parquet(p, index=False))
    outcome = {"task_id": task.task_id, "site": task.site, "pair": task.pair,
               "start_utc": task.start_utc.isoformat(), "left": str(task.left), "right": str(task.right),
               "status": "done", "seconds": time.perf_counter() - t0, "video_s": video_s,
               "problems": result.problems, "timing": timing,
               "timing_file": None if task.timing is None else str(task.timing),
               "core_s": None if task.core_s is None else [task.core_s[0], task.core_s[1]
                                                           if math.isfinite(task.core_s[1]) else None],
               "targets": int((summary["role"] == "target").sum()) if "role" in summary else None}
    _write_atomic(out / "tasks" / f"{task.task_id}.json",
                  lambda p: _write_text(p, json.dumps(outcome, indent=1)))
    return outcome


def finished(out_dir: Path, task: Task) -> dict[str, Any] | None:
    """The outcome of a task finished by an earlier run (same inputs), or None."""
    path = out_dir / "tasks" / f"{task.task_id}.json"
    try:
        outcome = json.loads(path.read_text(encoding="utf-8"))
    except (FileNotFoundError, ValueError):
        return None
    return outcome if outcome.get("status") == "done" else None


# ---------------------------------------------------------------------------- the record
class BatchRecord:
    """``batch.jsonl``: append-only, one JSON document a line, flushed and fsync'ed per line."""

    def __init__(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(path, "a", encoding="utf-8")  # noqa: SIM115 — closed by close()

    def write(self, doc_type: str, **fields: Any) -> None:
        doc = {"type": doc_type, "wall_utc": dt.datetime.now(dt.UTC).isoformat(), **fields}
        self._file.write(json.dumps(doc, default=str) + "\n")
        self._file.flush()
        os.fsync(self._file.fileno())

    def close(self) -> None:
        self._file.close()


def _versions() -> dict[str, str]:
    import dask
    import distributed

    return {"software": SOFTWARE, "python": sys.version.split()[0], "dask": dask.__version__,
            "distributed": distributed.__version__, "numpy": np.__version__, "pandas": pd.__version__}


# ---------------------------------------------------------------------------- the engine
@contextmanager
def dask_client(scheduler: str | None, n_workers: int | None) -> Iterator[Any]:
    """A client of the scheduler at ``scheduler``, or of a new LocalCluster (``n_workers`` processes, or one
    per core this process may use — :func:`drivers.cores.usable_cores`, a container's CPU quota included —
    single-threaded, on 127.0.0.1; its dashboard on a free port) that is shut down on exit with its
    worker processes (closing a client alone leaves a cluster it was handed running)."""
    from distributed import Client, LocalCluster

    if scheduler:
        with Client(scheduler, timeout="30s") as client:
            yield client
        return
    with (LocalCluster(n_workers=n_workers or usable_cores(), threads_per_worker=1, processes=True,
                       host="127.0.0.1", dashboard_address="127.0.0.1:0") as cluster,
          Client(cluster) as client):
        yield client


def run_batch(manifest: BatchManifest, out_dir: str | Path, *, scheduler: str | None = None,
              n_workers: int | None = None, say: Callable[[str], None] = print,
              show_progress: bool = False) -> BatchReport:
    """Run (or resume) the batch of ``manifest`` into ``out_dir``; see the module docstring."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    tasks, alone = plan(manifest)
    run = _BatchRun(out, BatchRecord(out / "batch.jsonl"), BatchReport(out), say, show_progress)
    try:
        run.record.write("start", batch=manifest.name, manifest=str(manifest.source),
                         manifest_sha256=manifest.sha256, versions=_versions(), tasks=len(tasks),
                         scheduler=scheduler or "LocalCluster")
        for seg in alone:
            run.report.unmatched.append(str(seg.path))
            run.record.write("unmatched", path=str(seg.path), start_utc=seg.start_utc.isoformat(),
                             reason="no segment of the other camera starts within "
                                    f"{manifest.match_tolerance_s:g} s")
        todo = [t for t in tasks if finished(out, t) is None]
        run.report.skipped = [t.task_id for t in tasks if t not in todo]
        say(f"rig batch: {len(tasks)} tasks ({len(run.report.skipped)} already done, {len(todo)} to run), "
            f"{len(alone)} unmatched segments")
        if todo:
            with dask_client(scheduler, n_workers) as client:
                run.execute(client, todo, manifest.max_retries)
        run.summarise(tasks)
    finally:
        run.report.seconds = time.perf_counter() - t0
        r = run.report
        run.record.write("stop", done=len(r.done), skipped=len(r.skipped), failed=len(r.failed),
                         unmatched=len(r.unmatched), seconds=r.seconds)
        run.record.close()
    return run.report


@dataclass
class _BatchRun:
    """One run of a batch: where it writes, its record and report, how it talks to the user."""

    out: Path
    record: BatchRecord
    report: BatchReport
    say: Callable[[str], None]
    show_progress: bool

    def execute(self, client: Any, todo: list[Task], max_retries: int) -> None:
        """Submit the tasks to the cluster, follow them to the end and record every outcome."""
        from distributed import as_completed
        from distributed.diagnostics.progressbar import progress

        link = client.dashboard_link
        self.say(f"rig batch: Dask scheduler {client.scheduler.address}"
                 + (f", dashboard {link}" if link else ""))
        futures = [client.submit(run_task, task, str(self.out), key=f"rig-batch-{task.task_id}",
                                 retries=max_retries, pure=False) for task in todo]
        by_key = {f.key: t for f, t in zip(futures, todo, strict=True)}
        if self.show_progress:
            progress(futures, notebook=False)
        for future in as_completed(futures):
            task = by_key[future.key]
            if future.status == "finished":
                self._done(task, future.result())
            else:
                self._failed(task, future.exception(), attempts=max_retries + 1)

    def _done(self, task: Task, outcome: dict[str, Any]) -> None:
        self.report.done.append(task.task_id)
        self.report.video_seconds += float(outcome.get("video_s", 0.0))
        self.record.write("task", **outcome)
        if not self.show_progress:
            self.say(f"  done {task.site}/{task.pair} {task.start_utc.isoformat()} "
                     f"({outcome['seconds']:.1f} s)")

    def _failed(self, task: Task, exc: BaseException, attempts: int) -> None:
        error = f"{type(exc).__name__}: {exc}"
        self.report.failed[task.task_id] = error
        self.record.write("task", task_id=task.task_id, site=task.site, pair=task.pair,
                          start_utc=task.start_utc.isoformat(), left=str(task.left), right=str(task.right),
                          status="failed", attempts=attempts, error=error)
        self.say(f"  FAILED {task.site}/{task.pair} {task.start_utc.isoformat()} after {attempts} attempts: "
                 f"{error}")

    def summarise(self, tasks: list[Task]) -> None:
        """Timing continuity per pair and the per-target trend over every finished task of the manifest."""
        outcomes = [o for o in (finished(self.out, t) for t in tasks) if o is not None]
        continuity = timing_continuity(outcomes)
        if not continuity.empty:
            _write_atomic(self.out / "continuity.csv", lambda p: continuity.to_csv(p, index=False))
            for row in continuity[continuity["jump"]].itertuples():
                self.report.jumps.append(
                    f"{row.site}/{row.pair}: timing jump of {row.residual_s * 1e3:+.3f} ms at the segment "
                    f"starting {row.start_utc} (u {row.u_residual_s * 1e3:.3f} ms)")
            pairs = sorted(set(continuity["site"] + "/" + continuity["pair"]))
            self.record.write("continuity", pairs=pairs, jumps=self.report.jumps)
        trend = target_trend(self.out)
        if not trend.empty:
            _write_atomic(self.out / "trend.csv", lambda p: trend.to_csv(p, index=False))


def timing_continuity(outcomes: Iterable[dict[str, Any]], frame_period_s: float = 1 / 60) -> pd.DataFrame:
    """Per pair, the second camera's sub-frame offset across segments against one drift model.

    Within a pair the two cameras' sub-frame phase (offset modulo a frame period) advances by the drift
    between segments: ``φ_k ≈ φ_{k−1} + drift·(t_k − t_{k−1})`` (mod T), with drift the weighted mean of
    the segments' estimates (weights 1/u²). A residual beyond ``JUMP_SIGMAS`` standard uncertainties (and
    beyond ``JUMP_FLOOR_S``) is a jump — a camera restarted, dropped frames, or a wrong estimate —
    reported, not smoothed over. The first segment of a pair has no residual. Segments measured with a given
    timing (``timing_file``) are left out: their timing was not estimated, there is nothing to check.
    """
    rows = []
    keys = ("site", "pair", "start_utc", "task_id")
    frame = pd.DataFrame([{**{k: o[k] for k in keys}, **o.get("timing", {})} for o in outcomes
                          if not o.get("timing_file")])
    if frame.empty or "offset_s" not in frame:
        return pd.DataFrame()
    frame = frame.dropna(subset=["offset_s"]).sort_values("start_utc")
    for (site, pair), g in frame.groupby(["site", "pair"], sort=True):
        drift, u_drift = g["drift_ppm"].to_numpy(float), g["u_drift_ppm"].to_numpy(float)
        ok = np.isfinite(drift) & np.isfinite(u_drift) & (u_drift > 0)
        weights = 1.0 / u_drift[ok] ** 2
        drift_ppm = float(np.sum(weights * drift[ok]) / weights.sum()) if ok.any() else 0.0
        u_drift_ppm = float(1.0 / np.sqrt(weights.sum())) if ok.any() else np.nan
        # ISO 8601 as written: whole seconds for segments, fractions for windows of a fractional window_s
        starts = pd.to_datetime(g["start_utc"], format="ISO8601").to_numpy()
        phase = np.mod(g["offset_s"].to_numpy(float), frame_period_s)
        u = g["u_offset_s"].to_numpy(float)
        for k in range(len(g)):
            residual = u_res = np.nan
            if k:
                dt_s = float((starts[k] - starts[k - 1]) / np.timedelta64(1, "s"))
                predicted = phase[k - 1] + drift_ppm * 1e-6 * dt_s
                residual = float((phase[k] - predicted + frame_period_s / 2) % frame_period_s
                                 - frame_period_s / 2)
                u_res = float(np.sqrt(np.nansum([u[k] ** 2, u[k - 1] ** 2,
                                                 (np.nan_to_num(u_drift_ppm) * 1e-6 * dt_s) ** 2])))
            rows.append({"site": site, "pair": pair, "start_utc": g["start_utc"].iloc[k],
                         "task_id": g["task_id"].iloc[k], "offset_s": g["offset_s"].iloc[k],
                         "drift_ppm": drift[k], "pair_drift_ppm": drift_ppm, "residual_s": residual,
                         "u_residual_s": u_res,
                         "jump": bool(np.isfinite(residual) and abs(residual) > max(JUMP_SIGMAS * u_res,
                                                                                    JUMP_FLOOR_S))})
    return pd.DataFrame(rows)


def target_trend(out: Path) -> pd.DataFrame:
    """Per target over the archive: amplitude, frequency and RMS against the segment's start.

    A target is followed from segment to segment by its rest position: the segments' target tracks whose
    positions lie within ``TARGET_GATE_MM`` of each other are one target, named ``T1``, ``T2``, … per pair in
    order of first appearance.
    """
    root = out / "segments"
    if not root.is_dir():
        return pd.DataFrame()
    seg = pd.read_parquet(root)
    if seg.empty or "role" not in seg:
        return pd.DataFrame()
    seg = seg[seg["role"] == "target"].copy()
    seg["site"], seg["pair"] = seg["site"].astype(str), seg["pair"].astype(str)
    seg = seg.sort_values(["site", "pair", "segment_start_utc", "track_id"], kind="stable")
    labels = []
    for _, g in seg.groupby(["site", "pair"], sort=False):
        centres: list[np.ndarray] = []
        for xyz in g[["x_mm", "y_mm", "z_mm"]].to_numpy(float):
            dist = [float(np.linalg.norm(xyz - c)) for c in centres]
            if dist and min(dist) <= TARGET_GATE_MM:
                labels.append(f"T{int(np.argmin(dist)) + 1}")
            else:
                centres.append(xyz)
                labels.append(f"T{len(centres)}")
    seg["target"] = labels
    columns = ["site", "pair", "target", "segment_start_utc", "task_id", "x_mm", "y_mm", "z_mm",
               "amplitude_mm", "amplitude_std_mm", "frequency_hz", "frequency_std_hz", "rms_mm"]
    return seg[[c for c in columns if c in seg]].reset_index(drop=True)
