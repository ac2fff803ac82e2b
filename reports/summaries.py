"""Derived display tables of the report: fit summaries, test-length summary, timing, measurands.

Pure functions of :class:`reports.tables.ReportTables`; :mod:`reports.build` writes them as CSV and the
HTML shows them.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from reports.tables import ReportTables
from rig.stereo.timing import TimingResult


def fits_frame(t: ReportTables) -> pd.DataFrame:
    """Per sync method: fit coefficients with 95 % intervals, R², the usable limit and the track delay."""
    rows: list[dict[str, Any]] = []
    for method in t.sync_methods:
        fit, lim = t.fits.get(method), t.limits.get(method)
        if fit is None or lim is None:  # a fit always comes with its limit
            rows.append({"sync_method": method, "note": t.fit_notes.get(method, "no sweep data")})
            continue
        (c0_low, c0_high), (c2_low, c2_high) = fit.ci("c0"), fit.ci("c2")
        rows.append(
            {
                "sync_method": method,
                "c0_pct": fit.c0,
                "c0_ci_low_pct": c0_low,
                "c0_ci_high_pct": c0_high,
                "c2_pct_per_hz2": fit.c2,
                "c2_ci_low_pct_per_hz2": c2_low,
                "c2_ci_high_pct_per_hz2": c2_high,
                "confidence": fit.confidence,
                "r2": fit.r2,
                "chi2_reduced": fit.chi2_reduced,
                "n_points": fit.n_points,
                "fit_max_hz": fit.f_max_hz,
                "tolerance_pct": lim.tolerance,
                "usable_limit_hz": lim.limit_hz,
                "u_usable_limit_hz": lim.u_limit_hz,
                "tolerance_reached": lim.reached,
                "f_max_tested_hz": lim.f_max_tested_hz,
                "track_delay_ms": t.track_delay_ms.get(method, float("nan")),
            }
        )
    return pd.DataFrame(rows)


def measurands(t: ReportTables, rig: dict[str, Any]) -> dict[str, Any]:
    """What was measured and under which conditions (GUM §10): cameras, volume, sweep, plate, rotor."""
    cams = c if isinstance(c := rig.get("cameras"), dict) else {}
    out: dict[str, Any] = {
        "cameras": {
            n: {k: c.get(k) for k in ("fps", "exposure_s", "resolution_px", "driver") if k in c}
            for n, c in sorted(cams.items())
            if isinstance(c, dict)
        },
    }
    p = t.poses
    if len(p):
        out["static_poses"] = {
            "n_marker_poses": len(p),
            "n_targets": int(p["target"].nunique()),
            "n_cycles": int(p["cycle"].nunique()),
            "distance_from_cameras_mm": [float(p["distance_mm"].min()), float(p["distance_mm"].max())],
        }
    if t.sweep is not None:
        prof = np.asarray(t.sweep["profile"], float)
        out["sweep"] = {
            "amplitude_mm": float(t.sweep["amplitude_mm"]),
            "frequency_hz": [float(prof[:, 1].min()), float(prof[:, 1].max())],
            "duration_s": float(t.sweep["t_stop_s"] - t.sweep["t_start_s"]),
            "axis": list(map(float, t.sweep["axis"])),
        }
    if t.plate_event is not None:
        out["plate"] = {k: t.plate_event.get(k) for k in ("frequency_hz", "amplitude_mm")}
    if t.rotation is not None:
        out["rotor"] = {k: t.rotation.get(k) for k in ("frequency_hz", "radius_mm")}
    return out


def fits_display(t: ReportTables) -> pd.DataFrame:
    """The fit table for the page: coefficients with their intervals as text, the usable limit with U."""
    rows: list[dict[str, Any]] = []
    for method in t.sync_methods:
        fit, lim = t.fits.get(method), t.limits.get(method)
        if fit is None or lim is None:  # a fit always comes with its limit
            rows.append({"sync method": method, "c0 (%)": t.fit_notes.get(method, "no sweep data")})
            continue
        h0, h2 = fit.t_factor * fit.u_c0, fit.t_factor * fit.u_c2  # 95 % half-widths
        if lim.reached and lim.source == "fit":
            usable = f"{lim.limit_hz:.2f} ± {fit.t_factor * lim.u_limit_hz:.2g}"
        elif lim.reached:
            usable = f"{lim.limit_hz:.2f} (last bin within tolerance beyond the fit)"
        else:
            usable = f"≥ {lim.limit_hz:.2f} (not reached)"
        rows.append(
            {
                "sync method": method,
                "c0 (%)": f"{fit.c0:.3g} ± {h0:.2g}",
                "c2 (%/Hz²)": f"{fit.c2:.3g} ± {h2:.2g}",
                "R²": fit.r2,
                "bins": fit.n_points,
                "fitted (Hz)": f"{fit.f_min_hz:.1f}–{fit.f_max_hz:.1f}",
                f"usable limit at ±{lim.tolerance:g} % (Hz)": usable,
                "track delay (ms)": t.track_delay_ms.get(method, float("nan")),
            }
        )
    return pd.DataFrame(rows)


def length_summary(lengths: pd.DataFrame) -> pd.DataFrame:
    """Per marker pair: number of test lengths, calibrated length, mean and worst ΔL (mm)."""
    if lengths.empty:
        return lengths
    g = lengths.groupby(["marker_a", "marker_b"], sort=True)
    return g.agg(
        n=("length_error_mm", "size"),
        length_cal_mm=("length_cal_mm", "mean"),
        length_error_mean_mm=("length_error_mm", "mean"),
        length_error_max_abs_mm=("length_error_mm", lambda s: float(s.abs().max())),
    ).reset_index()


def timing_frame(timing: TimingResult | None) -> pd.DataFrame:
    """Per camera: offset (s), line time (s) and clock drift (ppm) of timing.json, each with its standard
    uncertainty (NaN where absent)."""
    quantities = ("offset_s", "line_time_s", "drift_ppm")
    columns = ["camera", *[c for q in quantities for c in (q, f"u_{q}")]]
    if timing is None:
        return pd.DataFrame(columns=columns)
    nan = float("nan")
    rows = []
    for c in sorted(set(timing.offset_s) | set(timing.line_time_s)):
        row: dict[str, Any] = {"camera": c}
        values_by_q = (timing.offset_s, timing.line_time_s, timing.drift_ppm)
        for q, values in zip(quantities, values_by_q, strict=True):
            row[q] = values.get(c, nan)
            row[f"u_{q}"] = timing.uncertainty.get(q, {}).get(c, nan)
        rows.append(row)
    return pd.DataFrame(rows, columns=columns)
