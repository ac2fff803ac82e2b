"""All report tables from the run data and the analysis tracks — pure functions, no file I/O.

:func:`compute_tables` takes the record (:class:`reports.load.RunData`), the tracks of each sync method
(``{method: Analysis.tracks}``, the first being the primary method) and the acceptance settings, and
returns a :class:`ReportTables` from which the figures, the HTML and the certificate are drawn.
:func:`measured_values` turns the tables into the certificate's measured values with uncertainties.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from reports import band, band_phase, frequency, motion, phase, position, step_phase
from reports.certificate import Measured
from reports.errors import FitError
from reports.load import (
    RunData,
    accuracy_poses,
    calibration_residuals,
    camera_centres_mm,
    stream_events,
    typed_events,
)
from reports.quadfit import QuadraticFit, UsableLimit, fit_quadratic, usable_limit_with_bins
from reports.select import event_window
from rig.record.events import BandSweepEvent, SweepEvent
from rig.stereo.timing import TimingResult

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
    timing: TimingResult | None = None
    clock: pd.DataFrame | None = None  # the analysis' controller-clock offsets (Analysis.clock)
    phase: phase.PhaseResult | None = None  # the primary method's sweep delay and phase per bin
    centres_mm: dict[str, np.ndarray] = field(default_factory=dict)
    band_bins: pd.DataFrame | None = None  # the interleaved per-bin fits (reports.band.BAND_COLUMNS)
    band: dict[str, Any] | None = None  # the band by method and the certified edge (reports.band)
    extended: band_phase.ExtendedBand | None = None  # certify's shaker band step (reports.band_phase)
    steps: step_phase.StepPhase | None = None  # the sweep's steady steps (reports.step_phase)


def camera_fps(rig: dict[str, Any]) -> tuple[float, str]:
    """Camera frame rate from the rig snapshot (``cameras.<name>.fps``); else 60 fps."""
    cams = rig.get("cameras")
    entries = list(cams.values()) if isinstance(cams, dict) else cams if isinstance(cams, list) else []
    raw = [c.get("fps") for c in entries if isinstance(c, dict)]
    values = [float(v) for v in raw if isinstance(v, (int, float)) and v > 0]
    if values:
        return float(np.median(values)), "rig.cameras.*.fps"
    return DEFAULT_FPS, "default (no fps in the rig snapshot)"


def _alpha(timing: TimingResult | None, fs_hz: float) -> float | None:
    offset_s = _other_offset_s(timing)
    return None if offset_s is None else frequency.fractional_delay(offset_s, fs_hz)


def compute_tables(
    run: RunData,
    tracks_by_method: dict[str, pd.DataFrame],
    acceptance: dict[str, Any],
    *,
    gate_mm: float = position.DEFAULT_GATE_MM,
    bin_hz: float = frequency.DEFAULT_BIN_HZ,
    clock: pd.DataFrame | None = None,
) -> ReportTables:
    """Compute every table. ``clock``: the primary analysis' controller-clock offsets (``Analysis.clock``:
    ``segment``, ``session``, ``offset_s``, ``u_offset_s``, ``source``).

    Stages: static poses → sweep bins → per-method fits and usable limits → plate → rotation →
    trajectory of the most moving marker."""
    if not tracks_by_method:
        raise FitError("tracks_by_method must hold at least the primary sync method")
    methods = list(tracks_by_method)
    tracks = tracks_by_method[methods[0]]
    timing, calibration = run.timing, run.calibration
    fs_hz, fs_source = camera_fps(run.rig)
    centres = camera_centres_mm(calibration)
    poses = position.add_geometry(
        position.position_errors(position.match_static(tracks, accuracy_poses(run.events), gate_mm=gate_mm)),
        centres,
    )
    sweeps = typed_events(run.events, SweepEvent)
    # the last: a procedure's own step follows its preparation
    sweep = sweeps[-1].to_dict() if sweeps else None
    bins, reference_note = _sweep_bins(run, sweep, tracks_by_method, bin_hz)
    out = ReportTables(
        primary_sync=methods[0],
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
        fit_max_hz=float(acceptance.get("fit_max_hz") or fs_hz / 3),
        calibration=calibration_residuals(calibration),
        timing=timing,
        clock=clock,
        centres_mm=centres,
    )
    if reference_note:
        out.notes.append(reference_note)
    for method in methods:
        _fit_method(out, method, acceptance)
    _band_tables(out, run, tracks, acceptance, bin_hz)
    out.extended = _extended_band(out, run, tracks, acceptance, bin_hz)
    out.phase = _sweep_phase(out, run, sweep)
    out.steps = _sweep_steps(out, run, tracks, sweep, acceptance)
    _plate_tables(out, run, tracks, gate_mm)
    rotations = stream_events(run.events, "rotation")
    if len(sweeps) > 1 or len(rotations) > 1:
        out.notes.append(
            f"{len(sweeps)} sweep and {len(rotations)} rotation events recorded; "
            "the report analyses the last of each (the procedure's own step; earlier ones prepared it)"
        )
    if rotations:
        _rotation_tables(out, tracks, rotations[-1])  # `rig run rotation`: its own step, not the sync's
    out.trajectory, out.trajectory_source = _trajectory(tracks, out.plate_event, sweep, out.rotation_samples)
    return out


def _sweep_bins(
    run: RunData, sweep: dict[str, Any] | None, tracks_by_method: dict[str, pd.DataFrame], bin_hz: float
) -> tuple[pd.DataFrame, str]:
    """Amplitude and phase per frequency bin, track and sync method of the sweep; the reference's note."""
    if sweep is None:
        return pd.DataFrame(columns=frequency.BIN_COLUMNS), ""
    # the phase reference is the crank's polled actual frequency, not the commanded profile it leads
    reference, source = frequency.reference_sweep(sweep, stream_events(run.events, "exciter"))
    parts = [
        frequency.amplitude_by_bin(
            frequency.sweep_samples(tr, reference), reference, sync_method=method, bin_hz=bin_hz
        )
        for method, tr in tracks_by_method.items()
    ]
    return pd.concat(parts, ignore_index=True), f"sweep phase reference: {source}"


