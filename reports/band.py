"""The sweep's band beyond one camera's Nyquist limit: interleaved per-bin fits and the band by method.

The sync methods (``SYNC_METHODS``) give 3-D tracks at the reference camera's instants (fs): no tone above
fs/2 survives in them (the report's bins then fit the alias's samples with the reference phase, and the
track itself would show the alias). The **interleaved** analysis goes back to the 2-D observations of
every camera at its own row-corrected instant on the controller clock and fits, per frequency bin, the
sweep's exact phase law along the marker's line of motion (:func:`rig.stereo.band.fit_bin`): the pair's
interleaved instants carry it up to their combined Nyquist limit fs, unless the cameras' offset makes
the interleaving degenerate (α near 0 or a whole frame: the bins above fs/2 are refused with the reason),
and each bin's frequency is tested against its aliases (Δχ² > 25, refused otherwise).

Each oscillating 3-D track of the sweep (:func:`reports.frequency.sweep_samples`) takes the observations
of every camera nearest to its projected mean position (within its image amplitude + ``GATE_PX``); its line
of motion is measured from the same observations: the principal axis of its free 3-D interleaved fits over
the bins at least 2 Hz from every k·fs/2.

:func:`band_summary` states the band: one camera's Nyquist, the pair's combined rate at the measured offset,
the usable band of each sync method and of the interleaved fit (the highest frequency up to which every
bin holds |e| within the tolerance, guarded by 2u under the guarded rule, and is not refused), and the
certified upper edge with why it ends there.

Units: s (controller clock), Hz, mm, px, %.
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from reports import frequency
from reports.load import RunData
from reports.select import event_window
from rig.analysis.fiducial import CameraDating, own_camera_dating
from rig.config.analysis import SYNC_METHODS
from rig.stereo.band import BinFit, PairBand, fit_bin, instants_alpha, pair_band
from rig.stereo.dlt import DLTCamera
from rig.stereo.errors import StereoError

INTERLEAVED = "interleaved"
GATE_PX = 10.0
CONDITIONING_HZ = 2.0
LINE_BINS = 8  # free fits (spread over the sweep) that give a marker's line of motion
MIN_PER_CAMERA = 6
BAND_COLUMNS = [
    "track", "bin", "frequency_lo_hz", "frequency_hi_hz", "frequency_hz", "n_observations", "alpha_frames",
    "amplitude_ref_mm", "amplitude_meas_mm", "u_amplitude_mm", "amplitude_error_pct", "u_amplitude_error_pct",
    "alias_dchi2", "refused", "phase_deg", "u_phase_deg",
]
#: Why a method's tracks end where they do (the ceiling above any measured limit).
CEILINGS = {
    "trajectory": "tracks at the reference camera's instants (B-spline through both cameras): a tone above "
                  "one camera's Nyquist limit shows as its alias",
    "bandlimited": "the other camera resampled to the reference camera's instants: nothing above one "
                   "camera's Nyquist limit survives",
    "cubic": "the other camera resampled to the reference camera's instants: nothing above one camera's "
             "Nyquist limit survives",
    "linear": "the other camera interpolated to the reference camera's instants (the paper's): nothing "
              "above one camera's Nyquist limit survives",
}


@dataclass(frozen=True)
class _Marker:
    """One oscillating track: its name and mean position (mm)."""

    name: str
    mean_mm: np.ndarray


def _cameras(run: RunData) -> dict[str, DLTCamera]:
    cal = run.calibration
    entries = cal.to_dict().get("cameras", {}) if cal is not None else {}
    return {str(k): DLTCamera.from_dict(v) for k, v in entries.items()}


def _markers(samples: pd.DataFrame, tracks: pd.DataFrame, sweep: dict[str, Any]) -> list[_Marker]:
    """The oscillating tracks with their mean position (their line of motion comes later: _line_of)."""
    window = event_window(tracks, sweep)
    out = []
    for name in sorted(samples["track"].unique()):
        xyz = window[window["track"] == name][["x_mm", "y_mm", "z_mm"]].to_numpy(float)
        out.append(_Marker(str(name), xyz.mean(0)))
    return out


def _line_of(fits: list[tuple[float, BinFit]]) -> np.ndarray | None:
    """The marker's line of motion from its free interleaved fits (bins at least ``CONDITIONING_HZ`` from
    every k·fs/2, where each camera sees both quadratures): the principal axis of Σ a·aᵀ + b·bᵀ."""
    M = np.zeros((3, 3))
    for _, fit in fits:
        M += np.outer(fit.a, fit.a) + np.outer(fit.b, fit.b)
    if not np.trace(M) > 0:
        return None
    _, v = np.linalg.eigh(M)
    return np.asarray(v[:, -1])


def _segment_observations(run: RunData, cameras: dict[str, DLTCamera], segment: str,
                          clock: pd.DataFrame) -> dict[str, pd.DataFrame]:
    """Per camera: the segment's observations with ``t_s`` on the controller clock and undistorted ``uv``."""
    timing = run.timing
    out: dict[str, pd.DataFrame] = {}
    rows = clock[clock["segment"].astype(str) == segment]
    for cam, model in cameras.items():
        obs = run.folder.run.observations.get(cam)
        if obs is None or obs.empty or timing is None or cam not in timing.offset_s:
            continue
        parts = []
        for r in rows.itertuples():
            sel = obs[(obs["segment"].astype(str) == segment)
                      & (obs.get("session", pd.Series(0, index=obs.index)) == int(r.session))]
            sel = sel[np.isfinite(sel[["timestamp_s", "u_px", "v_px"]].to_numpy(float)).all(axis=1)]
            if sel.empty:
                continue
            # as the analysis dates the segment (rig.analysis.analyse.SegmentClock): the line time the
            # timing fiducial measured, then offset and rate — the other cameras by their own fiducial fit
            # when the segment has one (else the timing model's drift, extrapolated from the sync step)
            ts, rows_px = sel["timestamp_s"].to_numpy(float), sel["v_px"].to_numpy(float)
            own = _own_dating(run, cam, segment, r, float(np.median(rows_px))) \
                if cam != timing.reference_camera else None
            if own is not None:
                t_ctrl = own.controller_times_s(timing, ts, rows_px)
            else:
                line_error = float(getattr(r, "line_time_error_s", 0.0) or 0.0)
                rate, t_ref = float(getattr(r, "rate", 0.0) or 0.0), float(getattr(r, "t_ref_s", 0.0) or 0.0)
                dated = timing if not line_error else dataclasses.replace(
                    timing, line_time_s={c: v + line_error for c, v in timing.line_time_s.items()})
                t = dated.times(cam, ts, rows_px)
                t_ctrl = t + float(r.offset_s) + rate * (t - t_ref)
            uv = model.undistort_px(sel[["u_px", "v_px"]].to_numpy(float), strict=False)
            parts.append(pd.DataFrame({"t_s": t_ctrl, "u": uv[:, 0], "v": uv[:, 1]}))
        if parts:
            out[cam] = pd.concat(parts, ignore_index=True)
    return out


