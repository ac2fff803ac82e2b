"""All report tables from the run data and the analysis tracks — pure functions, no file I/O.

:func:`compute_tables` takes the record (:class:`reports.load.RunData`), the tracks of each sync method
(``{method: Analysis.tracks}``, the first being the primary method) and the acceptance settings, and
returns a :class:`ReportTables` from which the figures, the HTML and the certificate are drawn.
:func:`measured_values` turns the tables into the certificate's measured values with uncertainties.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from reports import frequency, motion, position
from reports.certificate import Measured
from reports.errors import FitError
from reports.load import RunData, accuracy_poses, calibration_residuals, camera_centres_mm, stream_events
from reports.quadfit import QuadraticFit, UsableLimit, fit_quadratic, usable_limit_with_bins
from reports.select import event_window

DEFAULT_FPS = 60.0


@dataclass
class ReportTables:
    """Everything the report shows. Frames have units in their column names."""

    primary_sync: str
    sync_methods: list[str]
    fs_hz: float
    fs_source: str
    alpha: float | None
    poses: pd.DataFrame
    position_summary: dict[str, float]
    iso9283: pd.DataFrame
    lengths: pd.DataFrame
    sweep: dict[str, Any] | None
    sweep_bins: pd.DataFrame
    sweep_means: pd.DataFrame
    fit_max_hz: float
    fits: dict[str, QuadraticFit] = field(default_factory=dict)
    limits: dict[str, UsableLimit] = field(default_factory=dict)
    fit_notes: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    track_delay_ms: dict[str, float] = field(default_factory=dict)
    plate: pd.DataFrame | None = None
    plate_event: dict[str, Any] | None = None
    rotation: dict[str, Any] | None = None
    rotation_samples: pd.DataFrame | None = None
    rotation_summary: dict[str, float] | None = None
    trajectory: pd.DataFrame | None = None
    trajectory_source: str = ""
    spectrum: pd.DataFrame | None = None
    calibration: pd.DataFrame | None = None
    timing: dict[str, Any] | None = None
    centres_mm: dict[str, np.ndarray] = field(default_factory=dict)


def camera_fps(rig: dict[str, Any], timing: dict[str, Any] | None) -> tuple[float, str]:
    """Camera frame rate from the rig snapshot (``cameras.<name>.fps``) or timing.json; else 60 fps."""
    cams = rig.get("cameras")
    values = []
    if isinstance(cams, dict):
        values = [c.get("fps") for c in cams.values() if isinstance(c, dict)]
    elif isinstance(cams, list):
        values = [c.get("fps") for c in cams if isinstance(c, dict)]
    values = [float(v) for v in values if isinstance(v, (int, float)) and v > 0]
    if values:
        return float(np.median(values)), "rig.cameras.*.fps"
    if timing and isinstance(timing.get("fps"), (int, float)):
        return float(timing["fps"]), "timing.json fps"
    return DEFAULT_FPS, "default (no fps in the rig snapshot)"


def _alpha(timing: dict[str, Any] | None, fs_hz: float) -> float | None:
    offsets = (timing or {}).get("offset_s") or {}
    ref = (timing or {}).get("reference_camera")
    others = [float(v) for k, v in sorted(offsets.items()) if k != ref and isinstance(v, (int, float))]
    return frequency.fractional_delay(others[0], fs_hz) if others else None


def compute_tables(
    run: RunData,
    tracks_by_method: dict[str, pd.DataFrame],
    acceptance: dict[str, Any],
    *,
    gate_mm: float = position.DEFAULT_GATE_MM,
    bin_hz: float = frequency.DEFAULT_BIN_HZ,
    timing: dict[str, Any] | None = None,
    calibration: dict[str, Any] | None = None,
) -> ReportTables:
    """Compute every table. ``timing``/``calibration`` default to the run folder's files."""
    if not tracks_by_method:
        raise FitError("tracks_by_method must hold at least the primary sync method")
    methods = list(tracks_by_method)
    primary = methods[0]
    tracks = tracks_by_method[primary]
    timing = run.timing if timing is None else timing
    calibration = run.calibration if calibration is None else calibration
    fs_hz, fs_source = camera_fps(run.rig, timing)
    centres = camera_centres_mm(calibration)

    poses = position.add_geometry(
        position.position_errors(position.match_static(tracks, accuracy_poses(run.events), gate_mm=gate_mm)),
        centres,
    )

    sweeps = stream_events(run.events, "sweep")
    sweep = sweeps[-1] if sweeps else None  # the last: a procedure's own step follows its preparation
    parts = []
    reference_note = ""
    if sweep is not None:
        # the phase reference is the crank's polled actual frequency, not the commanded profile it leads
        reference, source = frequency.reference_sweep(sweep, stream_events(run.events, "exciter"))
        reference_note = f"sweep phase reference: {source}"
        for method, tr in tracks_by_method.items():
            parts.append(
                frequency.amplitude_by_bin(
                    frequency.sweep_samples(tr, reference), reference, sync_method=method, bin_hz=bin_hz
                )
            )
    bins = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=frequency.BIN_COLUMNS)
    fit_max_hz = float(acceptance.get("fit_max_hz") or fs_hz / 3)
    out = ReportTables(
        primary_sync=primary,
        sync_methods=methods,
        fs_hz=fs_hz,
        fs_source=fs_source,
        alpha=_alpha(timing, fs_hz),
        poses=poses,
        position_summary=position.position_summary(poses),
        iso9283=position.iso9283(poses),
        lengths=position.length_errors(poses),
        sweep=sweep,
        sweep_bins=bins,
        sweep_means=frequency.bin_means(bins),
        fit_max_hz=fit_max_hz,
        calibration=calibration_residuals(calibration),
        timing=timing,
        centres_mm=centres,
    )
    if reference_note:
        out.notes.append(reference_note)
    for method in methods:
        b = bins[bins["sync_method"] == method]
        if b["frequency_hz"].nunique() >= 2:
            # phase = const − 360°·f·τ for tracks delayed by τ against the rig clock: one slope, an
            # intercept per track (each track's phase is relative to its own first bin)
            df = b["frequency_hz"] - b.groupby("track")["frequency_hz"].transform("mean")
            dp = b["phase_deg"] - b.groupby("track")["phase_deg"].transform("mean")
            slope = float((df * dp).sum() / (df**2).sum())
            out.track_delay_ms[method] = -slope / 360.0 * 1000.0
        sel = bins[(bins["sync_method"] == method) & (bins["frequency_hz"] <= fit_max_hz)]
        try:
            fit = fit_quadratic(sel["frequency_hz"], sel["amplitude_error_pct"], sel["u_amplitude_error_pct"])
        except FitError as exc:
            out.fit_notes[method] = str(exc)
            continue
        out.fits[method] = fit
        # per bin: mean over tracks; u = the tracks' mean u (they share the timing errors: not averaged down)
        cols = ["frequency_hz", "amplitude_error_pct", "u_amplitude_error_pct"]
        per_bin = b.groupby("bin", sort=True)[cols].mean()
        out.limits[method] = usable_limit_with_bins(
            fit,
            per_bin["frequency_hz"].to_numpy(),
            per_bin["amplitude_error_pct"].to_numpy(),
            float(acceptance["amplitude_error_pct"]),
            u_bins=per_bin["u_amplitude_error_pct"].to_numpy(),
            guard_k=2.0 if acceptance.get("decision_rule", "guarded") == "guarded" else 0.0,
        )

    plates = stream_events(run.events, "plate")
    if plates:
        out.plate_event = plates[0]
        geometry = (
            (run.rig.get("targets") or {}).get("plate") if isinstance(run.rig.get("targets"), dict) else None
        )
        tables = [
            motion.plate_table(tracks, p, geometry, gate_mm=gate_mm).assign(event=i)
            for i, p in enumerate(plates)
        ]
        out.plate = pd.concat(tables, ignore_index=True)
    rotations = stream_events(run.events, "rotation")
    if len(sweeps) > 1 or len(rotations) > 1:
        out.notes.append(
            f"{len(sweeps)} sweep and {len(rotations)} rotation events recorded; "
            "the report analyses the last of each (the procedure's own step; earlier ones prepared it)"
        )
    if rotations:
        out.rotation = rotations[-1]  # `rig run rotation`: its own step, not the sync step's rotor run
        out.rotation_samples = motion.rotation_samples(tracks, out.rotation)
        out.rotation_summary = motion.rotation_summary(out.rotation_samples, out.rotation)
        if len(out.rotation_samples) >= 8:
            out.spectrum = motion.amplitude_spectrum(
                out.rotation_samples["time_s"], out.rotation_samples["z_mm"]
            )
    out.trajectory, out.trajectory_source = _trajectory(tracks, out.plate_event, sweep, out.rotation_samples)
    return out


