"""3-D tracks → displacement relative to reference markers → spectra, dominant frequency, amplitude.

Pure functions on DataFrames (``rig measure`` step 4–5; mm, s, Hz):

- :func:`reference_tracks` — which tracks are reference markers: ``"auto"`` (tracks whose RMS motion about
  their median stays below ``static_mm``; at least 3 needed), ``"none"``, or positions (mm, the nearest
  track median within ``gate_mm``);
- :func:`stabilised_displacement` — per target track, the reference markers interpolated (linearly: they
  hardly move) to the target's own instants, the rigid transform mapping them home applied
  (:func:`rig.stereo.stabilize`), displacement = stabilised position − its median;
- :func:`summarise` — per track: principal direction of motion (first singular vector), spectrum along it
  on a uniform grid of one median sample period (gaps from dropped frames filled linearly, counted), the
  dominant frequency (interpolated spectral peak) and a four-parameter sine fit (amplitude, frequency and
  their standard uncertainties) for targets; half the peak-to-peak and the RMS (model-free) for every track.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from rig.stereo import fit_sine, spectrum, stabilize
from rig.stereo.errors import StereoError

__all__ = ["SeriesError", "reference_tracks", "stabilised_displacement", "summarise"]

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


def _series(tracks: pd.DataFrame, tid: int) -> tuple[np.ndarray, np.ndarray]:
    tr = tracks[tracks["track_id"] == tid].sort_values("time_s").drop_duplicates("time_s")
    return tr["time_s"].to_numpy(float), tr[XYZ].to_numpy(float)


def stabilised_displacement(tracks: pd.DataFrame, refs: list[int]) -> pd.DataFrame:
    """One row per track sample: time_s, track_id, role, x/y/z_mm (stabilised for targets), dx/dy/dz_mm."""
    ref_series = [_series(tracks, r) for r in refs]
    home = np.array([np.median(xyz, axis=0) for _, xyz in ref_series]) if refs else np.zeros((0, 3))
    rows = []
    for tid in sorted(int(t) for t in tracks["track_id"].unique()):
        t, xyz = _series(tracks, tid)
        role = "reference" if tid in refs else "target"
        if refs and role == "target":
            ref_at = np.stack([np.column_stack([np.interp(t, tr, rx[:, k], left=np.nan, right=np.nan)
                                                for k in range(3)]) for tr, rx in ref_series], axis=1)
            st = stabilize(ref_at, home, xyz[:, None, :])
            xyz = np.where(st.valid[:, None], st.targets_mm[:, 0, :], np.nan)
        d = xyz - np.nanmedian(xyz, axis=0)
        rows.append(pd.DataFrame({"time_s": t, "track_id": tid, "role": role, "x_mm": xyz[:, 0],
                                  "y_mm": xyz[:, 1], "z_mm": xyz[:, 2], "dx_mm": d[:, 0], "dy_mm": d[:, 1],
                                  "dz_mm": d[:, 2]}))
    return pd.concat(rows, ignore_index=True)


def _uniform(t: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    period = float(np.median(np.diff(t)))
    grid = t[0] + period * np.arange(int(np.floor((t[-1] - t[0]) / period + 1e-6)) + 1)
    filled = int(len(grid) - len(t))
    return grid, np.interp(grid, t, d), max(filled, 0)


def summarise(displacement: pd.DataFrame, refs: list[int], *, window_s: tuple[float, float] | None = None,
              notes: list[str] | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(summary per track, spectra in long form: track_id, frequency_hz, amplitude_mm) — module doc."""
    notes = notes if notes is not None else []
    rows, spectra = [], []
    for tid, group in displacement.groupby("track_id", sort=True):
        g = group.sort_values("time_s")
        if window_s is not None:
            g = g[(g["time_s"] >= window_s[0]) & (g["time_s"] <= window_s[1])]
        g = g[np.isfinite(g[["dx_mm", "dy_mm", "dz_mm"]].to_numpy(float)).all(axis=1)]
        row: dict[str, Any] = {"track_id": int(tid), "role": "reference" if tid in refs else "target",
                               "n_samples": len(g)}
        if len(g):
            row.update({k: float(g[k].median()) for k in XYZ})
        if len(g) < MIN_SAMPLES:
            notes.append(f"track {tid}: {len(g)} samples in the window (< {MIN_SAMPLES}); not analysed")
            rows.append(row)
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
            rows.append(row)
            continue
        try:
            sp = spectrum(grid, dg)
            fit = fit_sine(t, d)
            if abs(fit.frequency_hz - sp.peak_frequency_hz) > sp.resolution_hz:
                notes.append(f"track {tid}: the sine fit left the spectral peak ({fit.frequency_hz:.3f} vs "
                             f"{sp.peak_frequency_hz:.3f} Hz); amplitude fitted at the peak frequency")
                fit = fit_sine(t, d, frequency_hz=sp.peak_frequency_hz)
        except StereoError as exc:
            notes.append(f"track {tid}: no spectrum/sine fit ({exc})")
            rows.append(row)
            continue
        row.update({"dominant_frequency_hz": sp.peak_frequency_hz, "spectral_amplitude_mm": sp.peak_amplitude,
                    "resolution_hz": sp.resolution_hz, "frequency_hz": fit.frequency_hz,
                    "frequency_std_hz": fit.frequency_std_hz, "amplitude_mm": abs(fit.amplitude),
                    "amplitude_std_mm": fit.amplitude_std, "fit_residual_rms_mm": fit.residual_rms})
        rows.append(row)
        spectra.append(pd.DataFrame({"track_id": int(tid), "frequency_hz": sp.frequency_hz,
                                     "amplitude_mm": sp.amplitude}))
    spec = (pd.concat(spectra, ignore_index=True) if spectra
            else pd.DataFrame(columns=["track_id", "frequency_hz", "amplitude_mm"]))
    return pd.DataFrame(rows), spec
