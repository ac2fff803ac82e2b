"""Phase per steady step of a stepped profile: amplitude, frequency, phase and delay of every flat stretch.

A **steady step** is a flat stretch of the sweep's reference profile (:func:`steady_steps`: consecutive
points at one frequency — the shaker's staircase, the crank's hold at its peak), from ``settle_s`` after it
begins (the motion's transient and the volts' ramp after a FREQ change; stated in the certificate) to its end,
inside the sweep's steady window, with at least ``MIN_CYCLES`` cycles and ``MIN_SAMPLES`` samples.

Per step and oscillating track (:func:`reports.frequency.sweep_samples` of the primary sync method's
tracks): a four-parameter sine fit x = A·sin(φ(t) + δ + Δω·(t − t_mid)) + c (IEEE 1057) around the
reference phase φ(t) = 2π∫f dt of the profile (:func:`fit_step`): amplitude A, frequency f + Δω/2π and the
phase δ at the step's middle, each with its standard uncertainty from the fit covariance. Per step, the
mean over the tracks (the phase on the circle; the uncertainties the tracks' mean: they share the timing
errors) and the phase budget:

* the fit (Type A: noise, and the sync method's interpolation as far as it scatters);
* the reference's phase (Type B): for a generator's staircase from its phase restart (``phase_origin_s``)
  each FREQ change happened somewhere in its bracket (``step_brackets_s``: uniform, width/√12) and moves
  every later phase by 360°·Δf·δt; a restart known only to its own bracket adds 360°·f₀·width/√12 (with
  the timing fiducial it cancels: the cameras are dated from the same restart). For a polled reference
  (the crank: the drive reports its frequency, not its angle) the read-back rounding's random walk
  (:class:`reports.phase.ReferenceResolution`) from the sweep's start, and the phase is stated against the
  sweep's fitted constant c (:mod:`reports.phase`: the crank's angle at the start is not reported);
* the controller↔camera clock (Type B, 360°·f·u_clock of the segment).

The delay is −phase/(360°·f). Steps above one camera's Nyquist limit (fs/2) are left out: the tracks hold
their alias there (the band's interleaved fit covers them, :mod:`reports.band_phase`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from reports import frequency
from reports.certificate import Measured
from reports.phase import PhaseResult, ReferenceResolution

DEFAULT_SETTLE_S = 0.1
MIN_CYCLES = 3.0
MIN_SAMPLES = 12
NYQUIST_MARGIN = 0.95  # steps up to this share of fs/2 (a tone at fs/2 has no quadrature in one camera)
STEP_COLUMNS = ["step", "t_start_s", "t_stop_s", "frequency_ref_hz", "frequency_hz", "u_frequency_hz",
                "n_tracks", "n_samples", "amplitude_error_pct", "u_amplitude_error_pct", "phase_deg",
                "u_phase_fit_deg", "u_reference_deg", "u_clock_deg", "u_phase_deg", "delay_ms", "u_delay_ms"]


@dataclass(frozen=True)
class Step:
    """One steady step: analysed from ``t_start_s`` (start + settle) to ``t_stop_s``, at ``frequency_hz``."""

    t_start_s: float
    t_stop_s: float
    frequency_hz: float


@dataclass(frozen=True)
class StepFit:
    """A four-parameter fit of one track over one step: amplitude (mm), frequency (Hz), phase δ (rad) at the
    step's middle against the reference, each with its standard uncertainty; the number of samples."""

    amplitude_mm: float
    u_amplitude_mm: float
    frequency_hz: float
    u_frequency_hz: float
    phase_rad: float
    u_phase_rad: float
    n: int


@dataclass
class StepPhase:
    """The per-step table (:data:`STEP_COLUMNS`), how the steps were found and what the phase refers to."""

    bins: pd.DataFrame
    settle_s: float
    reference: str
    clock_source: str
    u_clock_s: float
    sync_method: str
    notes: list[str] = field(default_factory=list)


def steady_steps(profile: np.ndarray, window_s: tuple[float, float], *, settle_s: float,
                 tolerance_hz: float = 1e-9) -> list[Step]:
    """The flat stretches of ``profile`` ((N, 2): t_s, f_hz) — maximal runs of consecutive points within
    ``tolerance_hz`` of the run's first — from ``settle_s`` after each begins to its end, cut to ``window_s``;
    those shorter than ``MIN_CYCLES`` cycles are left out."""
    t, f = np.asarray(profile, float)[:, 0], np.asarray(profile, float)[:, 1]
    out: list[Step] = []
    i = 0
    while i < len(t) - 1:
        j = i
        while j + 1 < len(t) and abs(f[j + 1] - f[i]) <= tolerance_hz:
            j += 1
        if j > i and f[i] > 0:
            lo, hi = max(t[i] + settle_s, window_s[0]), min(t[j], window_s[1])
            if (hi - lo) * f[i] >= MIN_CYCLES:
                out.append(Step(float(lo), float(hi), float(f[i:j + 1].mean())))
        i = max(j, i + 1)
    return out