def _trajectory(
    tracks: pd.DataFrame, plate: dict | None, sweep: dict | None, rot: pd.DataFrame | None
) -> tuple[pd.DataFrame | None, str]:
    """x, y, z over time of the most moving marker (plate, else sweep, else rotor) for Figs. 5–8.

    On the plate that is the marker nearest the free end (the paper's "rightmost top marker")."""
    for name, event in (("plate", plate), ("sweep", sweep)):
        if event is None:
            continue
        prof = event.get("profile") or [
            [event["t_start_s"], event.get("frequency_hz", 1.0)],
            [event["t_stop_s"], event.get("frequency_hz", 1.0)],
        ]
        samples = frequency.sweep_samples(tracks, dict(event, profile=prof))
        if samples.empty:
            continue
        spread = samples.groupby("track", sort=True)["displacement_mm"].std()
        track = spread.index[int(np.argmax(spread.to_numpy()))]
        window = event_window(tracks, event)
        sel = window[window["track"] == track]
        out = sel[["time_s", "x_mm", "y_mm", "z_mm"]].sort_values("time_s").reset_index(drop=True)
        return out, f"{name} marker {track}"
    if rot is not None and len(rot):
        return rot[["time_s", "x_mm", "y_mm", "z_mm"]].reset_index(drop=True), "rotor marker"
    return None, ""