def _sweep_phase(out: ReportTables, run: RunData, sweep: dict[str, Any] | None) -> phase.PhaseResult | None:
    """The primary method's delay against the excitation and its phase per bin (:mod:`reports.phase`),
    with the sweep segment's controller-clock uncertainty; None without a sweep or a dated segment."""
    if sweep is None or out.clock is None or out.sweep_bins.empty:
        return None
    rows = out.clock[out.clock["segment"].astype(str) == str(sweep.get("segment"))]
    if not len(rows):
        return None
    row = rows.loc[rows["u_offset_s"].astype(float).idxmax()]
    polled = stream_events(run.events, "exciter")
    source = frequency.reference_sweep(sweep, polled)[1]
    return phase.phase_of_sweep(out.sweep_bins, out.primary_sync, u_clock_s=float(row["u_offset_s"]),
                                clock_source=str(row["source"]), reference=phase.reference_resolution(polled,
                                                                                                       source))


def _segment_clock(out: ReportTables, segment: Any) -> tuple[float, str] | None:
    """(u_offset_s at worst, source) of the analysis' controller clock over ``segment``; None when absent."""
    if out.clock is None:
        return None
    rows = out.clock[out.clock["segment"].astype(str) == str(segment)]
    if not len(rows):
        return None
    row = rows.loc[rows["u_offset_s"].astype(float).idxmax()]
    return float(row["u_offset_s"]), str(row["source"])


def _sweep_steps(out: ReportTables, run: RunData, tracks: pd.DataFrame, sweep: dict[str, Any] | None,
                 acceptance: dict[str, Any]) -> step_phase.StepPhase | None:
    """The sweep's steady steps (:mod:`reports.step_phase`) on the primary method's tracks; None without a
    sweep, a dated segment or a flat stretch in its reference profile."""
    clock = _segment_clock(out, sweep.get("segment")) if sweep is not None else None
    if sweep is None or clock is None:
        return None
    polled = stream_events(run.events, "exciter")
    reference, source = frequency.reference_sweep(sweep, polled)
    settle = acceptance.get("step_settle_s")
    return step_phase.step_phase(
        tracks, sweep, reference, fs_hz=out.fs_hz, u_clock_s=clock[0], clock_source=clock[1],
        sync_method=out.primary_sync,
        settle_s=float(settle) if settle is not None else step_phase.DEFAULT_SETTLE_S,
        sweep_phase=out.phase, resolution=phase.reference_resolution(polled, source))


