"""``build_report(run_dir)``: tables, figures, report.html and certificate.json from a run folder.

Evidence is immutable: the first report of a run issues its certificate (written into the run folder,
``certificate.json`` last); a later one writes a revision beside it, ``revisions/<n>-<sync>/`` (the same
outputs plus ``changes.json``), built in a hidden staging folder and renamed into place whole. Every file
is written atomically (:mod:`rig.record.atomic`).

A thin layer: load the run folder once (:mod:`reports.load`), run the analysis on it once per sync
method (the primary one, then those of ``[report] comparison``: by default ``"linear"``, the paper's;
:mod:`reports.scope`), compute the tables
(:mod:`reports.tables`), write them. Outputs are deterministic: the same run folder gives byte-identical
CSV, JSON, PNG and HTML (floats written to 9 significant digits in CSV and 10 in JSON; PNG without a
software/date stamp; the only date is the run's own start time).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import pandas as pd

from reports import band_phase, html, step_phase, summaries
from reports.certificate import acceptance_from_config, build_certificate, evaluate
from reports.errors import AnalysisFailedError, ReportError
from reports.load import RunData, load_record
from reports.phase import phase_section
from reports.scope import Scope
from reports.tables import ReportTables, compute_tables, controller_clock, measured_values
from rig.record.atomic import atomic_path, fsync_dir, write_json, write_text
from rig.record.folder import RunFolder
from rig.stereo.blas import one_blas_thread

DEFAULT_SYNC = "trajectory"
CERTIFICATE_NAME = "certificate.json"
REVISIONS_DIR = "revisions"


class AnalysisResult(Protocol):
    """What a report uses of one sync method's analysis (:class:`rig.analysis.Analysis`)."""

    @property
    def tracks(self) -> pd.DataFrame: ...

    @property
    def clock(self) -> pd.DataFrame: ...  # controller − reference camera clock per segment, with u

    @property
    def notes(self) -> list[str]: ...  # what the analysis skipped and why


class Analyse(Protocol):
    """``rig.analysis.analyse``: the run folder as read once → its analysis with one sync method."""

    def __call__(self, source: RunFolder, *, sync: str) -> AnalysisResult: ...


@dataclass(frozen=True)
class Analyses:
    """The analysis of every sync method that worked (the primary first) and notes on those that failed."""

    primary: str
    by_method: dict[str, AnalysisResult]
    notes: list[str]


@dataclass(frozen=True)
class Report:
    """What a report writes: the certificate, the tables and their CSV frames by name, and its scope (the
    figures or not)."""

    certificate: dict[str, Any]
    tables: ReportTables
    frames: dict[str, pd.DataFrame]
    acceptance: dict[str, Any]
    scope: Scope


@dataclass(frozen=True)
class ReportResult:
    """What :func:`build_report` wrote and decided."""

    run_dir: Path
    result: str  # PASS | FAIL | INCOMPLETE
    certificate: dict[str, Any]
    report_html: Path
    certificate_json: Path
    tables: dict[str, Path] = field(default_factory=dict)
    figures: dict[str, Path] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    revision: Path | None = None  # the revision folder when the run's certificate was already issued
    changes: dict[str, Any] | None = None  # a revision's differences from the issued certificate


@dataclass(frozen=True)
class Written:
    """The files :func:`_write_outputs` wrote."""

    report_html: Path
    certificate_json: Path
    tables: dict[str, Path]
    figures: dict[str, Path]

    def moved(self, old: Path, new: Path) -> Written:
        """The same files after their folder ``old`` was renamed to ``new``."""
        def move(path: Path) -> Path:
            return new / path.relative_to(old)

        return Written(move(self.report_html), move(self.certificate_json),
                       {k: move(v) for k, v in self.tables.items()},
                       {k: move(v) for k, v in self.figures.items()})

    def fields(self) -> dict[str, Any]:
        """As keyword arguments of :class:`ReportResult`."""
        return {"report_html": self.report_html, "certificate_json": self.certificate_json,
                "tables": self.tables, "figures": self.figures}