def _finite(x: float) -> bool:
    return x is not None and math.isfinite(x)


def measured_values(t: ReportTables, acceptance: dict[str, Any]) -> dict[str, Measured | None]:
    """The certificate's measured values with their uncertainty budgets (k = 2 unless a t-factor applies).

    Type A components come from the data (standard errors of means, fit covariances); the Type B
    component ``reference_u_mm`` is the standard uncertainty of a commanded position (robot accuracy or
    artefact calibration), taken as independent per pose.
    """
    u_ref = float(acceptance["reference_u_mm"])
    ref = ("reference position (robot AP / artefact)", "B")
    m: dict[str, Measured | None] = {}
    p = t.poses.dropna(subset=["error_mm"])
    if len(t.poses):
        m["detection_pct"] = Measured(100.0 * len(p) / len(t.poses), 0.0, note="counted; no uncertainty")
    if len(p):
        e = p["error_mm"].to_numpy(float)
        u_a = np.nan_to_num(p["u_error_mm"].to_numpy(float))
        i = int(np.argmax(e))
        m["position_max_mm"] = Measured.from_budget(
            float(e[i]),
            [("mean of the static samples", "A", float(u_a[i])), (*ref, u_ref)],
            note=f"pose {p['index'].iloc[i]}, marker {p['marker_id'].iloc[i]} "
            f"({int(p['n_samples'].iloc[i])} samples)",
        )
        rms = float(np.sqrt(np.mean(e**2)))
        w = e / (len(e) * rms) if rms > 0 else np.full(len(e), 1 / np.sqrt(len(e)))  # ∂rms/∂e_i
        m["position_rms_mm"] = Measured.from_budget(
            rms,
            [
                ("means of the static samples", "A", float(np.sqrt(np.sum((w * u_a) ** 2)))),
                (*ref, float(u_ref * np.sqrt(np.sum(w**2)))),
            ],
            note=f"{len(e)} marker poses",
        )
    rp = t.iso9283.dropna(subset=["rp_l_mm"])
    if len(rp):
        j = int(np.argmax(rp["rp_l_mm"].to_numpy(float)))
        row = rp.iloc[j]
        n, sd = int(row["n_cycles"]), float(row["s_l_mm"])
        m["repeatability_mm"] = Measured.from_budget(
            float(row["rp_l_mm"]),
            [
                ("mean distance l̄ (s/√n)", "A", sd / math.sqrt(n)),
                ("3·S_l (3·s/√(2(n−1)))", "A", 3 * sd / math.sqrt(2 * (n - 1))),
            ],
            note=f"target {row['target']}, marker {row['marker_id']}, {n} cycles",
        )
    if len(t.lengths):
        dl = t.lengths["length_error_mm"].abs().to_numpy(float)
        k = int(np.argmax(dl))
        m["length_error_mm"] = Measured.from_budget(
            float(dl[k]),
            [
                ("means of the two endpoints", "A", float(t.lengths["u_length_mm"].iloc[k])),
                # a rigid artefact carries robot pose errors along: only its marker coordinates count
                ("marker coordinates on the artefact (two endpoints)", "B", math.sqrt(2) * u_ref),
            ],
            note=f"{len(dl)} test lengths; worst {t.lengths['marker_a'].iloc[k]}–"
            f"{t.lengths['marker_b'].iloc[k]} in pose {t.lengths['index'].iloc[k]}",
        )
    fit = t.fits.get(t.primary_sync)
    if fit is not None:
        f_up = float(acceptance["amplitude_error_up_to_hz"])
        # |c0 + c2·f²| is largest at f = 0 or f = f_up (monotone in f²)
        f_worst = f_up if abs(fit.predict(f_up)) >= abs(fit.c0) else 0.0
        note = (
            f"sync '{t.primary_sync}', worst at {f_worst:g} Hz of 0–{f_up:g} Hz; fit "
            f"{fit.f_min_hz:.1f}–{fit.f_max_hz:.1f} Hz; k = t(0.975, {fit.dof})"
        )
        if f_up > fit.f_max_hz:
            note += "; extrapolated beyond the fitted range"
        m["amplitude_error_pct"] = Measured.from_budget(
            float(abs(fit.predict(f_worst))),
            [
                ("quadratic fit (scaled covariance)", "A", float(fit.u_predict(f_worst))),
                ("reference amplitude (crank radius)", "B", 100 * u_ref / float(t.sweep["amplitude_mm"])),
            ],
            k=fit.t_factor,
            note=note,
        )
        lim = t.limits[t.primary_sync]
        if lim.reached and lim.source != "fit":
            m["min_usable_frequency_hz"] = Measured(
                lim.limit_hz,
                0.0,
                note=f"last bin beyond the fitted range with |e| ≤ {lim.tolerance:g} %; "
                "the next bin exceeds it (a lower bound at bin resolution)",
            )
        elif lim.reached:
            m["min_usable_frequency_hz"] = Measured.from_budget(
                lim.limit_hz,
                [("quadratic fit (delta method)", "A", lim.u_limit_hz)],
                k=fit.t_factor,
                note=f"|e| reaches {lim.tolerance:g} % here",
            )
        else:
            m["min_usable_frequency_hz"] = Measured(
                lim.limit_hz,
                0.0,
                note=f"|e| stays below {lim.tolerance:g} % up to the highest tested frequency "
                "(a lower bound)",
            )
    freq = _frequency_errors(t)
    if freq:
        worst = max(freq, key=lambda r: abs(r[1]))
        m["frequency_error_pct"] = Measured.from_budget(
            abs(worst[1]),
            [("four-parameter sine fit", "A", worst[2])],
            note=f"worst: {worst[0]}; {len(freq)} steady motion(s)",
        )
    rs = t.rotation_summary
    if rs and _finite(rs.get("radius_error_mm", float("nan"))):
        m["radius_error_mm"] = Measured.from_budget(
            abs(rs["radius_error_mm"]),
            [("mean radius (s/√n)", "A", float(rs["u_radius_mm"])), ("rotor centre and radius", "B", u_ref)],
            note=f"{rs['n_samples']} samples",
        )
    if t.calibration is not None and len(t.calibration) and t.calibration["rms_px"].notna().any():
        m["calibration_rms_px"] = Measured(
            float(t.calibration["rms_px"].max()), 0.0, note="from calibration.json"
        )
    u_off = ((t.timing or {}).get("uncertainty") or {}).get("offset_s")
    if isinstance(u_off, dict):
        vals = [float(v) for v in u_off.values() if isinstance(v, (int, float))]
        u_off = max(vals) if vals else None
    if isinstance(u_off, (int, float)):
        m["sync_uncertainty_ms"] = Measured(1000 * float(u_off), 0.0, note="from timing.json")
    return m


def _frequency_errors(t: ReportTables) -> list[tuple[str, float, float]]:
    """(what, error %, standard uncertainty %) of every steady measured frequency (plate tracks, rotor)."""
    out = []
    if t.plate is not None:
        plate = t.plate
        identified = plate["marker_id"].astype(str) != ""
        if identified.any():  # tracks not identified as plate markers (a still reference) say nothing of it
            plate = plate[identified]
        for _, r in plate.iterrows():
            if _finite(r["frequency_error_pct"]):
                out.append(
                    (
                        f"plate {r['track']}",
                        float(r["frequency_error_pct"]),
                        100 * float(r["u_frequency_hz"]) / float(r["frequency_ref_hz"]),
                    )
                )
    rs = t.rotation_summary
    if rs and _finite(rs.get("frequency_error_pct", float("nan"))):
        out.append(
            (
                "rotor",
                float(rs["frequency_error_pct"]),
                100 * float(rs["u_frequency_hz"]) / rs["frequency_ref_hz"],
            )
        )
    return out