def _fit_method(out: ReportTables, method: str, acceptance: dict[str, Any]) -> None:
    """One sync method's track delay, quadratic fit and usable frequency limit (or why not) into ``out``."""
    bins = out.sweep_bins
    b = bins[bins["sync_method"] == method]
    if b["frequency_hz"].nunique() >= 2:
        # phase = const − 360°·f·τ for tracks delayed by τ against the rig clock: one slope, an
        # intercept per track (each track's phase is relative to its own first bin)
        df = b["frequency_hz"] - b.groupby("track")["frequency_hz"].transform("mean")
        dp = b["phase_deg"] - b.groupby("track")["phase_deg"].transform("mean")
        slope = float((df * dp).sum() / (df**2).sum())
        out.track_delay_ms[method] = -slope / 360.0 * 1000.0
    sel = bins[(bins["sync_method"] == method) & (bins["frequency_hz"] <= out.fit_max_hz)]
    try:
        fit = fit_quadratic(sel["frequency_hz"], sel["amplitude_error_pct"], sel["u_amplitude_error_pct"])
    except FitError as exc:
        out.fit_notes[method] = str(exc)
        return
    out.fits[method] = fit
    # per bin: mean over tracks; u = the tracks' mean u (they share the timing errors: not averaged down)
    cols = ["frequency_hz", "amplitude_error_pct", "u_amplitude_error_pct"]
    # tracks at the reference camera's instants: a bin above fs/2 is fitted on the alias's samples with the
    # reference phase — it may agree with the truth, but the track itself shows the alias, so no bin
    # beyond one camera's Nyquist limit counts towards the usable limit (reports.band: the interleaved fit)
    per_bin = b[b["frequency_hz"] <= out.fs_hz / 2].groupby("bin", sort=True)[cols].mean()
    out.limits[method] = usable_limit_with_bins(
        fit,
        per_bin["frequency_hz"].to_numpy(),
        per_bin["amplitude_error_pct"].to_numpy(),
        float(acceptance["amplitude_error_pct"]),
        u_bins=per_bin["u_amplitude_error_pct"].to_numpy(),
        guard_k=2.0 if acceptance.get("decision_rule", "guarded") == "guarded" else 0.0,
    )


def _band_tables(out: ReportTables, run: RunData, tracks: pd.DataFrame, acceptance: dict[str, Any],
                 bin_hz: float) -> None:
    """The sweep's interleaved bins and the band by method (:mod:`reports.band`) into ``out``."""
    if out.sweep is None:
        return
    reference, _ = frequency.reference_sweep(out.sweep, stream_events(run.events, "exciter"))
    out.band_bins, notes = band.interleaved_bins(run, tracks, out.clock, reference, fs_hz=out.fs_hz,
                                                 bin_hz=bin_hz)
    out.notes += notes
    bins = out.band_bins
    alpha = None
    if len(bins):  # where the marker's instants actually fall (rolling-shutter rows included)
        z = np.exp(2j * np.pi * bins["alpha_frames"].to_numpy(float)).mean()
        alpha = float(np.mod(np.angle(z) / (2 * np.pi), 1.0))
    guard_k = 2.0 if acceptance.get("decision_rule", "guarded") == "guarded" else 0.0
    out.band = band.band_summary(bins, out.limits, fs_hz=out.fs_hz, offset_s=_other_offset_s(out.timing),
                                 measured_alpha=alpha, tolerance_pct=float(acceptance["amplitude_error_pct"]),
                                 guard_k=guard_k)


def _extended_band(out: ReportTables, run: RunData, tracks: pd.DataFrame, acceptance: dict[str, Any],
                   bin_hz: float) -> band_phase.ExtendedBand | None:
    """Certify's band step (the last ``band_sweep`` event): interleaved bins with the phase against the
    generator's waveform (:mod:`reports.band_phase`); None without one."""
    events = typed_events(run.events, BandSweepEvent)
    if not events:
        return None
    sweep = events[-1].to_dict()
    bins, notes = band.interleaved_bins(run, tracks, out.clock, sweep, fs_hz=out.fs_hz, bin_hz=bin_hz)
    u_clock_s, source = float("nan"), "no controller clock for the band segment"
    if out.clock is not None:
        rows = out.clock[out.clock["segment"].astype(str) == str(sweep.get("segment"))]
        if len(rows):
            row = rows.loc[rows["u_offset_s"].astype(float).idxmax()]
            u_clock_s, source = float(row["u_offset_s"]), str(row["source"])
    ext = band_phase.extended_band(bins, sweep, u_clock_s=u_clock_s, clock_source=source,
                                   acceptance=acceptance)
    ext.notes += notes
    return ext


