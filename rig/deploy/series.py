"""3-D tracks → displacement relative to reference markers → spectra, dominant frequency, amplitude.

Pure functions on DataFrames (``rig measure`` step 4–5; mm, s, Hz):

- :func:`reference_tracks` — which tracks are reference markers: ``"auto"`` (tracks whose RMS motion about
  their median stays below ``static_mm``; at least 3 needed), ``"none"``, or positions (mm, the nearest
  track median within ``gate_mm``);
- :func:`stabilised_displacement` — per target track, the reference markers interpolated (linearly: they
  hardly move) to the target's own instants, the rigid transform mapping them home applied
  (:func:`rig.stereo.stabilize`), displacement = stabilised position − its median;
- :func:`summarise` — per track: principal direction of motion (first singular vector), the record along
  it on a uniform grid of one median sample period (gaps from dropped frames filled linearly, counted);
  for targets the dominant frequency (interpolated peak of the whole record's spectrum) and a single-tone
  four-parameter sine fit at it (amplitude, frequency and their standard uncertainties; a fit that fails
  leaves the spectrum and the peaks), and — for several modes, successive tones or a sweep — the Welch
  spectrum, every significant tone with its fitted amplitude and active interval, and the STFT table
  (:mod:`rig.deploy.spectra`); half the peak-to-peak and the RMS (model-free) for every track.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from rig.deploy.spectra import false_alarm_text, time_frequency, tone_peaks
from rig.stereo import fit_sine, spectrum, stabilize
from rig.stereo.errors import StereoError

__all__ = ["SeriesError", "SeriesTables", "reference_tracks", "stabilised_displacement", "summarise"]

XYZ = ["x_mm", "y_mm", "z_mm"]
MIN_SAMPLES = 16


class SeriesError(ValueError):
    """A reference-marker request or a series cannot be used (the message says why)."""


def _medians(tracks: pd.DataFrame) -> pd.DataFrame:
    g = tracks.groupby("track_id")
    med = g[XYZ].median()
    dev = tracks[XYZ].to_numpy(float) - med.loc[tracks["track_id"]].to_numpy(float)
    rms = pd.Series(np.sqrt(np.nansum(dev**2, axis=1)), index=tracks.index).groupby(tracks["track_id"])
    med["motion_rms_mm"] = np.sqrt(rms.apply(lambda s: float(np.mean(s.to_numpy() ** 2))))
    med["n"] = g.size()
    return med


def reference_tracks(tracks: pd.DataFrame, spec: Any, *, static_mm: float = 0.1,
                     gate_mm: float = 20.0) -> tuple[list[int], str]:
    """(track ids of the reference markers, a note saying how they were chosen)."""
    med = _medians(tracks)
    if isinstance(spec, str):
        if spec == "none":
            return [], "reference markers: none requested; displacements are relative to the cameras"
        if spec != "auto":
            raise SeriesError(f"reference_markers={spec!r}; allowed: 'auto', 'none' or positions X,Y,Z (mm)")
        static = med[(med["motion_rms_mm"] < static_mm) & (med["n"] >= MIN_SAMPLES)]
        if len(static) < 3:
            return [], (f"reference markers: only {len(static)} track(s) moved less than {static_mm} mm RMS "
                        "(3 needed); displacements are relative to the cameras, not stabilised")
        ids = [int(i) for i in static.index]
        return ids, (f"reference markers (auto, RMS motion < {static_mm} mm): tracks {ids} at "
                     + "; ".join(f"({r.x_mm:.1f}, {r.y_mm:.1f}, {r.z_mm:.1f}) mm"
                                 for r in static.itertuples()))
    pts = np.asarray(spec, dtype=float).reshape(-1, 3)
    if len(pts) < 3:
        raise SeriesError(f"{len(pts)} reference marker position(s) given; a rigid transform needs ≥ 3")
    centres = med[XYZ].to_numpy(float)
    ids = []
    for p in pts:
        d = np.linalg.norm(centres - p, axis=1)
        k = int(np.argmin(d))
        if d[k] > gate_mm:
            raise SeriesError(f"reference marker at ({p[0]:g}, {p[1]:g}, {p[2]:g}) mm: the nearest track is "
                              f"{d[k]:.1f} mm away (allowed {gate_mm:g} mm); check the position or the "
                              "calibration's coordinate frame")
        ids.append(int(med.index[k]))
    if len(set(ids)) != len(ids):
        raise SeriesError(f"reference marker positions {pts.tolist()} map to repeated tracks {ids}")
    return ids, f"reference markers (given positions): tracks {ids}"


def _by_track(tracks: pd.DataFrame) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Track id → (time_s increasing, xyz (N, 3) mm); a repeated instant keeps its first row."""
    ids = tracks["track_id"].to_numpy(np.int64)
    t_all = tracks["time_s"].to_numpy(float)
    order = np.lexsort((t_all, ids))
    ids, t_all, xyz_all = ids[order], t_all[order], tracks[XYZ].to_numpy(float)[order]
    keep = np.r_[True, (np.diff(ids) != 0) | (np.diff(t_all) != 0)]
    ids, t_all, xyz_all = ids[keep], t_all[keep], xyz_all[keep]
    cuts = np.flatnonzero(np.diff(ids)) + 1
    return {int(ids[lo]): (t_all[lo:hi], xyz_all[lo:hi])
            for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, len(ids)], strict=True) if hi > lo}