def fit_step(t_s: np.ndarray, x_mm: np.ndarray, phi_rad: np.ndarray, f_hz: float,
             iterations: int = 4) -> StepFit:
    """Four-parameter LS fit x = a·cos ψ + b·sin ψ + c, ψ = φ + Δω·(t − t_mid) (Gauss–Newton from the
    three-parameter fit, Δω = 0): the phase δ = atan2(a, b) at t_mid (x = A·sin(φ + δ) + c)."""
    tau = t_s - 0.5 * (t_s.min() + t_s.max())
    dw = 0.0
    for _ in range(iterations):
        psi = phi_rad + dw * tau
        X = np.column_stack([np.cos(psi), np.sin(psi), np.ones_like(psi)])
        a, b, c = np.linalg.lstsq(X, x_mm, rcond=None)[0]
        J = np.column_stack([X, tau * (-a * np.sin(psi) + b * np.cos(psi))])
        step = np.linalg.lstsq(J, x_mm - X @ np.array([a, b, c]), rcond=None)[0]
        dw += float(step[3])
    psi = phi_rad + dw * tau
    X = np.column_stack([np.cos(psi), np.sin(psi), np.ones_like(psi)])
    a, b, c = np.linalg.lstsq(X, x_mm, rcond=None)[0]
    J = np.column_stack([X, tau * (-a * np.sin(psi) + b * np.cos(psi))])
    resid = x_mm - X @ np.array([a, b, c])
    s2 = float(resid @ resid) / max(len(x_mm) - 4, 1)
    cov = s2 * np.linalg.pinv(J.T @ J)
    amp = float(np.hypot(a, b))
    g_amp = np.array([a, b]) / amp
    g_phase = np.array([b, -a]) / amp**2  # ∂atan2(a, b)/∂(a, b)
    return StepFit(amp, math.sqrt(max(float(g_amp @ cov[:2, :2] @ g_amp), 0.0)),
                   f_hz + dw / (2 * math.pi), math.sqrt(max(float(cov[3, 3]), 0.0)) / (2 * math.pi),
                   float(math.atan2(a, b)), math.sqrt(max(float(g_phase @ cov[:2, :2] @ g_phase), 0.0)),
                   len(x_mm))


def staircase_reference_u_deg(sweep: dict[str, Any], t_s: float) -> float:
    """Standard uncertainty (°) of a generator staircase's phase law at ``t_s``: each earlier FREQ change
    uniform in its bracket (360°·Δf·width/√12), and the restart's own bracket unless the timing fiducial
    dated the cameras from it (module docstring)."""
    var = 0.0
    prof = np.asarray(sweep["profile"], float)
    for sent, done in sweep.get("step_brackets_s") or []:
        if 0.5 * (sent + done) >= t_s:
            continue
        k = int(np.searchsorted(prof[:, 0], 0.5 * (sent + done), side="left"))
        before = prof[max(k, 0), 1]
        after = prof[min(k + 1, len(prof) - 1), 1]
        var += (360.0 * (after - before) * (done - sent)) ** 2 / 12.0
    origin = sweep.get("phase_origin_s")
    fiducial = str(sweep.get("phase_origin", "")).startswith("PHASe:SYNChronize of the timing fiducial")
    if origin and not fiducial:
        var += (360.0 * prof[0, 1] * (origin[1] - origin[0])) ** 2 / 12.0
    return math.sqrt(var)


def _track_fits(samples: pd.DataFrame, reference: dict[str, Any], steps: list[Step]) -> pd.DataFrame:
    """One row per (step, track) with a usable fit: step, track, amplitude/frequency/phase and their u."""
    rows = []
    for track, g in samples.groupby("track", sort=True):
        t, x = g["time_s"].to_numpy(float), g["displacement_mm"].to_numpy(float)
        for k, s in enumerate(steps):
            m = (t >= s.t_start_s) & (t <= s.t_stop_s)
            if m.sum() < MIN_SAMPLES:
                continue
            phi = frequency.sweep_phase_rad(reference, t[m])
            fit = fit_step(t[m], x[m], phi, s.frequency_hz)
            rows.append({"step": k, "track": track, "t_mid_s": float(t[m].mean()), **fit.__dict__})
    return pd.DataFrame(rows)


