"""Steady motions: the oscillating plate (paper Figs. 3–8) and the rotor (Figs. 9–15).

* :func:`plate_table` — per oscillating track: reference and measured amplitude and frequency.
* :func:`rotation_samples` / :func:`rotation_summary` — the rotor marker's radius about the commanded
  centre and axis (Fig. 14) and its rotation frequency.
* :func:`amplitude_spectrum` — one-sided amplitude spectrum in mm (flat-top window, normalised by its
  coherent gain so a sinusoid of amplitude A shows A wherever it falls between bins; Fig. 15).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

from reports.errors import ReportError
from reports.frequency import _peak_frequency_hz, sweep_samples
from reports.select import event_window
from rig.stereo.spectrum import window_weights

DEFAULT_ROTOR_GATE_MM = 50.0


def _window(tracks: pd.DataFrame, event: dict) -> pd.DataFrame:
    return event_window(tracks, event)


def sine_fit_known_f(t_s: np.ndarray, x: np.ndarray, f_hz: float) -> tuple[float, float]:
    """Amplitude and its standard uncertainty of x = a·cos 2πft + b·sin 2πft + c (frequency known)."""
    w = 2 * np.pi * f_hz * (t_s - t_s[0])
    X = np.column_stack([np.cos(w), np.sin(w), np.ones_like(w)])
    coef, *_ = np.linalg.lstsq(X, x, rcond=None)
    r = x - X @ coef
    cov = float(r @ r) / max(len(x) - 3, 1) * np.linalg.inv(X.T @ X)
    amp = float(np.hypot(coef[0], coef[1]))
    g = coef[:2] / amp if amp > 0 else np.array([np.sqrt(0.5), np.sqrt(0.5)])
    return amp, float(np.sqrt(max(g @ cov[:2, :2] @ g, 0.0)))


def fit_frequency(t_s: np.ndarray, x: np.ndarray, f0_hz: float) -> tuple[float, float]:
    """Frequency and its standard uncertainty (Hz) by the four-parameter sine fit (IEEE 1057).

    Starts from the Lomb–Scargle peak within ±50 % of ``f0_hz``; the uncertainty is from the Jacobian at
    the solution, scaled by the residual variance. (NaN, NaN) with fewer than 8 samples.
    """
    from scipy.optimize import least_squares

    t = np.asarray(t_s, float)
    x = np.asarray(x, float)
    if len(t) < 8 or not f0_hz > 0:
        return float("nan"), float("nan")
    tc = t - t.mean()
    f_start = _peak_frequency_hz(t, x, 0.5 * f0_hz, 1.5 * f0_hz)
    if not np.isfinite(f_start):
        f_start = f0_hz
    w = 2 * np.pi * f_start * tc
    X = np.column_stack([np.cos(w), np.sin(w), np.ones_like(w)])
    a, b, c = np.linalg.lstsq(X, x, rcond=None)[0]

    def resid(p: np.ndarray) -> np.ndarray:
        ph = 2 * np.pi * p[3] * tc
        return p[0] * np.cos(ph) + p[1] * np.sin(ph) + p[2] - x

    sol = least_squares(
        resid, np.array([a, b, c, f_start]), x_scale="jac", xtol=1e-14, ftol=1e-14, gtol=1e-14
    )
    J = sol.jac
    dof = max(len(x) - 4, 1)
    s2 = float(sol.fun @ sol.fun) / dof
    try:
        cov = s2 * np.linalg.inv(J.T @ J)
        u_f = float(np.sqrt(max(cov[3, 3], 0.0)))
    except np.linalg.LinAlgError:
        u_f = float("nan")
    return float(sol.x[3]), u_f


def plate_rest_positions_mm(geometry: dict) -> dict[str, np.ndarray]:
    """Rest position of every plate marker ``plate_r{r}c{c}`` from the rig's ``targets.plate`` table (mm).

    Column c lies (c + 1)·pitch from the clamp ``root_mm`` along ``length_direction``; rows are
    ``row_pitch_mm`` apart along ``width_direction``, centred on the root.
    """
    try:
        root = np.asarray(geometry["root_mm"], float)
        lv = np.asarray(geometry.get("length_direction", (0.0, 1.0, 0.0)), float)
        wv = np.asarray(geometry.get("width_direction", (0.0, 0.0, 1.0)), float)
        rows, cols = int(geometry["rows"]), int(geometry["cols"])
        pitch, row_pitch = float(geometry["pitch_mm"]), float(geometry["row_pitch_mm"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ReportError(f"targets.plate of the rig snapshot is incomplete or invalid ({exc!r})") from exc
    lv, wv = lv / np.linalg.norm(lv), wv / np.linalg.norm(wv)
    return {
        f"plate_r{r}c{c}": root + (c + 1) * pitch * lv + ((rows - 1) / 2 - r) * row_pitch * wv
        for r in range(rows)
        for c in range(cols)
    }


def _identify(
    means: dict[str, np.ndarray], expected: dict[str, np.ndarray], gate_mm: float
) -> dict[str, str]:
    """track → marker id by unique nearest assignment of mean positions, within ``gate_mm``."""
    if not means or not expected:
        return {}
    tracks, ids = list(means), list(expected)
    dist = np.linalg.norm(
        np.stack([means[k] for k in tracks])[:, None, :] - np.stack([expected[i] for i in ids])[None, :, :],
        axis=2,
    )
    r_idx, c_idx = linear_sum_assignment(dist)
    return {tracks[r]: ids[c] for r, c in zip(r_idx, c_idx, strict=True) if dist[r, c] <= gate_mm}


PLATE_COLUMNS = ["track", "marker_id", "n_samples", "frequency_ref_hz", "frequency_meas_hz", "u_frequency_hz",
                 "frequency_error_pct", "amplitude_ref_mm", "amplitude_meas_mm", "u_amplitude_mm",
                 "amplitude_error_pct"]


def plate_table(
    tracks: pd.DataFrame, plate: dict, geometry: dict | None = None, *, gate_mm: float = DEFAULT_ROTOR_GATE_MM
) -> pd.DataFrame:
    """Per oscillating track of a ``plate`` event: amplitude and frequency, reference vs measured.

    A clamped plate's markers move by different amplitudes (``marker_amplitudes_mm``): each track is then
    identified as a marker by its mean position against the rest positions of ``geometry`` (the rig's
    ``targets.plate``); a track that cannot be identified gets no reference amplitude (NaN). Without
    per-marker amplitudes every track's reference is ``amplitude_mm``.
    """
    for key in ("frequency_hz", "amplitude_mm"):
        if key not in plate:
            raise ReportError(f"plate event: missing field '{key}'")
    f_ref = float(plate["frequency_hz"])
    per_marker = {str(k): float(v) for k, v in (plate.get("marker_amplitudes_mm") or {}).items()}
    smallest = min(per_marker.values()) if per_marker else float(plate["amplitude_mm"])
    as_sweep = dict(
        plate, amplitude_mm=smallest, profile=[[plate["t_start_s"], f_ref], [plate["t_stop_s"], f_ref]]
    )
    samples = sweep_samples(tracks, as_sweep)
    window = event_window(tracks, plate)
    means = {
        k: g[["x_mm", "y_mm", "z_mm"]].to_numpy(float).mean(axis=0)
        for k, g in window[window["track"].isin(set(samples["track"]))].groupby("track", sort=True)
    }
    identity: dict[str, str] = {}
    if per_marker and geometry:
        expected = {k: v for k, v in plate_rest_positions_mm(geometry).items() if k in per_marker}
        identity = _identify(means, expected, gate_mm)
    rows = []
    for track, g in samples.groupby("track", sort=True):
        t = g["time_s"].to_numpy(float)
        x = g["displacement_mm"].to_numpy(float)
        amp, u_amp = sine_fit_known_f(t, x, f_ref)
        f_meas, u_f = fit_frequency(t, x, f_ref)
        marker = identity.get(track, "")
        a_ref = per_marker.get(marker, np.nan) if per_marker else float(plate["amplitude_mm"])
        rows.append(
            {
                "track": track,
                "marker_id": marker,
                "n_samples": len(t),
                "frequency_ref_hz": f_ref,
                "frequency_meas_hz": f_meas,
                "u_frequency_hz": u_f,
                "frequency_error_pct": 100 * (f_meas - f_ref) / f_ref,
                "amplitude_ref_mm": a_ref,
                "amplitude_meas_mm": amp,
                "u_amplitude_mm": u_amp,
                "amplitude_error_pct": 100 * (amp - a_ref) / a_ref,
            }
        )
    return pd.DataFrame(rows, columns=PLATE_COLUMNS)


def rotation_samples(
    tracks: pd.DataFrame, rotation: dict, *, gate_mm: float = DEFAULT_ROTOR_GATE_MM
) -> pd.DataFrame:
    """Samples of the rotor marker: ``time_s``, ``x_mm``, ``y_mm``, ``z_mm``, ``radius_mm``, ``axial_mm``,
    ``in_plane_mm`` (the radial vector on a fixed unit vector ⟂ axis: a sinusoid at the rotation frequency).

    The rotor track is the one whose mean radius about the commanded axis through ``centre_mm`` is
    closest to ``radius_mm`` among tracks whose centroid lies within ``gate_mm`` of the centre.
    """
    for key in ("centre_mm", "axis", "radius_mm"):
        if key not in rotation:
            raise ReportError(f"rotation event: missing field '{key}'")
    centre = np.asarray(rotation["centre_mm"], float)
    axis = np.asarray(rotation["axis"], float)
    if centre.shape != (3,) or axis.shape != (3,) or not np.linalg.norm(axis) > 0:
        raise ReportError("rotation.centre_mm and rotation.axis must be [x, y, z] (axis non-zero)")
    axis = axis / np.linalg.norm(axis)
    best, best_cost = None, np.inf
    win = _window(tracks, rotation)
    for track, g in win.groupby("track", sort=True):
        p = g[["x_mm", "y_mm", "z_mm"]].to_numpy(float) - centre
        if len(p) < 10 or np.linalg.norm(p.mean(axis=0)) > gate_mm:
            continue
        radial = p - np.outer(p @ axis, axis)
        cost = abs(np.linalg.norm(radial, axis=1).mean() - float(rotation["radius_mm"]))
        if cost < best_cost:
            best, best_cost = track, cost
    cols = ["track", "time_s", "x_mm", "y_mm", "z_mm", "radius_mm", "axial_mm", "in_plane_mm"]
    if best is None:
        return pd.DataFrame(columns=cols)
    g = win[win["track"] == best].sort_values("time_s")
    p = g[["x_mm", "y_mm", "z_mm"]].to_numpy(float) - centre
    axial = p @ axis
    radial = p - np.outer(axial, axis)
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return pd.DataFrame(
        {
            "track": best,
            "time_s": g["time_s"].to_numpy(float),
            "x_mm": g["x_mm"].to_numpy(float),
            "y_mm": g["y_mm"].to_numpy(float),
            "z_mm": g["z_mm"].to_numpy(float),
            "radius_mm": np.linalg.norm(radial, axis=1),
            "axial_mm": axial,
            "in_plane_mm": radial @ e1,
        },
        columns=cols,
    )


def rotation_summary(samples: pd.DataFrame, rotation: dict) -> dict[str, float]:
    """Radius mean/std/error (mm) and rotation frequency (four-parameter sine fit, in-plane coordinate)."""
    r_ref = float(rotation["radius_mm"])
    f_ref = float(rotation.get("frequency_hz", np.nan))
    if samples.empty:
        return {
            "radius_ref_mm": r_ref,
            "frequency_ref_hz": f_ref,
            "n_samples": 0,
            "radius_mean_mm": np.nan,
            "radius_std_mm": np.nan,
            "radius_error_mm": np.nan,
            "u_radius_mm": np.nan,
            "frequency_meas_hz": np.nan,
            "u_frequency_hz": np.nan,
            "frequency_error_pct": np.nan,
        }
    r = samples["radius_mm"].to_numpy(float)
    t = samples["time_s"].to_numpy(float)
    f_meas, u_f = fit_frequency(t, samples["in_plane_mm"].to_numpy(float), f_ref)
    return {
        "radius_ref_mm": r_ref,
        "frequency_ref_hz": f_ref,
        "n_samples": len(r),
        "radius_mean_mm": float(r.mean()),
        "radius_std_mm": float(r.std(ddof=1)) if len(r) > 1 else np.nan,
        "radius_error_mm": float(r.mean() - r_ref),
        "u_radius_mm": float(r.std(ddof=1) / np.sqrt(len(r))) if len(r) > 1 else np.nan,
        "frequency_meas_hz": f_meas,
        "u_frequency_hz": u_f,
        "frequency_error_pct": 100 * (f_meas - f_ref) / f_ref if f_ref > 0 else np.nan,
    }


def amplitude_spectrum(t_s: np.ndarray, x: np.ndarray) -> pd.DataFrame:
    """One-sided amplitude spectrum (``frequency_hz``, ``amplitude_mm``) of a nearly uniformly sampled signal.

    The samples are linearly interpolated onto a uniform grid at the median step, the mean is removed, a
    flat-top window applied and the result normalised by the window's coherent gain (Σw/N). A flat-top
    window reads a sinusoid's amplitude within 0.12 % wherever its frequency falls between two bins (a
    Hann window loses up to 15 % half-way between bins), at the cost of a peak ≈ 4 bins wide.
    """
    t = np.asarray(t_s, float)
    v = np.asarray(x, float)
    ok = np.isfinite(t) & np.isfinite(v)
    t, v = t[ok], v[ok]
    if len(t) < 8:
        raise ReportError(f"a spectrum needs ≥ 8 samples, got {len(t)}")
    order = np.argsort(t)
    t, v = t[order], v[order]
    dt = float(np.median(np.diff(t)))
    if not dt > 0:
        raise ReportError("a spectrum needs increasing sample times")
    grid = t[0] + dt * np.arange(int(np.floor((t[-1] - t[0]) / dt)) + 1)
    y = np.interp(grid, t, v)
    y = y - y.mean()
    w = window_weights("flattop", len(y))  # scipy.signal.windows.flattop(n, sym=False), bit for bit
    spec = np.fft.rfft(y * w)
    amp = 2 * np.abs(spec) / w.sum()
    return pd.DataFrame({"frequency_hz": np.fft.rfftfreq(len(y), dt), "amplitude_mm": amp})