def _own_dating(run: RunData, camera: str, segment: str, row: Any, row_px: float) -> CameraDating | None:
    """``camera``'s own timing fiducial fit over the segment (:func:`own_camera_dating`, the reference
    camera's fiducial offset as the prior); None when the segment was not dated by a fiducial or this
    camera's fit is not usable."""
    timing = run.timing
    if timing is None or not str(getattr(row, "source", "")).startswith("timing fiducial"):
        return None
    exposure = ((run.rig.get("cameras") or {}).get(camera) or {}).get("exposure_s")
    exposure_s = float(exposure) if isinstance(exposure, int | float) and 0 <= exposure < 1 else 0.0
    own, _ = own_camera_dating(run.folder.run_dir, run.folder.run.events.get("fiducial"), segment,
                               int(row.session), camera, timing=timing, exposure_s=exposure_s,
                               prior_offset_s=float(row.offset_s), row_px=row_px)
    return own


def _assign(obs: pd.DataFrame, model: DLTCamera, markers: list[_Marker], reach_mm: np.ndarray,
            ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each marker's observations in one camera: nearest projected mean, within the image of ``reach_mm``
    (the sweep's amplitude along its axis) + ``GATE_PX``; one per instant; (t_s increasing, uv (N, 2))."""
    uv = obs[["u", "v"]].to_numpy(float)
    ok = np.isfinite(uv).all(axis=1)
    centres = model.project(np.array([m.mean_mm for m in markers]))
    reach = [float(np.linalg.norm(model.project((m.mean_mm + reach_mm)[None])[0] - c))
             for m, c in zip(markers, centres, strict=True)]
    d = np.linalg.norm(uv[:, None, :] - centres[None, :, :], axis=2)
    d[~ok] = np.inf
    nearest = np.argmin(d, axis=1)
    out = {}
    for k, m in enumerate(markers):
        sel = (nearest == k) & (d[:, k] <= reach[k] + GATE_PX)
        t, pts = obs["t_s"].to_numpy(float)[sel], uv[sel]
        order = np.argsort(t, kind="stable")
        t, pts = t[order], pts[order]
        keep = np.r_[True, np.diff(t) > 1e-9] if t.size else np.zeros(0, bool)
        out[m.name] = (t[keep], pts[keep])
    return out


def interleaved_bins(run: RunData, tracks: pd.DataFrame, clock: pd.DataFrame | None, sweep: dict[str, Any],
                     *, fs_hz: float, bin_hz: float) -> tuple[pd.DataFrame, list[str]]:
    """Per (oscillating track, frequency bin): the interleaved fit (``BAND_COLUMNS``), and notes.

    ``sweep``: the reference sweep (:func:`reports.frequency.reference_sweep`); ``tracks``/``clock``: the
    primary analysis' tracks and controller-clock offsets. Bins where a camera has fewer than 6
    observations or fewer than 3 cycles are left out; a bin whose fit fails is noted."""
    empty = pd.DataFrame(columns=BAND_COLUMNS)
    segment = sweep.get("segment")
    cameras = _cameras(run)
    if clock is None or clock.empty or not isinstance(segment, str) or len(cameras) < 2 or run.timing is None:
        return empty, ["interleaved analysis: needs the sweep's segment, calibration, timing and the "
                       "controller clock; not done"]
    samples = frequency.sweep_samples(tracks, sweep)
    if samples.empty:
        return empty, []
    markers = _markers(samples, tracks, sweep)
    per_cam = _segment_observations(run, cameras, segment, clock)
    ref = run.timing.reference_camera
    names = [ref, *sorted(c for c in per_cam if c != ref)] if ref in per_cam else []
    if len(names) < 2:
        return empty, ["interleaved analysis: the sweep has observations of fewer than two cameras"]
    amp_ref = float(sweep["amplitude_mm"])
    t0, t1 = float(sweep["t_start_s"]), float(sweep["t_stop_s"])
    inside = {c: o[(o["t_s"] >= t0) & (o["t_s"] <= t1)] for c, o in per_cam.items()}  # as the bins' tracks
    axis = np.asarray(sweep["axis"], float)
    reach_mm = amp_ref * axis / np.linalg.norm(axis)
    assigned = {c: _assign(inside[c], cameras[c], markers, reach_mm) for c in names}
    rows: list[dict[str, Any]] = []
    notes: list[str] = []
    for m in markers:
        data = [assigned[c][m.name] for c in names]
        rows += _marker_bins(m, data, [cameras[c].P for c in names], sweep, fs_hz=fs_hz, bin_hz=bin_hz,
                             notes=notes)
    return pd.DataFrame(rows, columns=BAND_COLUMNS), notes


def _windows(data: list[tuple[np.ndarray, np.ndarray]], sweep: dict[str, Any], bin_hz: float,
             ) -> list[tuple[int, float, float, float, list[np.ndarray], list[np.ndarray], list[np.ndarray]]]:
    """The frequency bins of one marker's observations: (bin = lo/bin_hz, lo, hi, mean f, per-camera
    instants, pixels, phases), bins with ≥ 6 observations of every camera and ≥ 3 cycles."""
    f_of = [frequency.profile_frequency_hz(sweep, t) for t, _ in data]
    phase_of = [frequency.sweep_phase_rad(sweep, t) for t, _ in data]
    f_all = np.concatenate(f_of)
    if not f_all.size:
        return []
    edges = np.arange(np.floor(f_all.min() / bin_hz) * bin_hz, f_all.max() + bin_hz, bin_hz)
    out = []
    for lo, hi in itertools.pairwise(edges):
        b = round(float(lo) / bin_hz)  # numbered from 0 Hz: the same bin for every marker
        masks = [(f >= lo) & (f < hi) for f in f_of]
        if min(int(k.sum()) for k in masks) < MIN_PER_CAMERA:
            continue
        ph = [p[k] for p, k in zip(phase_of, masks, strict=True)]
        if (max(float(p.max()) for p in ph) - min(float(p.min()) for p in ph)) / (2 * np.pi) < 3:
            continue
        ts = [t[k] for (t, _), k in zip(data, masks, strict=True)]
        uvs = [uv[k] for (_, uv), k in zip(data, masks, strict=True)]
        f_mid = float(np.mean(np.concatenate([f[k] for f, k in zip(f_of, masks, strict=True)])))
        out.append((b, float(lo), float(hi), f_mid, ts, uvs, ph))
    return out


def _marker_bins(m: _Marker, data: list[tuple[np.ndarray, np.ndarray]], Ps: list[np.ndarray],
                 sweep: dict[str, Any], *, fs_hz: float, bin_hz: float,
                 notes: list[str]) -> list[dict[str, Any]]:
    """The bins of one marker (see :func:`interleaved_bins`): free fits give the line of motion, then each
    bin is fitted along it with the alias test."""
    amp_ref = float(sweep["amplitude_mm"])
    axis = np.asarray(sweep["axis"], float)
    windows = _windows(data, sweep, bin_hz)
    free = []
    conditioned = [w for w in windows if abs(w[3] - fs_hz / 2 * round(2 * w[3] / fs_hz)) >= CONDITIONING_HZ]
    for _, _, _, f_mid, ts, uvs, ph in conditioned[::max(1, len(conditioned) // LINE_BINS)]:
        try:
            free.append((f_mid, fit_bin(Ps, ts, uvs, ph, axis, f_ref_hz=f_mid)))
        except StereoError:
            continue
    line = _line_of(free)
    if line is None:
        notes.append(f"interleaved fit of {m.name}: no bin away from k·fs/2 gives its line of motion")
        return []
    rows = []
    for b, lo, hi, f_mid, ts, uvs, ph in windows:
        alpha = instants_alpha(ts[0], ts[1], fs_hz)
        try:
            fit = fit_bin(Ps, ts, uvs, ph, axis, f_ref_hz=f_mid, direction=line,
                          identify=pair_band(fs_hz, alpha / fs_hz))
        except StereoError as exc:
            notes.append(f"interleaved fit of {m.name} in {lo:g}–{hi:g} Hz failed: {exc}")
            continue
        u_amp = max(fit.u_amplitude, 1e-9 * amp_ref)
        rows.append({
            "track": m.name, "bin": b, "frequency_lo_hz": lo, "frequency_hi_hz": hi,
            "frequency_hz": f_mid, "n_observations": fit.n_observations, "alpha_frames": alpha,
            "amplitude_ref_mm": amp_ref, "amplitude_meas_mm": fit.amplitude, "u_amplitude_mm": u_amp,
            "amplitude_error_pct": 100 * (fit.amplitude - amp_ref) / amp_ref,
            "u_amplitude_error_pct": 100 * u_amp / amp_ref, "alias_dchi2": fit.alias_dchi2,
            "refused": fit.refused,
            # x = A·sin(φ + phase) along the sweep's axis against the reference's φ (wrapped to ±180°)
            "phase_deg": float(np.rad2deg(np.angle(np.exp(1j * fit.phase_rad)))),
            "u_phase_deg": float(np.rad2deg(u_amp / max(fit.amplitude, 1e-12))),
        })
    return rows


def usable_edge(bins: pd.DataFrame, tolerance_pct: float, guard_k: float) -> tuple[float, float, str]:
    """(lowest bin's lower edge, upper edge of the last bin of the unbroken passing run from the lowest, why
    it ends there) of per-bin means over tracks; a bin passes when not refused by any track and
    |e| + guard_k·u ≤ tolerance. NaN edges when no bin passes."""
    if bins.empty:
        return float("nan"), float("nan"), "no interleaved bin"
    g = bins.groupby("bin", sort=True)
    per = g[["frequency_lo_hz", "frequency_hi_hz", "frequency_hz", "amplitude_error_pct",
             "u_amplitude_error_pct"]].mean()
    refused = g["refused"].agg(lambda s: next((r for r in s if r), ""))
    lo_edge, edge = float(per["frequency_lo_hz"].iloc[0]), float("nan")
    for b, r in per.iterrows():
        if refused[b]:
            return lo_edge, edge, f"the bin at {r['frequency_hz']:.1f} Hz is refused: {refused[b]}"
        worst = abs(r["amplitude_error_pct"]) + guard_k * r["u_amplitude_error_pct"]
        if worst > tolerance_pct:
            return lo_edge, edge, (
                f"at {r['frequency_hz']:.1f} Hz |e| = {abs(r['amplitude_error_pct']):.2f} % "
                f"(+{guard_k:g}u = {worst:.2f} %) exceeds the {tolerance_pct:g} % tolerance")
        edge = float(r["frequency_hi_hz"])
    return lo_edge, edge, "the highest frequency swept (a lower bound: the sweep ends there)"


def band_summary(bins: pd.DataFrame, limits: dict[str, Any], *, fs_hz: float, offset_s: float | None,
                 measured_alpha: float | None, tolerance_pct: float, guard_k: float) -> dict[str, Any]:
    """The band as the certificate states it (plain JSON types); ``limits``: the analysed sync methods'
    :class:`reports.quadfit.UsableLimit` (``limit_hz``, ``reached``)."""
    alpha = measured_alpha if measured_alpha is not None else (
        float(np.mod(offset_s * fs_hz, 1.0)) if offset_s is not None else None)
    pair: PairBand | None = pair_band(fs_hz, alpha / fs_hz) if alpha is not None else None
    methods: dict[str, Any] = {}
    for m in SYNC_METHODS:
        lim = limits.get(m)
        measured = float(min(lim.limit_hz, fs_hz / 2)) if lim is not None else None
        methods[m] = {"ceiling_hz": fs_hz / 2, "why_ceiling": CEILINGS[m], "analysed": lim is not None,
                      "usable_to_hz": measured,
                      "note": ("" if lim is None else "measured: the usable frequency limit of its quadratic "
                               "fit and bins, at most its ceiling")}
    lo, edge, why = usable_edge(bins, tolerance_pct, guard_k)
    ceiling = pair.combined_nyquist_hz if pair is not None else fs_hz / 2
    methods[INTERLEAVED] = {"ceiling_hz": ceiling, "analysed": not bins.empty,
                            "why_ceiling": (pair.degenerate_reason() if pair is not None and pair.degenerate
                                            else "the pair's combined Nyquist limit fs (a tone at k·fs is "
                                                 "constant in every camera)"),
                            "usable_from_hz": lo if np.isfinite(lo) else None,
                            "usable_to_hz": edge if np.isfinite(edge) else None, "why_it_ends": why}
    best = max(((k, v["usable_to_hz"]) for k, v in methods.items() if v["usable_to_hz"] is not None),
               key=lambda kv: kv[1], default=(None, None))
    return {
        "single_camera_nyquist_hz": fs_hz / 2,
        "fs_hz": fs_hz,
        "offset_frames": alpha,
        "alias_separation": pair.alias_separation if pair is not None else None,
        "combined_rate_hz": pair.combined_rate_hz if pair is not None else None,
        "combined_nyquist_hz": pair.combined_nyquist_hz if pair is not None else None,
        "degenerate": pair.degenerate if pair is not None else None,
        "tolerance_pct": tolerance_pct,
        "methods": methods,
        "certified_to_hz": best[1],
        "certified_by": best[0],
        "why_it_ends": (methods[best[0]].get("why_it_ends") or methods[best[0]]["note"] + "; "
                        + methods[best[0]]["why_ceiling"]) if best[0] else "no method has a usable band",
    }


__all__ = ["BAND_COLUMNS", "INTERLEAVED", "band_summary", "interleaved_bins", "usable_edge"]