def _stabilised_targets(series: dict[int, tuple[np.ndarray, np.ndarray]], refs: list[int],
                        targets: list[int]) -> dict[int, np.ndarray]:
    """Each target's xyz (mm) mapped by the rigid transform that brings the reference markers (interpolated
    linearly to its instants) back to their medians; NaN where no transform. One transform per instant
    of any target (targets share the reference camera's instants)."""
    home = np.array([np.median(series[r][1], axis=0) for r in refs])
    instants = np.unique(np.concatenate([series[tid][0] for tid in targets]))
    ref_at = np.stack([np.column_stack([np.interp(instants, tr, rx[:, k], left=np.nan, right=np.nan)
                                        for k in range(3)]) for tr, rx in (series[r] for r in refs)], axis=1)
    at = {tid: np.searchsorted(instants, series[tid][0]) for tid in targets}
    tgt = np.full((len(instants), len(targets), 3), np.nan)
    for m, tid in enumerate(targets):
        tgt[at[tid], m] = series[tid][1]
    st = stabilize(ref_at, home, tgt)
    return {tid: np.where(st.valid[at[tid], None], st.targets_mm[at[tid], m], np.nan)
            for m, tid in enumerate(targets)}


def stabilised_displacement(tracks: pd.DataFrame, refs: list[int]) -> pd.DataFrame:
    """One row per track sample: time_s, track_id, role, x/y/z_mm (stabilised for targets), dx/dy/dz_mm."""
    series = _by_track(tracks)
    targets = [tid for tid in sorted(series) if tid not in refs]
    moved = _stabilised_targets(series, refs, targets) if refs and targets else {}
    ts, ids, roles, xyzs, ds = [], [], [], [], []
    for tid in sorted(series):
        t, xyz = series[tid]
        xyz = moved.get(tid, xyz)
        ts.append(t)
        ids.append(np.full(len(t), tid, dtype=np.int64))
        roles += ["reference" if tid in refs else "target"] * len(t)
        xyzs.append(xyz)
        ds.append(xyz - np.nanmedian(xyz, axis=0))
    xyz_all, d_all = np.concatenate(xyzs), np.concatenate(ds)
    return pd.DataFrame({"time_s": np.concatenate(ts), "track_id": np.concatenate(ids), "role": roles,
                         "x_mm": xyz_all[:, 0], "y_mm": xyz_all[:, 1], "z_mm": xyz_all[:, 2],
                         "dx_mm": d_all[:, 0], "dy_mm": d_all[:, 1], "dz_mm": d_all[:, 2]})