def _other_offset_s(timing: TimingResult | None) -> float | None:
    if timing is None:
        return None
    others = [v for k, v in sorted(timing.offset_s.items()) if k != timing.reference_camera]
    return others[0] if others else None


def _plate_tables(out: ReportTables, run: RunData, tracks: pd.DataFrame, gate_mm: float) -> None:
    """The plate's per-track vibration table of every plate event (and the first event) into ``out``."""
    plates = stream_events(run.events, "plate")
    if not plates:
        return
    out.plate_event = plates[0]
    targets = run.rig.get("targets")
    geometry = (targets or {}).get("plate") if isinstance(targets, dict) else None
    tables = [
        motion.plate_table(tracks, p, geometry, gate_mm=gate_mm).assign(event=i) for i, p in enumerate(plates)
    ]
    out.plate = pd.concat(tables, ignore_index=True)


def _rotation_tables(out: ReportTables, tracks: pd.DataFrame, rotation: dict[str, Any]) -> None:
    """The rotor marker's samples, summary and (from 8 samples) amplitude spectrum into ``out``."""
    out.rotation = rotation
    samples = motion.rotation_samples(tracks, rotation)
    out.rotation_samples = samples
    out.rotation_summary = motion.rotation_summary(samples, rotation)
    if len(samples) >= 8:
        out.spectrum = motion.amplitude_spectrum(samples["time_s"], samples["z_mm"])


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


REFERENCE = ("reference position (robot AP / artefact)", "B")


def measured_values(t: ReportTables, acceptance: dict[str, Any]) -> dict[str, Measured | None]:
    """The certificate's measured values with their uncertainty budgets (k = 2 unless a t-factor applies).

    Type A components come from the data (standard errors of means, fit covariances); the Type B
    component ``reference_u_mm`` is the standard uncertainty of a commanded position (robot accuracy or
    artefact calibration), taken as independent per pose.
    """
    u_ref_mm = float(acceptance["reference_u_mm"])
    m: dict[str, Measured | None] = {}
    m.update(_position_values(t.poses, u_ref_mm))
    m.update(_repeatability_value(t.iso9283))
    m.update(_length_value(t.lengths, u_ref_mm))
    m.update(_sweep_values(t, float(acceptance["amplitude_error_up_to_hz"]), u_ref_mm))
    m.update(_steady_values(t, u_ref_mm))
    if t.calibration is not None and len(t.calibration) and t.calibration["rms_px"].notna().any():
        m["calibration_rms_px"] = Measured(
            float(t.calibration["rms_px"].max()), 0.0, note="from calibration.json"
        )
    sync = sync_uncertainty(t.timing, t.clock)
    if sync is not None:
        m["sync_uncertainty_ms"] = sync
    m.update(_timing_values(t.phase))
    m.update(band_phase.measured_values(t.extended))
    m.update(step_phase.measured_values(t.steps))
    return m


def _timing_values(ph: phase.PhaseResult | None) -> dict[str, Measured]:
    """The sweep's delay against the excitation and the controller↔camera clock's uncertainty behind it.

    Without the timing fiducial the start events leave the clock to ±½ frame: the delay's U then usually
    reaches its limit, and the certificate states it without deciding
    (:func:`reports.certificate.beyond_resolution`)."""
    if ph is None:
        return {}
    fiducial = ph.clock_source.startswith("timing fiducial")
    clock_u_ms = next(c[2] for c in ph.budget if c[0] == "controller↔camera clock")
    how = "timing fiducial" if fiducial else "start events (±½ frame; no timing fiducial in this run)"
    p10, u10 = ph.phase_at_deg(10.0)
    p25, u25 = ph.phase_at_deg(25.0)
    delay = Measured.from_budget(
        abs(ph.delay_ms), ph.budget,
        note=f"sync '{ph.sync_method}', τ = {ph.delay_ms:+.4g} ms over {len(ph.bins)} bins "
             f"{ph.bins['frequency_hz'].min():.3g}–{ph.bins['frequency_hz'].max():.3g} Hz; phase "
             f"{p10:+.3g} ± {2 * u10:.2g}° at 10 Hz, {p25:+.3g} ± {2 * u25:.2g}° at 25 Hz (k = 2); clock: "
             f"{how}; reference: {ph.reference.source}")
    clock = Measured(clock_u_ms, 0.0, note=f"sweep segment, {how}: {ph.clock_source}")
    out = {"phase_delay_ms": delay,
           "controller_clock_u_ms": clock if fiducial else dataclasses.replace(
               clock, decidable=False, note=clock.note + "; the criterion is the timing fiducial's")}
    return out


