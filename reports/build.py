"""``build_report(run_dir)``: rebuild tables, figures, report.html and certificate.json from a run folder.

A thin layer: load the record (:mod:`reports.load`), run the analysis once per sync method (the primary
one, then ``"linear"``, the paper's, for comparison), compute the tables (:mod:`reports.tables`), write
them. Outputs are deterministic: the same run folder gives byte-identical CSV, JSON, PNG and HTML (floats
written to 9 significant digits in CSV and 10 in JSON; PNG without a software/date stamp; the only date
is the run's own start time).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from reports import figures, html, summaries
from reports.certificate import acceptance_from_config, build_certificate, evaluate
from reports.errors import AnalysisFailedError, ReportError
from reports.load import load_record
from reports.tables import compute_tables, measured_values

DEFAULT_SYNC = "trajectory"
COMPARISON_SYNC = "linear"
Analyse = Callable[..., Any]  # analyse(run_dir, *, sync=...) -> object with .tracks, .timing, .calibration


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
    """CSV with '\\n' line ends and floats to 9 significant digits (deterministic)."""
    df.to_csv(path, index=False, float_format="%.9g", lineterminator="\n")


def _default_analyse() -> Analyse:
    try:
        from rig.analysis import analyse
    except ImportError as exc:
        raise ReportError(
            f"rig.analysis is not available ({exc}); pass analysis=... to build_report"
        ) from exc
    return analyse


def build_report(
    run_dir: str | Path,
    *,
    sync: str | None = None,
    compare: tuple[str, ...] = (COMPARISON_SYNC,),
    analysis: Analyse | None = None,
    make_figures: bool = True,
    in_run: bool = False,
) -> ReportResult:
    """Rebuild ``tables/``, ``figures/``, ``report.html`` and ``certificate.json`` inside ``run_dir``.

    ``sync`` is the primary synchronization method (default: ``rig.analysis.sync`` of the snapshot, else
    ``"trajectory"``); ``compare`` adds methods shown beside it. ``analysis`` replaces
    ``rig.analysis.analyse``.
    A failing comparison method is reported as a note; a failing primary method raises.
    ``make_figures=False`` skips the figures (≈ 3 s of matplotlib) for a quick table/certificate rebuild.
    ``in_run=True``: built by the run's own last step (the procedures' ``report`` step), which is
    finishing normally — the conditions then say so (``exit_status`` "success", the stop document follows)
    instead of a missing stop document (a killed run).
    """
    run = load_record(run_dir)
    run_dir = run.run_dir
    acceptance = acceptance_from_config(run.rig)
    analysis_cfg = run.rig.get("analysis") if isinstance(run.rig.get("analysis"), dict) else {}
    primary = sync or analysis_cfg.get("sync") or DEFAULT_SYNC
    methods = [primary, *[m for m in compare if m != primary]]
    analyse = analysis or _default_analyse()
    notes: list[str] = []
    results: dict[str, Any] = {}
    for method in methods:
        try:
            results[method] = analyse(run_dir, sync=method)
        except Exception as exc:
            if method == primary:
                if isinstance(exc, ValueError | OSError):  # the analysis' own errors name the cause
                    raise AnalysisFailedError(f"analysis with sync '{method}' failed: {exc}") from exc
                raise
            notes.append(f"comparison sync '{method}' failed: {type(exc).__name__}: {exc}")
    main = results[primary]
    t = compute_tables(
        run,
        {m: r.tracks for m, r in results.items()},
        acceptance,
        gate_mm=float(acceptance["identification_gate_mm"]),
        bin_hz=float(acceptance["frequency_bin_hz"]),
        timing=getattr(main, "timing", None) or run.timing,
        calibration=getattr(main, "calibration", None) or run.calibration,
    )
    notes += [f"quadratic fit, sync '{m}': {msg}" for m, msg in sorted(t.fit_notes.items())]
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
    stop = run.stop or {}
    conditions = {
        "run_id": run.run_id,
        "procedure": run.start.get("procedure"),
        "date_utc": run.start.get("wall_utc"),
        "exit_status": "success" if in_run and run.stop is None else run.exit_status,
        "stop_reason": stop.get("reason") if not (in_run and run.stop is None) else "finishing normally",
        "clock": run.start.get("clock"),
        "sync_method": primary,
        "compared_sync_methods": [m for m in results if m != primary],
        "camera_fps": t.fs_hz,
        "camera_fps_source": t.fs_source,
        "calibration_convention": (run.calibration or {}).get("convention"),
        "timing_method": (t.timing or {}).get("method"),
        "report_software": _software_version(),
        "versions": run.start.get("versions"),
        "measurands": summaries.measurands(t, run.rig),
        "rig": run.rig,
        "notes": notes,
    }
    measured = measured_values(t, acceptance)
    extra = {
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
    cert = _clean(build_certificate(measured, acceptance, conditions, extra))

    tables_dir, figures_dir = run_dir / "tables", run_dir / "figures"
    tables_dir.mkdir(exist_ok=True)
    figures_dir.mkdir(exist_ok=True)
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
    if t.plate is not None:
        frames["plate"] = t.plate
    if t.rotation_samples is not None:
        frames["rotation_samples"] = t.rotation_samples
        frames["rotation_summary"] = pd.DataFrame([t.rotation_summary])
    if t.spectrum is not None:
        frames["rotor_spectrum"] = t.spectrum
    table_paths = {}
    for name, df in frames.items():
        path = tables_dir / f"{name}.csv"
        write_csv(df, path)
        table_paths[name] = path
    tol = float(acceptance["amplitude_error_pct"])
    pngs: dict[str, bytes] = {}
    figure_paths = {}
    for name, fig in (
        figures.all_figures(t, tol, float(acceptance["position_max_mm"])) if make_figures else {}
    ).items():
        path = figures_dir / f"{name}.png"
        figures.save_png(fig, path)
        pngs[name] = path.read_bytes()
        figure_paths[name] = path
    cert_path = run_dir / "certificate.json"
    cert_path.write_text(
        json.dumps(cert, indent=2, sort_keys=True, ensure_ascii=False) + "\n", encoding="utf-8"
    )
    pose_cols = [
        "index",
        "cycle",
        "target",
        "marker_id",
        "x_cmd_mm",
        "y_cmd_mm",
        "z_cmd_mm",
        "ex_mm",
        "ey_mm",
        "ez_mm",
        "error_mm",
        "u_error_mm",
        "n_samples",
        "distance_mm",
        "off_axis_mm",
    ]
    html_tables = {
        "iso9283": t.iso9283[t.iso9283["n_cycles"] >= 2].drop(columns=["x_cmd_mm", "y_cmd_mm", "z_cmd_mm"]),
        "length_summary": frames["length_summary"],
        "poses": t.poses[pose_cols],
        "fits": summaries.fits_display(t),
        "sweep_means": t.sweep_means,
        "plate": t.plate,
        "calibration": t.calibration,
        "timing": frames["timing"],
    }
    html_path = run_dir / "report.html"
    html_path.write_text(html.render(cert, t, pngs, acceptance, html_tables), encoding="utf-8")
    return ReportResult(
        run_dir=run_dir,
        result=cert["result"],
        certificate=cert,
        report_html=html_path,
        certificate_json=cert_path,
        tables=table_paths,
        figures=figure_paths,
        notes=notes,
    )