def _software_version() -> str:
    try:
        return f"rig-controller {metadata.version('rig-controller')}"
    except metadata.PackageNotFoundError:
        return "rig-controller (not installed)"


def _clean(value: Any) -> Any:
    """Plain JSON values: NaN/inf → null, numpy → Python, floats to 10 significant digits."""
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, np.ndarray):
        return _clean(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return float(f"{v:.10g}") if math.isfinite(v) else None
    return value


def write_csv(df: pd.DataFrame, path: Path) -> None:
    """CSV with '\\n' line ends and floats to 9 significant digits (deterministic), written atomically."""
    with atomic_path(path) as tmp:
        df.to_csv(tmp, index=False, float_format="%.9g", lineterminator="\n")


def _default_analyse() -> Analyse:
    """``rig.analysis.analyse`` for one report: the run folder prepared once (2-D tracks, pairs, clocks:
    what no sync method changes), then triangulated with each method asked for."""
    from rig.analysis.analyse import PreparedRun, analyse_prepared, prepare_run

    last: list[PreparedRun] = []  # the folder last prepared (one report reads it once)

    def analyse(source: RunFolder, *, sync: str) -> AnalysisResult:
        if not last or last[0].folder is not source:
            last[:] = [prepare_run(source)]
        return analyse_prepared(last[0], sync=sync)

    return analyse


def _check_writable(run_dir: Path) -> None:
    """``OSError`` (e.g. EROFS, EACCES, ENOSPC) when ``run_dir`` takes no new file or its disk has no room
    for one byte: every output of a report (issued or a revision) is written under it, so a read-only run or
    a full disk is refused before minutes of analysis (a disk with less room than the outputs still fails
    when they are written, leaving nothing half-written)."""
    with tempfile.TemporaryFile(dir=run_dir, prefix=".write-probe-") as probe:
        probe.write(b"\0")
        probe.flush()
        os.fsync(probe.fileno())  # a filesystem that allocates late (ext4) allocates here


@one_blas_thread()  # the analyses' and tables' many small solves: more BLAS threads only spin
def build_report(
    run_dir: str | Path,
    *,
    sync: str | None = None,
    scope: Scope | None = None,
    no_figures_why: str | None = None,
    analysis: Analyse | None = None,
    in_run: bool = False,
    checkpoint: Callable[[], None] | None = None,
) -> ReportResult:
    """Build ``tables/``, ``figures/``, ``report.html`` and ``certificate.json`` of ``run_dir``.

    A run without ``certificate.json`` gets its certificate **issued**: the outputs are written into the
    run folder, the certificate last (its presence marks the report as issued). A run whose certificate
    is already issued is never rewritten: the outputs go to a new revision ``revisions/<n>-<sync>/``
    (with ``changes.json``: what differs from the issued certificate), see :attr:`ReportResult.revision`.

    ``sync`` is the primary synchronization method (default: ``rig.analysis.analyse.sync`` of the snapshot,
    else ``"trajectory"``). ``scope``: the comparison methods analysed beside it (each a whole second
    analysis) and whether figures are drawn (≈ 1 s of matplotlib); default: the run's ``[report]``
    (:meth:`Scope.of_snapshot`). What it leaves out is said in the notes, and report.html says when no
    figure was drawn; no criterion depends on either. ``no_figures_why`` (e.g. ``"--no-figures"``): draw none
    whatever the scope, the notes giving that reason. ``analysis`` replaces ``rig.analysis.analyse.analyse``.
    A failing comparison method is reported as a note; a failing primary method raises.
    ``in_run=True``: built by the run's own last step (the procedures' ``report`` step), which is
    finishing normally — the conditions then say so (``exit_status`` "success", the stop document follows)
    instead of a missing stop document (a killed run).
    ``checkpoint``: called before each analysis (the primary and every comparison: the report's CPU) and
    just before the certificate is issued (not for a revision); the run's report step passes its checkpoint,
    so an abort requested while the report was built stops the step at the next of them — without
    analysing on — and no certificate saying "finishing normally" is issued for a run that ends aborted (a
    later ``rig report RUN`` issues it from the record, stop document included).
    An ``OSError`` while writing (full disk, read-only folder) propagates; no output is left half-written.
    A folder that takes no new file (read-only) raises before the analysis, not after it.
    """
    run = load_record(run_dir)
    _check_writable(Path(run_dir))
    acceptance = acceptance_from_config(run.rig)
    scope = scope or _recorded_scope(run.rig)
    if no_figures_why:
        scope = dataclasses.replace(scope, figures=False, figures_why=no_figures_why)
    primary = sync or _configured_sync(run.rig)
    analyses = _analyse_all(run.folder, [primary, *[m for m in scope.comparison if m != primary]],
                            analysis or _default_analyse(), checkpoint or _no_checkpoint)
    t = _tables(run, analyses, acceptance)
    revision = _next_revision(run.run_dir, primary)  # None: this report issues the certificate
    notes = (analyses.notes + _notes(run, t, in_run=in_run) + scope.notes()
             + ([revision.note] if revision else []))
    report = _certify(run, t, analyses, acceptance, notes, scope=scope, in_run=in_run)
    cert = report.certificate
    if revision is None:
        written = _write_outputs(run.run_dir, report, before_certificate=checkpoint)
        return ReportResult(run.run_dir, cert["result"], cert, notes=notes, **written.fields())
    changes = certificate_changes(revision.issued, cert, revision=revision.number, sync=primary)
    written = _write_revision(run.run_dir, revision, report, changes)
    return ReportResult(run.run_dir, cert["result"], cert, notes=notes, changes=changes,
                        revision=revision.folder(run.run_dir), **written.fields())


def _recorded_scope(rig: dict[str, Any]) -> Scope:
    """The run's ``[report]`` (:meth:`Scope.of_snapshot`); a snapshot edited out of range is a
    :class:`ReportError` naming the field."""
    try:
        return Scope.of_snapshot(rig)
    except ValueError as exc:  # ConfigError
        raise ReportError(f"the run's rig snapshot: {exc}") from exc


def _configured_sync(rig: dict[str, Any]) -> str:
    """The snapshot's ``analysis.sync``, else :data:`DEFAULT_SYNC`."""
    analysis_cfg = rig.get("analysis")
    configured = analysis_cfg.get("sync") if isinstance(analysis_cfg, dict) else None
    return str(configured or DEFAULT_SYNC)


def _no_checkpoint() -> None:
    """No abort point (a report outside a run)."""


def _analyse_all(folder: RunFolder, methods: list[str], analyse: Analyse,
                 checkpoint: Callable[[], None]) -> Analyses:
    """The analysis of every method that worked (the first, primary, must), its notes and notes on the
    rest; ``checkpoint()`` before each (its exception, an abort, propagates)."""
    notes: list[str] = []
    results: dict[str, AnalysisResult] = {}
    for method in methods:
        checkpoint()
        try:
            results[method] = analyse(folder, sync=method)
            if method == methods[0]:
                notes += [f"analysis, sync '{method}': {n}" for n in results[method].notes]
        except Exception as exc:
            if method == methods[0]:
                if isinstance(exc, ValueError | OSError):  # the analysis' own errors name the cause
                    raise AnalysisFailedError(f"analysis with sync '{method}' failed: {exc}") from exc
                raise
            notes.append(f"comparison sync '{method}' failed: {type(exc).__name__}: {exc}")
    return Analyses(methods[0], results, notes)


def _tables(run: RunData, analyses: Analyses, acceptance: dict[str, Any]) -> ReportTables:
    """The report's tables from the tracks of every method, with the primary method's controller clock."""
    main = analyses.by_method[analyses.primary]
    return compute_tables(
        run,
        {m: r.tracks for m, r in analyses.by_method.items()},
        acceptance,
        gate_mm=float(acceptance["identification_gate_mm"]),
        bin_hz=float(acceptance["frequency_bin_hz"]),
        clock=main.clock,
    )


def _notes(run: RunData, t: ReportTables, *, in_run: bool) -> list[str]:
    """The tables' notes and what the record says of how the run ended."""
    notes = [f"quadratic fit, sync '{m}': {msg}" for m, msg in sorted(t.fit_notes.items())]
    notes += t.notes
    if run.stop is None and in_run:
        notes.append("built as the run's last step, before its stop document (which records how it ended)")
    elif run.stop is None:
        notes.append(
            "the record has no stop document yet: the report was built as a step of the run (or the run "
            "was killed); the result follows from the criteria"
        )
    if run.truncated_last_line:
        notes.append("the record's last line was cut short (the run was killed); it was ignored")
    return notes


def _certify(run: RunData, t: ReportTables, analyses: Analyses, acceptance: dict[str, Any], notes: list[str],
             *, scope: Scope, in_run: bool) -> Report:
    """The measured values, the certificate deciding on them and the CSV tables."""
    measured = measured_values(t, acceptance)
    conditions = _conditions(run, t, analyses, notes, in_run=in_run)
    cert = _clean(build_certificate(measured, acceptance, conditions, _extra(t, analyses.primary)))
    return Report(cert, t, _table_frames(t, measured, acceptance), acceptance, scope)


def _conditions(run: RunData, t: ReportTables, analyses: Analyses, notes: list[str], *,
                in_run: bool) -> dict[str, Any]:
    """The certificate's conditions: the run, how it ended, the methods, the software, the rig."""
    primary = analyses.primary
    stop = run.stop or {}
    return {
        "run_id": run.run_id,
        "procedure": run.start.get("procedure"),
        "date_utc": run.start.get("wall_utc"),
        "exit_status": "success" if in_run and run.stop is None else run.exit_status,
        "stop_reason": stop.get("reason") if not (in_run and run.stop is None) else "finishing normally",
        "clock": run.start.get("clock"),
        "sync_method": primary,
        "compared_sync_methods": [m for m in analyses.by_method if m != primary],
        "camera_fps": t.fs_hz,
        "camera_fps_source": t.fs_source,
        "calibration_convention": run.calibration.convention if run.calibration else None,
        "timing_method": t.timing.method if t.timing else None,
        "report_software": _software_version(),
        "versions": run.start.get("versions"),
        "measurands": summaries.measurands(t, run.rig),
        "rig": run.rig,
        "notes": notes,
    }


def _extra(t: ReportTables, primary: str) -> dict[str, Any]:
    return {
        "controller_clock": controller_clock(t.clock),
        "band": t.band,
        "phase": phase_section(t.phase),
        "extended_band": band_phase.section(t.extended),
        "steady_steps": step_phase.section(t.steps),
        "usable_frequency": {
            m: {
                "tolerance_pct": lim.tolerance,
                "limit_hz": lim.limit_hz,
                "u_limit_hz": lim.u_limit_hz,
                "reached_within_tested_range": lim.reached,
                "f_max_tested_hz": lim.f_max_tested_hz,
                "fit": t.fits[m].to_dict(),
            }
            for m, lim in t.limits.items()
        },
        "method": {
            "measurement_model": "DLT stereo triangulation of marker centroids; truth from the commanded "
            "robot poses and exciter/rotor settings of the record",
            "sync_method": primary,
            "amplitude_estimator": "three-parameter sine fit per frequency bin with the reference phase",
            "quadratic_fit": "weighted least squares, covariance scaled by the reduced chi-square, "
            "Student-t intervals",
        },
    }


def _table_frames(t: ReportTables, measured: dict[str, Any],
                  acceptance: dict[str, Any]) -> dict[str, pd.DataFrame]:
    """The CSV tables by name."""
    criteria = pd.DataFrame(evaluate(measured, acceptance))
    criteria["budget"] = [
        "; ".join(f"{b['component']} ({b['type']}): {b['u']:.6g}" for b in budget)
        for budget in criteria["budget"]
    ]
    frames = {
        "position_errors": t.poses,
        "iso9283": t.iso9283,
        "length_errors": t.lengths,
        "length_summary": summaries.length_summary(t.lengths),
        "sweep_bins": t.sweep_bins,
        "sweep_means": t.sweep_means,
        "quadratic_fit": summaries.fits_frame(t),
        "calibration_residuals": t.calibration,
        "timing": summaries.timing_frame(t.timing),
        "criteria": criteria,
        "position_summary": pd.DataFrame([t.position_summary]),
    }
    if t.phase is not None:
        frames["phase_bins"] = t.phase.bins
    if t.plate is not None:
        frames["plate"] = t.plate
    if t.rotation_samples is not None:
        frames["rotation_samples"] = t.rotation_samples
        frames["rotation_summary"] = pd.DataFrame([t.rotation_summary])
    if t.spectrum is not None:
        frames["rotor_spectrum"] = t.spectrum
    if t.band_bins is not None and len(t.band_bins):
        frames["band_bins"] = t.band_bins
    if t.extended is not None and len(t.extended.bins):
        frames["extended_band"] = t.extended.bins
    if t.steps is not None and len(t.steps.bins):
        frames["steady_steps"] = t.steps.bins
    return frames


POSE_COLUMNS = ["index", "cycle", "target", "marker_id", "x_cmd_mm", "y_cmd_mm", "z_cmd_mm", "ex_mm",
                "ey_mm", "ez_mm", "error_mm", "u_error_mm", "n_samples", "n_unsettled", "distance_mm",
                "off_axis_mm"]


def _write_outputs(out_dir: Path, report: Report,
                   before_certificate: Callable[[], None] | None = None) -> Written:
    """Write tables, figures (when the scope draws them), report.html and — last, after
    ``before_certificate()`` — certificate.json into ``out_dir`` (each file atomically)."""
    cert, t, frames, acceptance = report.certificate, report.tables, report.frames, report.acceptance
    tables_dir = out_dir / "tables"
    tables_dir.mkdir(exist_ok=True)
    table_paths = {}
    for name, df in frames.items():
        table_paths[name] = tables_dir / f"{name}.csv"
        write_csv(df, table_paths[name])
    figure_paths = _write_figures(out_dir / "figures", t, acceptance) if report.scope.figures else {}
    pngs = {name: path.read_bytes() for name, path in figure_paths.items()}
    html_tables = {
        "iso9283": t.iso9283[t.iso9283["n_cycles"] >= 2].drop(columns=["x_cmd_mm", "y_cmd_mm", "z_cmd_mm"]),
        "length_summary": frames["length_summary"],
        "poses": t.poses[POSE_COLUMNS],
        "fits": summaries.fits_display(t),
        "sweep_means": t.sweep_means,
        "plate": t.plate,
        "calibration": t.calibration,
        "timing": frames["timing"],
    }
    html_path = write_text(out_dir / "report.html", html.render(cert, t, pngs, acceptance, html_tables,
                                                                figures_note=report.scope.figures_note))
    if before_certificate is not None:
        before_certificate()
    cert_path = write_json(out_dir / CERTIFICATE_NAME, cert, indent=2, sort_keys=True, ensure_ascii=False)
    return Written(html_path, cert_path, table_paths, figure_paths)


def _write_figures(figures_dir: Path, t: ReportTables, acceptance: dict[str, Any]) -> dict[str, Path]:
    """Draw every figure of the tables into ``figures_dir`` as PNG; their paths by name."""
    from reports import figures  # matplotlib: ≈ 1.5 CPU-s to import, only for a report that draws

    figures_dir.mkdir(exist_ok=True)
    paths = {}
    for name, fig in figures.all_figures(t, float(acceptance["amplitude_error_pct"]),
                                         float(acceptance["position_max_mm"])).items():
        paths[name] = figures_dir / f"{name}.png"
        figures.save_png(fig, paths[name])
    return paths


# ------------------------------------------------------------------------------------------ revisions
@dataclass(frozen=True)
class Revision:
    """A revision's number (1, 2, …), folder name ``<n>-<sync>`` under ``revisions/`` and the issued
    certificate it leaves unchanged."""

    number: int
    name: str
    sync: str
    issued: dict[str, Any]

    def folder(self, run_dir: Path) -> Path:
        return run_dir / REVISIONS_DIR / self.name

    @property
    def note(self) -> str:
        return (f"revision {self.number} (sync '{self.sync}') of this run's report: the issued certificate "
                f"(certificate.json of the run folder, result {self.issued.get('result')}) is unchanged")


def issued_certificate(run_dir: str | Path) -> dict[str, Any] | None:
    """The run's issued certificate (``certificate.json``), or None when none was issued yet.

    A certificate that exists but cannot be read as a JSON object is still issued (it is never replaced);
    it is returned as ``{"result": None, "criteria": [], "unreadable": "<why>"}``."""
    path = Path(run_dir) / CERTIFICATE_NAME
    if not path.exists():
        return None
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        return {"result": None, "criteria": [], "unreadable": f"{type(exc).__name__}: {exc}"}
    if not isinstance(doc, dict):
        return {"result": None, "criteria": [], "unreadable": "not a JSON object"}
    return doc


def _next_revision(run_dir: Path, sync: str) -> Revision | None:
    """The next revision of the run's report, or None when its certificate is not issued yet."""
    issued = issued_certificate(run_dir)
    if issued is None:
        return None
    folder = run_dir / REVISIONS_DIR
    numbers = [int(m.group(1)) for p in (folder.iterdir() if folder.is_dir() else ())
               if (m := re.match(r"(\d+)-", p.name))]
    number = max(numbers, default=0) + 1
    return Revision(number, f"{number}-{sync}", sync, issued)


def _write_revision(run_dir: Path, revision: Revision, report: Report, changes: dict[str, Any]) -> Written:
    """Write a revision's outputs and ``changes.json`` into a hidden staging folder, then rename it into
    place whole as ``revisions/<n>-<sync>/``; nothing is left behind on failure."""
    staging = run_dir / REVISIONS_DIR / f".staging-{revision.name}-{os.getpid()}"
    final = revision.folder(run_dir)
    try:
        staging.mkdir(parents=True)
        written = _write_outputs(staging, report)
        write_json(staging / "changes.json", changes, indent=2, sort_keys=True, ensure_ascii=False)
        if final.exists():
            raise ReportError(f"{final} appeared while this revision was built (another `rig report` of "
                              "the same run?); run it again")
        os.rename(staging, final)
        fsync_dir(final.parent)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return written.moved(staging, final)


def certificate_changes(issued: dict[str, Any], revised: dict[str, Any], *, revision: int,
                        sync: str) -> dict[str, Any]:
    """What a revision's certificate changes against the issued one: the overall result and every
    criterion whose value (beyond 10 significant digits) or decision differs; ``summary``: one line each."""
    before = {r.get("id"): r for r in issued.get("criteria") or [] if isinstance(r, dict)}
    after = {r.get("id"): r for r in revised.get("criteria") or [] if isinstance(r, dict)}
    criteria = []
    for cid in [*before, *(c for c in after if c not in before)]:
        a, b = before.get(cid) or {}, after.get(cid) or {}
        if a.get("value") != b.get("value") or a.get("status") != b.get("status"):
            criteria.append({"id": cid, "issued_value": a.get("value"), "revised_value": b.get("value"),
                             "issued_status": a.get("status"), "revised_status": b.get("status"),
                             "unit": b.get("unit", a.get("unit"))})
    summary = [f"result {issued.get('result')} → {revised.get('result')}"
               if issued.get("result") != revised.get("result") else f"result {revised.get('result')} (same)"]
    summary += [f"{c['id']}: {_fmt(c['issued_value'])} → {_fmt(c['revised_value'])} {c['unit'] or ''} "
                f"({c['issued_status']} → {c['revised_status']})".replace("  ", " ") for c in criteria]
    if issued.get("unreadable"):
        summary.insert(0, f"the issued certificate could not be read ({issued['unreadable']})")
    return {"revision": revision, "sync_method": sync, "issued_certificate": CERTIFICATE_NAME,
            "issued_result": issued.get("result"), "revised_result": revised.get("result"),
            "issued_sync_method": (issued.get("conditions") or {}).get("sync_method"),
            "criteria": criteria, "summary": summary}


def _fmt(value: Any) -> str:
    return "—" if value is None else f"{value:.6g}" if isinstance(value, float) else str(value)