def _per_step(fits: pd.DataFrame, steps: list[Step], amplitude_mm: float) -> pd.DataFrame:
    """Means over the tracks per step (phase on the circle), before the phase budget."""
    g = fits.groupby("step", sort=True)
    out = g[["frequency_hz", "u_frequency_hz", "amplitude_mm", "u_amplitude_mm", "u_phase_rad",
             "t_mid_s"]].mean()
    out["phase_rad"] = g["phase_rad"].agg(lambda p: float(np.angle(np.exp(1j * p.to_numpy(float)).mean())))
    out["n_tracks"] = g.size()
    out["n_samples"] = g["n"].sum()
    out["t_start_s"] = [steps[k].t_start_s for k in out.index]
    out["t_stop_s"] = [steps[k].t_stop_s for k in out.index]
    out["frequency_ref_hz"] = [steps[k].frequency_hz for k in out.index]
    out["amplitude_error_pct"] = 100.0 * (out["amplitude_mm"] - amplitude_mm) / amplitude_mm
    out["u_amplitude_error_pct"] = 100.0 * out["u_amplitude_mm"] / amplitude_mm
    return out.reset_index()


def step_phase(tracks: pd.DataFrame, sweep: dict[str, Any], reference: dict[str, Any], *, fs_hz: float,
               u_clock_s: float, clock_source: str, sync_method: str, settle_s: float = DEFAULT_SETTLE_S,
               sweep_phase: PhaseResult | None = None,
               resolution: ReferenceResolution | None = None) -> StepPhase | None:
    """The steady steps of ``reference``'s profile (the reference sweep: :func:`frequency.reference_sweep`)
    fitted on ``tracks`` (module docstring); None when the profile has no steady step.

    Without a phase origin (the crank) the phase is stated against ``sweep_phase``'s constant c (needs
    ``sweep_phase`` and ``resolution``; without them the steps' phase is NaN, with a note)."""
    prof = np.asarray(reference["profile"], float)
    window = (float(sweep["t_start_s"]), float(sweep["t_stop_s"]))
    q = resolution.q_hz if resolution is not None else 0.0
    found = steady_steps(prof, window, settle_s=settle_s, tolerance_hz=max(1e-9, 0.5 * q))
    steps = [s for s in found if s.frequency_hz <= NYQUIST_MARGIN * fs_hz / 2]
    if not found:
        return None
    exact = bool(sweep.get("phase_origin_s"))
    ref_text = (f"the generator's phase law from its restart ({sweep.get('phase_origin') or 'bracket'}), "
                "steps at the FREQ commands' bracket midpoints" if exact else
                "the polled frequency's phase 2π∫f dt; the drive reports no angle, so the phase is stated "
                "against the sweep's fitted constant c (reports.phase)")
    result = StepPhase(pd.DataFrame(columns=STEP_COLUMNS), settle_s, ref_text, clock_source, u_clock_s,
                       sync_method)
    if len(steps) < len(found):
        result.notes.append(f"{len(found) - len(steps)} steady step(s) above {NYQUIST_MARGIN:g} × one "
                            f"camera's Nyquist limit ({fs_hz / 2:g} Hz) left out: the tracks hold the alias")
    samples = frequency.sweep_samples(tracks, sweep)
    fits = _track_fits(samples, reference, steps) if steps and not samples.empty else pd.DataFrame()
    if fits.empty:
        result.notes.append(f"{len(found)} steady step(s) found, none with {MIN_SAMPLES} samples of an "
                            "oscillating track")
        return result
    out = _per_step(fits, steps, float(sweep["amplitude_mm"]))
    phase = np.rad2deg(out["phase_rad"].to_numpy(float))
    f = out["frequency_ref_hz"].to_numpy(float)
    u_fit = np.rad2deg(out["u_phase_rad"].to_numpy(float))
    if exact:
        u_ref = np.array([staircase_reference_u_deg(sweep, t) for t in out["t_mid_s"]])
    else:
        phase, u_ref = _against_sweep_line(out, fits, samples, reference=reference, sweep_phase=sweep_phase,
                                           resolution=resolution)
        if sweep_phase is None:
            result.notes.append("steady steps of a reference without a phase origin: phase not stated (no "
                                "sweep line to refer it to)")
    u_clock = 360.0 * f * u_clock_s
    out["phase_deg"] = phase
    out["u_phase_fit_deg"] = u_fit
    out["u_reference_deg"] = u_ref
    out["u_clock_deg"] = u_clock
    out["u_phase_deg"] = np.sqrt(u_fit**2 + u_ref**2 + u_clock**2)
    out["delay_ms"] = -phase / (360.0 * f) * 1000.0
    out["u_delay_ms"] = out["u_phase_deg"] / (360.0 * f) * 1000.0
    result.bins = out[STEP_COLUMNS]
    return result


