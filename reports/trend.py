"""A setup's certificates over time: every criterion's value, expanded uncertainty and limit per run.

Built from the catalogue of runs (:mod:`rig.record.catalogue`): ``rig runs trend SETUP`` prints the table and
writes ``trend_<setup>.csv`` and ``trend_<setup>.png`` (one panel per criterion: value ± U against the
run's start date, the limit as a dashed line, failed runs marked).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import pandas as pd
from matplotlib.figure import Figure

from reports.figures import new_figure, save_png
from rig.record.atomic import atomic_path
from rig.record.catalogue import RunEntry

TREND_COLUMNS = ["run_id", "started_utc", "procedure", "result", "simulated", "criterion", "unit", "value",
                 "expanded_uncertainty", "limit_value", "comparison", "status"]


def trend_frame(entries: Sequence[RunEntry]) -> pd.DataFrame:
    """One row per (run, criterion) of the runs that issued a certificate, oldest run first."""
    rows = [
        {"run_id": e.run_id, "started_utc": e.started_utc, "procedure": e.procedure, "result": e.result,
         "simulated": e.simulated, "criterion": c.criterion, "unit": c.unit, "value": c.value,
         "expanded_uncertainty": c.expanded_uncertainty, "limit_value": c.limit_value,
         "comparison": c.comparison, "status": c.status}
        for e in entries if e.result is not None for c in e.criteria
    ]
    frame = pd.DataFrame(rows, columns=TREND_COLUMNS)
    frame["started_utc"] = pd.to_datetime(frame["started_utc"], utc=True, errors="coerce")
    return frame.sort_values(["started_utc", "run_id"], kind="stable").reset_index(drop=True)


def trend_figure(frame: pd.DataFrame, setup: str) -> Figure | None:
    """One panel per evaluated criterion: value with ±U bars against the date, the limit dashed."""
    evaluated = frame.dropna(subset=["value"])
    if evaluated.empty:
        return None
    criteria = list(dict.fromkeys(evaluated["criterion"]))
    fig, axes = new_figure(len(criteria), 1, size=(7.5, 1.9 * len(criteria) + 0.6), sharex=True)
    for ax, criterion in zip(axes[:, 0], criteria, strict=True):
        rows = evaluated[evaluated["criterion"] == criterion]
        passed = rows["status"] == "PASS"
        for mask, marker, label in ((passed, "o", "PASS"), (~passed, "x", "not PASS")):
            part = rows[mask]
            if not part.empty:
                ax.errorbar(part["started_utc"], part["value"], yerr=part["expanded_uncertainty"].fillna(0),
                            fmt=marker, ms=5, capsize=2, label=label)
        limits = rows["limit_value"].dropna()
        if not limits.empty:
            ax.plot(rows["started_utc"], rows["limit_value"], ls="--", lw=1, color="#b3261e", label="limit")
        ax.set_ylabel(f"{criterion}\n({rows['unit'].iloc[0]})", fontsize=8)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7.5)
    axes[-1, 0].set_xlabel("run started (UTC)")
    fig.suptitle(f"Certificates of '{setup}' over time (bars: expanded uncertainty U, k = 2)",
                 fontweight="bold", fontsize=10)
    fig.autofmt_xdate()
    return fig


def write_trend(frame: pd.DataFrame, setup: str, out_dir: str | Path) -> tuple[Path, Path | None]:
    """Write ``trend_<setup>.csv`` and (when any criterion was evaluated) ``trend_<setup>.png``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = "trend_" + (re.sub(r"[^A-Za-z0-9._-]+", "_", setup).strip("_") or "setup")
    csv_path = out_dir / f"{stem}.csv"
    with atomic_path(csv_path) as tmp:
        frame.to_csv(tmp, index=False)
    fig = trend_figure(frame, setup)
    if fig is None:
        return csv_path, None
    png_path = out_dir / f"{stem}.png"
    save_png(fig, png_path)
    return csv_path, png_path


def archive_trend_figure(trend: pd.DataFrame) -> Figure | None:
    """``rig batch``: each target's amplitude and frequency against the segment's start, one colour per
    target (site/pair/target) — what a structural engineer watches for damage."""
    if trend.empty:
        return None
    fig, axes = new_figure(2, 1, size=(8.5, 5.2), sharex=True)
    labels = trend["site"] + "/" + trend["pair"] + "/" + trend["target"]
    for label, g in trend.groupby(labels, sort=True):
        when = pd.to_datetime(g["segment_start_utc"], utc=True)
        axes[0, 0].errorbar(when, g["amplitude_mm"], yerr=2 * g.get("amplitude_std_mm", 0), fmt="o-", ms=3,
                            lw=0.8, capsize=2, label=label)
        axes[1, 0].errorbar(when, g["frequency_hz"], yerr=2 * g.get("frequency_std_hz", 0), fmt="o-", ms=3,
                            lw=0.8, capsize=2, label=label)
    axes[0, 0].set_ylabel("amplitude (mm), ±2u")
    axes[1, 0].set_ylabel("frequency (Hz), ±2u")
    axes[1, 0].set_xlabel("segment start (UTC)")
    axes[0, 0].legend(title="site/pair/target", loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7.5)
    fig.suptitle("Targets over the archive", fontweight="bold", fontsize=10.5)
    fig.autofmt_xdate()
    return fig