def _unsettled_note(poses: pd.DataFrame) -> str:
    """``, k samples left out …`` when some of ``poses``' samples were taken while a marker still moved (see
    :func:`reports.position.settled_samples`), else ''."""
    left_out = int(poses["n_unsettled"].sum())
    if not left_out:
        return ""
    where = f" in {int((poses['n_unsettled'] > 0).sum())} of them" if len(poses) > 1 else ""
    return f", {left_out} samples{where} left out: taken while the marker still moved"


def _position_values(poses: pd.DataFrame, u_ref_mm: float) -> dict[str, Measured]:
    """Detection rate, largest and RMS position error of the static poses."""
    m: dict[str, Measured] = {}
    p = poses.dropna(subset=["error_mm"])
    if len(poses):
        m["detection_pct"] = Measured(100.0 * len(p) / len(poses), 0.0, note="counted; no uncertainty")
    if not len(p):
        return m
    e = p["error_mm"].to_numpy(float)
    u_a = np.nan_to_num(p["u_error_mm"].to_numpy(float))
    i = int(np.argmax(e))
    m["position_max_mm"] = Measured.from_budget(
        float(e[i]),
        [("mean of the static samples", "A", float(u_a[i])), (*REFERENCE, u_ref_mm)],
        note=f"pose {p['index'].iloc[i]}, marker {p['marker_id'].iloc[i]} "
        f"({int(p['n_samples'].iloc[i])} samples{_unsettled_note(p.iloc[[i]])})",
    )
    rms = float(np.sqrt(np.mean(e**2)))
    w = e / (len(e) * rms) if rms > 0 else np.full(len(e), 1 / np.sqrt(len(e)))  # ∂rms/∂e_i
    m["position_rms_mm"] = Measured.from_budget(
        rms,
        [
            ("means of the static samples", "A", float(np.sqrt(np.sum((w * u_a) ** 2)))),
            (*REFERENCE, float(u_ref_mm * np.sqrt(np.sum(w**2)))),
        ],
        note=f"{len(e)} marker poses{_unsettled_note(p)}",
    )
    return m


def _repeatability_value(iso9283: pd.DataFrame) -> dict[str, Measured]:
    """The largest ISO 9283 position repeatability RP_l over targets and markers."""
    rp = iso9283.dropna(subset=["rp_l_mm"])
    if not len(rp):
        return {}
    row = rp.iloc[int(np.argmax(rp["rp_l_mm"].to_numpy(float)))]
    n, sd = int(row["n_cycles"]), float(row["s_l_mm"])
    return {"repeatability_mm": Measured.from_budget(
        float(row["rp_l_mm"]),
        [
            ("mean distance l̄ (s/√n)", "A", sd / math.sqrt(n)),
            ("3·S_l (3·s/√(2(n−1)))", "A", 3 * sd / math.sqrt(2 * (n - 1))),
        ],
        note=f"target {row['target']}, marker {row['marker_id']}, {n} cycles",
    )}


def _length_value(lengths: pd.DataFrame, u_ref_mm: float) -> dict[str, Measured]:
    """The largest test-length error between two markers of one pose."""
    if not len(lengths):
        return {}
    dl = lengths["length_error_mm"].abs().to_numpy(float)
    k = int(np.argmax(dl))
    return {"length_error_mm": Measured.from_budget(
        float(dl[k]),
        [
            ("means of the two endpoints", "A", float(lengths["u_length_mm"].iloc[k])),
            # a rigid artefact carries robot pose errors along: only its marker coordinates count
            ("marker coordinates on the artefact (two endpoints)", "B", math.sqrt(2) * u_ref_mm),
        ],
        note=f"{len(dl)} test lengths; worst {lengths['marker_a'].iloc[k]}–"
        f"{lengths['marker_b'].iloc[k]} in pose {lengths['index'].iloc[k]}",
    )}