def _uniform(t: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    period = float(np.median(np.diff(t)))
    grid = t[0] + period * np.arange(int(np.floor((t[-1] - t[0]) / period + 1e-6)) + 1)
    filled = int(len(grid) - len(t))
    return grid, np.interp(grid, t, d), max(filled, 0)


@dataclass
class SeriesTables:
    """What :func:`summarise` produces (long-form DataFrames, mm, Hz, s).

    ``summary``: one row per track; ``spectra``: the Welch amplitude spectrum per target track (track_id,
    frequency_hz, amplitude_mm, noise_floor_mm, threshold_mm); ``peaks``: every significant tone per target
    track (:class:`rig.deploy.spectra.Peak` fields with units); ``time_frequency``: the STFT amplitude per
    target track (track_id, time_s = window centre, frequency_hz, amplitude_mm)."""

    summary: pd.DataFrame
    spectra: pd.DataFrame
    peaks: pd.DataFrame
    time_frequency: pd.DataFrame


SPECTRA_COLUMNS = ["track_id", "frequency_hz", "amplitude_mm", "noise_floor_mm", "threshold_mm"]
PEAK_COLUMNS = ["track_id", "rank", "frequency_hz", "frequency_std_hz", "amplitude_mm", "amplitude_std_mm",
                "t_start_s", "t_stop_s", "welch_amplitude_mm", "noise_floor_mm", "false_alarm_probability",
                "method"]
TF_COLUMNS = ["track_id", "time_s", "frequency_hz", "amplitude_mm"]


@dataclass(frozen=True)
class _Record:
    """One target track along its principal direction: measured (t_s, d_mm) and on a uniform grid."""

    track_id: int
    t_s: np.ndarray
    d_mm: np.ndarray
    grid_s: np.ndarray
    grid_mm: np.ndarray


def _dominant(rec: _Record, notes: list[str]) -> dict[str, Any]:
    """The whole record's interpolated spectral peak, and a single-tone sine fit at it (separately: a fit
    that fails keeps the spectrum)."""
    tid, grid, dg, t, d = rec.track_id, rec.grid_s, rec.grid_mm, rec.t_s, rec.d_mm
    try:
        sp = spectrum(grid, dg)
    except StereoError as exc:
        notes.append(f"track {tid}: no spectrum ({exc})")
        return {}
    out = {"dominant_frequency_hz": sp.peak_frequency_hz, "spectral_amplitude_mm": sp.peak_amplitude,
           "resolution_hz": sp.resolution_hz}
    try:
        fit = fit_sine(t, d, initial_frequency_hz=sp.peak_frequency_hz)
        if abs(fit.frequency_hz - sp.peak_frequency_hz) > sp.resolution_hz:
            notes.append(f"track {tid}: the sine fit left the spectral peak ({fit.frequency_hz:.3f} vs "
                         f"{sp.peak_frequency_hz:.3f} Hz); amplitude fitted at the peak frequency")
            fit = fit_sine(t, d, frequency_hz=sp.peak_frequency_hz)
    except StereoError as exc:
        notes.append(f"track {tid}: no single-tone sine fit at {sp.peak_frequency_hz:.3f} Hz ({exc}); the "
                     "spectrum and the peaks table stand")
        return out
    out.update({"frequency_hz": fit.frequency_hz, "frequency_std_hz": fit.frequency_std_hz,
                "amplitude_mm": abs(fit.amplitude), "amplitude_std_mm": fit.amplitude_std,
                "fit_residual_rms_mm": fit.residual_rms})
    return out


def _tones(rec: _Record, notes: list[str], false_alarm: float) -> tuple[list[pd.DataFrame], int]:
    """([spectra, peaks, time–frequency] frames of one target track, number of peaks)."""
    tid, grid, dg, t, d = rec.track_id, rec.grid_s, rec.grid_mm, rec.t_s, rec.d_mm
    try:
        sg = time_frequency(grid, dg)
        peaks, ws = tone_peaks(grid, dg, samples=(t, d), false_alarm=false_alarm, sg=sg)
    except StereoError as exc:
        notes.append(f"track {tid}: no Welch spectrum / peaks ({exc})")
        return [], 0
    spec = pd.DataFrame({"track_id": tid, "frequency_hz": ws.frequency_hz, "amplitude_mm": ws.amplitude,
                         "noise_floor_mm": ws.noise_floor, "threshold_mm": ws.threshold})
    pk = pd.DataFrame([(tid, i, p.frequency_hz, p.frequency_std_hz, p.amplitude, p.amplitude_std, p.t_start_s,
                        p.t_stop_s, p.welch_amplitude, p.noise_floor, p.false_alarm_probability, p.method)
                       for i, p in enumerate(peaks)], columns=PEAK_COLUMNS)
    tf = pd.DataFrame({"track_id": tid, "time_s": np.repeat(sg.time_s, len(sg.frequency_hz)),
                       "frequency_hz": np.tile(sg.frequency_hz, len(sg.time_s)),
                       "amplitude_mm": sg.amplitude.ravel()})
    return [spec, pk, tf], len(peaks)


def summarise(displacement: pd.DataFrame, refs: list[int], *, window_s: tuple[float, float] | None = None,
              notes: list[str] | None = None, false_alarm: float = 1e-3) -> SeriesTables:
    """Summary per track, and per target track its Welch spectrum, significant tones and STFT table (module
    doc; :mod:`rig.deploy.spectra`). ``false_alarm``: probability that a spectrum of noise alone shows a
    peak above the significance threshold."""
    notes = notes if notes is not None else []
    rows: list[dict[str, Any]] = []
    frames: list[list[pd.DataFrame]] = [[], [], []]
    for tid, group in displacement.groupby("track_id", sort=True):
        g = group.sort_values("time_s")
        if window_s is not None:
            g = g[(g["time_s"] >= window_s[0]) & (g["time_s"] <= window_s[1])]
        g = g[np.isfinite(g[["dx_mm", "dy_mm", "dz_mm"]].to_numpy(float)).all(axis=1)]
        row: dict[str, Any] = {"track_id": int(tid), "role": "reference" if tid in refs else "target",
                               "n_samples": len(g)}
        rows.append(row)
        if len(g):
            row.update({k: float(g[k].median()) for k in XYZ})
        if len(g) < MIN_SAMPLES:
            notes.append(f"track {tid}: {len(g)} samples in the window (< {MIN_SAMPLES}); not analysed")
            continue
        t, d3 = g["time_s"].to_numpy(float), g[["dx_mm", "dy_mm", "dz_mm"]].to_numpy(float)
        d3 = d3 - d3.mean(axis=0)
        axis = np.linalg.svd(d3, full_matrices=False)[2][0]
        axis = axis * np.sign(axis[np.argmax(np.abs(axis))])
        d = d3 @ axis
        grid, dg, filled = _uniform(t, d)
        row.update({"direction_x": axis[0], "direction_y": axis[1], "direction_z": axis[2],
                    "rms_mm": float(np.sqrt(np.mean(d**2))),
                    "half_peak_to_peak_mm": float(0.5 * (d.max() - d.min())), "filled_samples": filled})
        if tid in refs:  # a reference marker's motion is noise and shake: no tone to fit
            continue
        rec = _Record(int(tid), t, d, grid, dg)
        row.update(_dominant(rec, notes))
        parts, row["n_peaks"] = _tones(rec, notes, false_alarm)
        for acc, part in zip(frames, parts, strict=False):
            acc.append(part)
    if any(r.get("n_peaks") for r in rows):
        notes.append(false_alarm_text(false_alarm))
    columns = (SPECTRA_COLUMNS, PEAK_COLUMNS, TF_COLUMNS)
    spectra, peaks, tf = (pd.concat(f, ignore_index=True) if f else pd.DataFrame(columns=cols)
                          for f, cols in zip(frames, columns, strict=True))
    return SeriesTables(pd.DataFrame(rows), spectra, peaks, tf)