def _against_sweep_line(out: pd.DataFrame, fits: pd.DataFrame, samples: pd.DataFrame, *,
                        reference: dict[str, Any], sweep_phase: PhaseResult | None,
                        resolution: ReferenceResolution | None) -> tuple[np.ndarray, np.ndarray]:
    """A polled reference's step phases as :mod:`reports.phase` states its bins: each track's phase relative
    to its first frequency bin (:func:`frequency.amplitude_by_bin`'s convention) minus the sweep line's
    constant c; u: the reference's random walk from the sweep's first bin and c's own."""
    if sweep_phase is None or resolution is None:
        return np.full(len(out), np.nan), np.full(len(out), np.nan)
    first = _first_bin_phase_rad(samples, reference)
    rel = fits.assign(rel=np.exp(1j * (fits["phase_rad"] - fits["track"].map(first))))
    rel = rel.dropna(subset=["rel"]).groupby("step")["rel"].mean()
    p = np.rad2deg(np.angle(rel.reindex(out["step"]).to_numpy(complex))) - sweep_phase.intercept_deg
    p = np.rad2deg(np.angle(np.exp(1j * np.deg2rad(p))))
    t0 = float(sweep_phase.bins["t_mid_s"].min())
    walk = np.sqrt(resolution.walk_deg2_per_s() * np.maximum(out["t_mid_s"].to_numpy(float) - t0, 0.0))
    return p, np.hypot(walk, sweep_phase.u_intercept_deg)


def _first_bin_phase_rad(samples: pd.DataFrame, reference: dict[str, Any]) -> dict[str, float]:
    """Each track's absolute phase (rad) in its first frequency bin, as amplitude_by_bin selects it."""
    out = {}
    for track, g in samples.groupby("track", sort=True):
        t, x = g["time_s"].to_numpy(float), g["displacement_mm"].to_numpy(float)
        phi = frequency.sweep_phase_rad(reference, t)
        first = next(frequency.fitted_bins(frequency.profile_frequency_hz(reference, t), phi), None)
        if first is None:
            continue
        m = first[2]
        out[str(track)] = frequency._fit_bin(t[m], x[m], phi[m])[2]
    return out


def measured_values(sp: StepPhase | None) -> dict[str, Measured]:
    """``step_phase_deg``: the worst step's |phase| with its budget (steps with a stated phase)."""
    if sp is None or sp.bins.empty or not np.isfinite(sp.bins["phase_deg"].to_numpy(float)).any():
        return {}
    t = sp.bins[np.isfinite(sp.bins["phase_deg"].to_numpy(float))]
    j = int(np.argmax(np.abs(t["phase_deg"].to_numpy(float))))
    r = t.iloc[j]
    clock = "timing fiducial" if sp.clock_source.startswith("timing fiducial") else \
        "start events (±½ frame: no timing fiducial in this segment)"
    return {"step_phase_deg": Measured.from_budget(
        abs(float(r["phase_deg"])),
        [("four-parameter fit of the step", "A", float(r["u_phase_fit_deg"])),
         ("reference phase law", "B", float(r["u_reference_deg"])),
         ("controller↔camera clock", "B", float(r["u_clock_deg"]))],
        note=f"worst of {len(t)} steady steps {t['frequency_ref_hz'].min():.3g}–"
             f"{t['frequency_ref_hz'].max():.3g} Hz: {r['frequency_ref_hz']:.4g} Hz, delay "
             f"{r['delay_ms']:+.4g} ± {2 * r['u_delay_ms']:.2g} ms (k = 2); settle {sp.settle_s:g} s; "
             f"clock: {clock}")}


def section(sp: StepPhase | None) -> dict[str, Any] | None:
    """The certificate's ``steady_steps`` section (plain JSON types)."""
    if sp is None:
        return None
    return {
        "sync_method": sp.sync_method,
        "settle_s": sp.settle_s,
        "reference": sp.reference,
        "clock_source": sp.clock_source,
        "u_clock_ms": 1000.0 * sp.u_clock_s,
        "model": "x = A·sin(φ(t) + phase + Δω·(t − t_mid)) + c per step and track (four-parameter fit), "
                 "φ the reference's phase 2π∫f dt; delay = −phase/(360°·f)",
        "steps": sp.bins.to_dict("records"),
        "notes": list(sp.notes),
    }


__all__ = ["DEFAULT_SETTLE_S", "STEP_COLUMNS", "Step", "StepFit", "StepPhase", "fit_step", "measured_values",
           "section", "staircase_reference_u_deg", "steady_steps", "step_phase"]