def _sweep_values(t: ReportTables, f_up_hz: float, u_ref_mm: float) -> dict[str, Measured]:
    """The primary method's worst amplitude error over 0–``f_up_hz`` and its usable frequency limit."""
    fit = t.fits.get(t.primary_sync)
    if fit is None or t.sweep is None:
        return {}
    # |c0 + c2·f²| is largest at f = 0 or f = f_up (monotone in f²)
    f_worst = f_up_hz if abs(fit.predict(f_up_hz)) >= abs(fit.c0) else 0.0
    note = (
        f"sync '{t.primary_sync}', worst at {f_worst:g} Hz of 0–{f_up_hz:g} Hz; fit "
        f"{fit.f_min_hz:.1f}–{fit.f_max_hz:.1f} Hz; k = t(0.975, {fit.dof})"
    )
    if f_up_hz > fit.f_max_hz:
        note += "; extrapolated beyond the fitted range"
    amplitude = Measured.from_budget(
        float(abs(fit.predict(f_worst))),
        [
            ("quadratic fit (scaled covariance)", "A", float(fit.u_predict(f_worst))),
            ("reference amplitude (crank radius)", "B", 100 * u_ref_mm / float(t.sweep["amplitude_mm"])),
        ],
        k=fit.t_factor,
        note=note,
    )
    return {"amplitude_error_pct": amplitude, "min_usable_frequency_hz": _usable_limit_value(
        t.limits[t.primary_sync], fit.t_factor)}


def _usable_limit_value(lim: UsableLimit, t_factor: float) -> Measured:
    """The usable frequency limit: from the fit (delta-method uncertainty) or a lower bound."""
    if lim.reached and lim.source != "fit":
        return Measured(
            lim.limit_hz,
            0.0,
            note=f"last bin beyond the fitted range with |e| ≤ {lim.tolerance:g} %; "
            "the next bin exceeds it (a lower bound at bin resolution)",
        )
    if lim.reached:
        return Measured.from_budget(
            lim.limit_hz,
            [("quadratic fit (delta method)", "A", lim.u_limit_hz)],
            k=t_factor,
            note=f"|e| reaches {lim.tolerance:g} % here",
        )
    return Measured(
        lim.limit_hz,
        0.0,
        note=f"|e| stays below {lim.tolerance:g} % up to the highest tested frequency (a lower bound)",
    )


def _steady_values(t: ReportTables, u_ref_mm: float) -> dict[str, Measured]:
    """The worst steady-motion frequency error (plate tracks, rotor) and the rotor radius error."""
    m: dict[str, Measured] = {}
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
            [
                ("mean radius (s/√n)", "A", float(rs["u_radius_mm"])),
                ("rotor centre and radius", "B", u_ref_mm),
            ],
            note=f"{rs['n_samples']} samples",
        )
    return m


def sync_uncertainty(timing: TimingResult | None, clock: pd.DataFrame | None) -> Measured | None:
    """The largest camera offset uncertainty of timing.json (ms; camera ↔ reference camera: what the
    triangulation of moving markers depends on), None when timing.json gives none. The note names the
    controller-clock offset's worst uncertainty (reference camera ↔ controller, :func:`controller_clock`),
    which shifts whole tracks against the commanded truth in time but not the cameras against each other;
    it is reported beside the criterion, not in it (its 1 ms limit is for the cameras' sync)."""
    u_cam = timing.uncertainty.get("offset_s", {}) if timing is not None else {}
    if not u_cam:
        return None
    camera = max(u_cam, key=lambda c: u_cam[c])
    note = f"camera {camera!r}, from timing.json"
    worst = _worst_clock(clock)
    if worst is not None:
        note += (f"; controller clock ↔ reference camera (not in this value): u = "
                 f"{1000 * float(worst['u_offset_s']):.3g} ms at worst (segment {worst['segment']!r})")
    # the value is itself a standard uncertainty; its own uncertainty is not evaluated (u = 0)
    return Measured(1000 * u_cam[camera], 0.0, note=note)


def _worst_clock(clock: pd.DataFrame | None) -> pd.Series | None:
    if clock is None or not len(clock):
        return None
    return clock.loc[clock["u_offset_s"].astype(float).idxmax()]


def controller_clock(clock: pd.DataFrame | None) -> list[dict[str, Any]]:
    """Per analysed segment: the controller − reference camera clock offset (s), its standard uncertainty
    (s) and how it was found (the analysis' ``Analysis.clock``), for the certificate."""
    if clock is None:
        return []
    return [{"segment": str(r["segment"]), "session": int(r["session"]), "offset_s": float(r["offset_s"]),
             "u_offset_s": float(r["u_offset_s"]), "source": str(r["source"])}
            for r in clock.to_dict("records")]


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
