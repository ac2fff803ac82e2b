"""Error versus frequency along the sweep, per synchronization method.

The ``sweep`` truth event gives the reference: displacement along ``axis`` = ``amplitude_mm``·sin φ(t),
with f(t) piecewise linear through [[t_s, f_hz], …] and φ its exact integral. f(t) is the drive's
**actual** frequency polled during the sweep (the ``exciter`` events, :func:`reference_sweep`), not the
commanded ``profile``: the sweep driver sets each segment's ramp rate 2 % above the segment's slope
(drivers/exciter/sweep.py), so the crank reaches every segment end early and its phase runs ahead of the
commanded profile by an equivalent ≈ ½·update_interval·margin/(1+margin) (≈ 5 ms at 0.5 s, 2 %) — taken as
the reference it would show up as a spurious "track delay" that no camera clock causes. The sweep is cut
into frequency bins (``bin_hz`` wide); in each bin the measured displacement of every oscillating track
is fitted by linear least squares with the reference phase, x = a·cos φ + b·sin φ + c (IEEE 1057
three-parameter fit with the frequency known from the truth), so a slowly changing frequency costs
nothing. Amplitude √(a²+b²) and its standard uncertainty come from the fit covariance.

Relative amplitude error e = 100·(A_meas − A_ref)/A_ref in %, signed (linear interpolation loses
amplitude, so e < 0 and grows quadratically in magnitude, notes §5).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from typing import TypeGuard

import numpy as np
import pandas as pd

from reports.errors import ReportError
from reports.select import event_window

DEFAULT_BIN_HZ = 1.0
MIN_CYCLES_PER_BIN = 3.0
MIN_SAMPLES_PER_BIN = 12
# A track oscillates with the exciter when the std of its axial displacement exceeds this share of a
# sine's std (A/√2); static reference markers stay near zero and the sweep markers near one.
OSCILLATING_STD_SHARE = 0.3
BIN_COLUMNS = [
    "sync_method",
    "track",
    "bin",
    "frequency_lo_hz",
    "frequency_hi_hz",
    "frequency_hz",
    "t_mid_s",
    "n_samples",
    "amplitude_ref_mm",
    "amplitude_meas_mm",
    "u_amplitude_mm",
    "amplitude_error_pct",
    "u_amplitude_error_pct",
    "phase_deg",
    "measured_frequency_hz",
]


def _profile(sweep: dict) -> tuple[np.ndarray, np.ndarray]:
    prof = np.asarray(sweep.get("profile"), dtype=float)
    if prof.ndim != 2 or prof.shape[1] != 2 or len(prof) < 2:
        raise ReportError(f"sweep.profile must be [[t_s, f_hz], ...] with ≥ 2 rows, got shape {prof.shape}")
    if not np.all(np.isfinite(prof)):
        raise ReportError("sweep.profile holds a non-finite value (null/NaN)")
    if np.any(np.diff(prof[:, 0]) < 0):
        raise ReportError("sweep.profile times must not decrease (equal times = a step in frequency)")
    return prof[:, 0], prof[:, 1]


def profile_frequency_hz(sweep: dict, t_s: np.ndarray) -> np.ndarray:
    """The commanded frequency f(t) of the sweep (linear between profile points, held outside)."""
    tp, fp = _profile(sweep)
    return np.interp(np.asarray(t_s, float), tp, fp)


def sweep_phase_rad(sweep: dict, t_s: np.ndarray) -> np.ndarray:
    """Exact phase φ(t) = 2π∫f dt of the piecewise-linear profile, zero at the first profile time."""
    tp, fp = _profile(sweep)
    t = np.asarray(t_s, float)
    seg_cycles = 0.5 * (fp[1:] + fp[:-1]) * np.diff(tp)
    knot_cycles = np.concatenate([[0.0], np.cumsum(seg_cycles)])
    k = np.clip(np.searchsorted(tp, t, side="right") - 1, 0, len(tp) - 2)
    dt = t - tp[k]
    seg_dt = tp[k + 1] - tp[k]
    slope = np.divide(fp[k + 1] - fp[k], seg_dt, out=np.zeros_like(dt), where=seg_dt > 0)
    inside = (t >= tp[0]) & (t <= tp[-1])
    cycles = np.where(inside, knot_cycles[k] + fp[k] * dt + 0.5 * slope * dt**2, np.nan)
    before = t < tp[0]
    cycles = np.where(before, fp[0] * (t - tp[0]), cycles)
    after = t > tp[-1]
    cycles = np.where(after, knot_cycles[-1] + fp[-1] * (t - tp[-1]), cycles)
    return 2 * np.pi * cycles


ARRIVED_TOL_HZ = 0.006  # polled frequency within this of the setpoint = arrived (drives report 0.01 Hz)


def reference_sweep(sweep: dict, polled: list[dict]) -> tuple[dict, str]:
    """The sweep event with ``profile`` replaced by the polled actual frequency, and where f(t) came from.

    ``polled``: ``exciter`` event payloads (``t_s`` rig clock, ``frequency_hz`` actual, ``setpoint_hz``).
    The samples inside [t_start_s, t_stop_s] are used when they cover the window (no gap at either end
    longer than their own spacing) at least as densely as the commanded profile's points; the instant the
    drive reached each setpoint between two polls is put back (:func:`ramp_knots`). Otherwise the
    commanded profile is kept (it leads the motion by the drive's ramp margin, see the module docstring)
    and the returned source says so.
    """
    t0, t1 = float(sweep["t_start_s"]), float(sweep["t_stop_s"])
    rows = sorted(
        (float(p["t_s"]), float(p["frequency_hz"]), _setpoint(p))
        for p in polled
        if _is_number(p.get("t_s")) and _is_number(p.get("frequency_hz")) and t0 <= float(p["t_s"]) <= t1
    )
    prof_t = _profile(sweep)[0]
    if len(rows) >= 2:
        arr = np.array(rows, dtype=float)
        keep = np.r_[True, np.diff(arr[:, 0]) > 0]
        t, f, sp = arr[keep, 0], arr[keep, 1], arr[keep, 2]
        gap = float(np.median(np.diff(t))) if t.size > 1 else np.inf
        dense = 0 < gap <= float(np.median(np.diff(prof_t)))
        if dense and t[0] - t0 <= gap * 1.01 and t1 - t[-1] <= gap * 1.01:
            tk, fk = ramp_knots(t, f, sp)
            prof = np.column_stack([tk, fk]).tolist()
            return dict(sweep, profile=prof), (
                f"polled actual frequency ({t.size} samples every {gap:.3g} s, "
                f"{tk.size - t.size} setpoint arrivals between polls restored)")
    if sweep.get("body", "exciter") != "exciter":  # a generator's frequency law is exact, no drive ramp
        return dict(sweep), (
            f"commanded profile of the {sweep['body']} ({sweep.get('profile_source') or 'generator sweep'})"
        )
    return dict(sweep), (
        f"commanded profile ({len(rows)} polled samples in the sweep window do not cover it densely): the "
        "phase reference leads the crank by the drive's ramp margin"
    )


def ramp_knots(t_s: np.ndarray, f_hz: np.ndarray, setpoint_hz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Polled (t, f) of a ramping drive plus the instants it reached its setpoint between two polls.

    A drive ramps linearly toward each new setpoint and then holds it, so f(t) has a corner where it
    arrives. Joining the polls with straight lines cuts that corner and loses phase in every segment
    (≈ s·δt²/8 cycles, a systematic lag ∝ the frequency): the corner is placed where the line through the
    ramp's own polls (from the last poll of the previous setpoint) reaches the arrived value. NaN
    setpoints leave the polls as they are.
    """
    t, f, sp = (np.asarray(a, float) for a in (t_s, f_hz, setpoint_hz))
    knots_t, knots_f = [t], [f]
    if t.size < 3 or not np.isfinite(sp).all():
        return t, f
    change = np.flatnonzero(np.diff(sp) != 0) + 1  # first poll with a new setpoint
    rate: float | None = None
    for i0, i_end in zip(change, np.r_[change[1:], t.size], strict=True):
        target = sp[i0]
        arrived = np.flatnonzero(np.abs(f[i0:i_end] - target) <= ARRIVED_TOL_HZ)
        if not arrived.size:
            continue
        k1 = i0 + int(arrived[0])  # first poll at the setpoint; the ramp runs from poll i0 − 1 to k1 − 1
        ramp = slice(i0 - 1, k1)
        if k1 - (i0 - 1) >= 2:
            slope, icpt = np.polyfit(t[ramp], f[ramp], 1)
            rate = abs(float(slope))
        if not rate:
            continue
        t_prev = t[k1 - 1]
        t_hit = t_prev + abs(f[k1] - f[k1 - 1]) / rate if k1 - (i0 - 1) < 2 else (f[k1] - icpt) / slope
        if t_prev < t_hit < t[k1]:
            knots_t.append(np.array([t_hit]))
            knots_f.append(np.array([f[k1]]))
    tt, ff = np.concatenate(knots_t), np.concatenate(knots_f)
    order = np.argsort(tt, kind="stable")
    return tt[order], ff[order]


def _setpoint(p: dict) -> float:
    v = p.get("setpoint_hz")
    return float(v) if _is_number(v) else float("nan")


def _is_number(v: object) -> TypeGuard[int | float]:
    """A finite int or float (not a bool)."""
    return isinstance(v, int | float) and not isinstance(v, bool) and bool(np.isfinite(v))


def sweep_samples(tracks: pd.DataFrame, sweep: dict) -> pd.DataFrame:
    """Axial displacement of the oscillating tracks during the sweep.

    Returns rows ``track`` (``"<segment>#<track_id>"``), ``time_s``, ``displacement_mm`` (projection on the
    sweep axis minus the track's mean), for tracks whose displacement std exceeds
    ``OSCILLATING_STD_SHARE``·A/√2 (static reference markers are left out).
    """
    for key in ("t_start_s", "t_stop_s", "amplitude_mm", "axis"):
        if key not in sweep:
            raise ReportError(f"sweep event: missing field '{key}'")
    axis = np.asarray(sweep["axis"], float)
    if axis.shape != (3,) or not np.linalg.norm(axis) > 0:
        raise ReportError(f"sweep.axis must be a non-zero [x, y, z] vector, got {sweep['axis']!r}")
    axis = axis / np.linalg.norm(axis)
    amp = float(sweep["amplitude_mm"])
    sel = event_window(tracks, sweep)
    parts = []
    for name, g in sel.groupby("track", sort=True):
        s = g[["x_mm", "y_mm", "z_mm"]].to_numpy(float) @ axis
        s = s - s.mean()
        if len(s) >= MIN_SAMPLES_PER_BIN and s.std() >= OSCILLATING_STD_SHARE * amp / np.sqrt(2):
            parts.append(
                pd.DataFrame({"track": name, "time_s": g["time_s"].to_numpy(float), "displacement_mm": s})
            )
    if not parts:
        return pd.DataFrame(columns=["track", "time_s", "displacement_mm"])
    return pd.concat(parts, ignore_index=True).sort_values(
        ["track", "time_s"], kind="stable", ignore_index=True
    )


def _fit_bin(t: np.ndarray, x: np.ndarray, phi: np.ndarray) -> tuple[float, float, float]:
    """Three-parameter LS fit x = a·cos φ + b·sin φ + c → (amplitude, u(amplitude), phase δ in rad)."""
    X = np.column_stack([np.cos(phi), np.sin(phi), np.ones_like(phi)])
    coef, *_ = np.linalg.lstsq(X, x, rcond=None)
    resid = x - X @ coef
    dof = len(x) - 3
    s2 = float(resid @ resid) / dof
    cov = s2 * np.linalg.inv(X.T @ X)
    a, b = coef[0], coef[1]
    amp = float(np.hypot(a, b))
    grad = np.array([a, b]) / amp if amp > 0 else np.array([np.sqrt(0.5), np.sqrt(0.5)])
    u_amp = float(np.sqrt(max(float(grad @ cov[:2, :2] @ grad), 0.0)))
    return amp, u_amp, float(np.arctan2(a, b))


def lomb_scargle_power(t_s: np.ndarray, y: np.ndarray, omega_rad_s: np.ndarray) -> np.ndarray:
    """Lomb–Scargle periodogram of ``y`` (zero-mean; N samples at ``t_s``, s) at the angular frequencies
    ``omega_rad_s`` (rad/s), in the legacy power units (A²·N/4) of ``scipy.signal.lombscargle`` with its
    defaults (no weights, no floating mean): the same operations in the same order as SciPy ≥ 1.15 computes
    them (tests/test_reports_lomb.py), here because importing scipy.signal costs ≈ 1 CPU-s in every process
    that writes a report."""
    n = y.shape[0]
    weights = (np.ones_like(y, dtype=np.float64) * (1.0 / n)).reshape(-1, 1)  # they sum to 1
    freqst = np.asarray(omega_rad_s, np.float64).reshape(1, -1) * np.asarray(t_s, np.float64).reshape(-1, 1)
    weights_y = weights * np.asarray(y, np.float64).reshape(-1, 1)
    coswt, sinwt = np.cos(freqst), np.sin(freqst)
    cc = np.dot(weights.T, coswt * coswt)
    ss = 1.0 - cc
    cs = np.dot(weights.T, coswt * sinwt)
    tau = 0.5 * np.arctan2(2.0 * cs, cc - ss)  # the phase that makes the cosine and sine terms orthogonal
    freqst_tau = freqst - tau
    coswt_tau, sinwt_tau = np.cos(freqst_tau), np.sin(freqst_tau)
    yc = np.dot(weights_y.T, coswt_tau)
    ys = np.dot(weights_y.T, sinwt_tau)
    cc = np.dot(weights.T, coswt_tau * coswt_tau)
    ss = 1.0 - cc
    epsneg = np.finfo(np.float64).epsneg  # keeps a and b finite where a term vanishes
    cc[cc < epsneg] = epsneg
    ss[ss < epsneg] = epsneg
    a, b = yc / cc, ys / ss
    power: np.ndarray = np.squeeze(2.0 * (a * yc + b * ys))
    power *= float(n) / 4.0
    return power


def _peak_frequency_hz(t: np.ndarray, x: np.ndarray, lo_hz: float, hi_hz: float) -> float:
    """Frequency of the Lomb–Scargle peak in [lo, hi] (0.005 Hz grid, parabolic refinement)."""
    freqs = np.arange(max(lo_hz, 0.05), hi_hz, 0.005)
    if len(freqs) < 3:
        return float("nan")
    power = lomb_scargle_power(t - t[0], x - x.mean(), 2 * np.pi * freqs)
    k = int(np.argmax(power))
    if 0 < k < len(freqs) - 1:
        y0, y1, y2 = power[k - 1 : k + 2]
        denom = y0 - 2 * y1 + y2
        shift = 0.5 * (y0 - y2) / denom if denom != 0 else 0.0
        return float(freqs[k] + shift * 0.005)
    return float(freqs[k])


def fitted_bins(f_t_hz: np.ndarray, phi_rad: np.ndarray,
                bin_hz: float = DEFAULT_BIN_HZ) -> Iterator[tuple[np.float64, np.float64, np.ndarray]]:
    """The bins :func:`amplitude_by_bin` fits in one track, in frequency order: (lo Hz, hi Hz, mask of the
    samples whose reference frequency ``f_t_hz`` lies in [lo, hi)), those with ≥ MIN_SAMPLES_PER_BIN samples
    spanning ≥ MIN_CYCLES_PER_BIN cycles of the reference phase ``phi_rad`` (rad)."""
    edges = np.arange(np.floor(f_t_hz.min() / bin_hz) * bin_hz, f_t_hz.max() + bin_hz, bin_hz)
    for lo, hi in itertools.pairwise(edges):
        m = (f_t_hz >= lo) & (f_t_hz < hi)
        if int(m.sum()) < MIN_SAMPLES_PER_BIN:
            continue
        if (phi_rad[m].max() - phi_rad[m].min()) / (2 * np.pi) < MIN_CYCLES_PER_BIN:
            continue
        yield lo, hi, m


def amplitude_by_bin(
    samples: pd.DataFrame, sweep: dict, *, sync_method: str, bin_hz: float = DEFAULT_BIN_HZ
) -> pd.DataFrame:
    """Per (track, frequency bin): reference and measured amplitude, error and phase (``BIN_COLUMNS``).

    ``phase_deg`` is the phase of the measured motion relative to the reference, minus that of the track's
    first bin (the sweep event does not fix the phase origin): a timing error shows as a phase growing with f.
    Bins with fewer than 3 cycles or 12 samples are left out. ``bin`` is the bin's place on the frequency
    axis (``frequency_lo_hz / bin_hz``), the same for every track, so per-bin means over tracks that start
    or end at different frequencies (a marker lost for a while) compare like with like.
    """
    if not bin_hz > 0:
        raise ReportError(f"bin_hz must be > 0, got {bin_hz!r}")
    amp_ref = float(sweep["amplitude_mm"])
    if not amp_ref > 0:
        raise ReportError(f"sweep.amplitude_mm must be > 0, got {amp_ref!r}")
    rows = []
    for track, g in samples.groupby("track", sort=True):
        t = g["time_s"].to_numpy(float)
        x = g["displacement_mm"].to_numpy(float)
        f_t = profile_frequency_hz(sweep, t)
        phi = sweep_phase_rad(sweep, t)
        first_phase = None
        for lo, hi, m in fitted_bins(f_t, phi, bin_hz):
            n = int(m.sum())
            amp, u_amp, delta = _fit_bin(t[m], x[m], phi[m])
            u_amp = max(u_amp, 1e-9 * amp_ref)  # numerical floor: exact synthetic data give u ≈ 1e-16
            first_phase = delta if first_phase is None else first_phase
            phase = float(np.rad2deg(np.angle(np.exp(1j * (delta - first_phase)))))
            rows.append(
                {
                    "sync_method": sync_method,
                    "track": track,
                    "bin": round(lo / bin_hz),
                    "frequency_lo_hz": float(lo),
                    "frequency_hi_hz": float(hi),
                    "frequency_hz": float(f_t[m].mean()),
                    "t_mid_s": float(t[m].mean()),
                    "n_samples": n,
                    "amplitude_ref_mm": amp_ref,
                    "amplitude_meas_mm": amp,
                    "u_amplitude_mm": u_amp,
                    "amplitude_error_pct": 100 * (amp - amp_ref) / amp_ref,
                    "u_amplitude_error_pct": 100 * u_amp / amp_ref,
                    "phase_deg": phase,
                    "measured_frequency_hz": _peak_frequency_hz(
                        t[m], x[m], lo - 0.5 * bin_hz, hi + 0.5 * bin_hz
                    ),
                }
            )
    return pd.DataFrame(rows, columns=BIN_COLUMNS)


def bin_means(bins: pd.DataFrame) -> pd.DataFrame:
    """Mean over tracks per (sync method, bin), for display: frequency, amplitudes, error, phase."""
    cols = [
        "frequency_hz",
        "amplitude_ref_mm",
        "amplitude_meas_mm",
        "amplitude_error_pct",
        "phase_deg",
        "measured_frequency_hz",
        "t_mid_s",
    ]
    if bins.empty:
        return pd.DataFrame(columns=["sync_method", "bin", "n_tracks", *cols])
    g = bins.groupby(["sync_method", "bin"], sort=True)
    out = g[cols].mean()
    out.insert(0, "n_tracks", g.size())
    return out.reset_index()


def linear_interp_gain(f_hz: np.ndarray, fs_hz: float, alpha: float) -> np.ndarray:
    """|H(α)| of linear interpolation at fractional delay α ∈ [0, 1]: √(1 − 4α(1−α)·sin²(πf/fs)), notes §5."""
    theta = 2 * np.pi * np.asarray(f_hz, float) / fs_hz
    return np.sqrt(1 - 4 * alpha * (1 - alpha) * np.sin(theta / 2) ** 2)


def theory_linear_pct(f_hz: np.ndarray, fs_hz: float, alpha: float | None = None) -> np.ndarray:
    """Relative amplitude error (%) of linear interpolation of a sinusoid sampled at fs.

    With ``alpha`` the gain at that fractional delay; with ``None`` the mean gain over α uniform in [0, 1]
    (64-point Gauss–Legendre), the expectation for an unknown constant delay.
    """
    if not fs_hz > 0:
        raise ReportError(f"fs_hz must be > 0, got {fs_hz!r}")
    if alpha is not None:
        return 100 * (linear_interp_gain(f_hz, fs_hz, alpha) - 1)
    nodes, weights = np.polynomial.legendre.leggauss(64)
    a = 0.5 * (nodes + 1)
    gains = np.array([linear_interp_gain(f_hz, fs_hz, ai) for ai in a])
    return 100 * (np.tensordot(0.5 * weights, gains, axes=1) - 1)


def fractional_delay(offset_s: float, fs_hz: float) -> float:
    """α = frac(offset·fs) ∈ [0, 1): where camera B's instants fall between camera A's samples."""
    return float(np.mod(offset_s * fs_hz, 1.0))
