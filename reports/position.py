"""Error versus position: static poses of the arm, ISO 9283 AP/RP, VDI/VDE 2634-1 length errors.

Inputs are the analysis tracks (``segment``, ``time_s``, ``track_id``, ``x_mm``, ``y_mm``, ``z_mm``, …)
and the commanded poses of :func:`reports.load.accuracy_poses`. A track is identified as a commanded
marker when its median position in the pose's time window is the nearest one (unique assignment) and
lies within ``gate_mm`` — a gate far larger than the errors it reports. The measured position is the
mean of the track's samples in the window taken at rest (:func:`settled_samples`: a frame exposed while the
arm still arrived — a camera clock mapped late on a loaded host, an arm still settling — is left out and
counted, not averaged in); its standard uncertainty per axis is the Type A standard error s/√n (samples
taken as independent: a static marker's noise is white frame to frame).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

from reports.errors import ReportError

XYZ = ("x", "y", "z")
DEFAULT_GATE_MM = 50.0
# A sample is at rest within SETTLED_FACTOR × the median frame-to-frame step of its window from the rest
# position. For white Gaussian noise of σ per axis a step's length has median 2.18 σ and a sample's distance
# from the rest (the median of 3 samples) is Maxwell-distributed with scale 1.2 σ, so the bound is 9 scales:
# a sample at rest exceeds it with probability < 1e-15, and < 2e-4 when a short window's median step comes
# out half its true value. Steps from the arrival are few, so they do not move the median.
SETTLED_FACTOR = 5.0
REST_SAMPLES = 3  # the rest position: the median of the window's last samples (the arm has arrived by then)
MIN_JUDGED = 2 * REST_SAMPLES  # fewer samples in a window: all kept (too few to tell rest from noise)


def settled_samples(xyz_mm: np.ndarray) -> np.ndarray:
    """Which of a static marker's samples (N, 3) mm, in time order, were taken at rest (bool (N,)): those
    within ``SETTLED_FACTOR`` × the median length of the frame-to-frame steps (+ 1 nm, for noise-free data)
    of the rest position, the median of the last ``REST_SAMPLES`` samples. Windows of fewer than
    ``MIN_JUDGED`` samples are kept whole."""
    n = len(xyz_mm)
    if n < MIN_JUDGED:
        return np.ones(n, dtype=bool)
    rest = np.median(xyz_mm[-REST_SAMPLES:], axis=0)
    step_mm = float(np.median(np.linalg.norm(np.diff(xyz_mm, axis=0), axis=1)))
    settled: np.ndarray = np.linalg.norm(xyz_mm - rest, axis=1) <= SETTLED_FACTOR * step_mm + 1e-6
    return settled


def _check_columns(frame: pd.DataFrame, columns: list[str], what: str) -> None:
    missing = [c for c in columns if c not in frame.columns]
    if missing:
        raise ReportError(f"{what}: missing column(s) {missing}; have {list(frame.columns)}")


def match_static(
    tracks: pd.DataFrame, poses: pd.DataFrame, *, gate_mm: float = DEFAULT_GATE_MM
) -> pd.DataFrame:
    """Measured position of every commanded marker of every pose (NaN where no track lies within the gate).

    Returns ``poses`` with ``x_meas_mm``, ``y_meas_mm``, ``z_meas_mm``, ``u_x_mm``, ``u_y_mm``, ``u_z_mm``
    (standard errors of the means), ``n_samples`` (averaged), ``n_unsettled`` (left out: taken while the
    marker still moved, :func:`settled_samples`) and ``track_id`` (−1 when unmatched) added.
    """
    if not gate_mm > 0:
        raise ReportError(f"gate_mm must be > 0, got {gate_mm!r}")
    _check_columns(tracks, ["time_s", "track_id", "x_mm", "y_mm", "z_mm"], "tracks")
    out = poses.copy()
    meas = np.full((len(out), 3), np.nan)  # x, y, z_meas_mm
    u = np.full((len(out), 3), np.nan)  # u_x, u_y, u_z_mm
    n_samples = np.zeros(len(out), dtype=np.int64)
    n_unsettled = np.zeros(len(out), dtype=np.int64)
    track_id = np.full(len(out), -1, dtype=np.int64)
    seg = tracks["segment"].astype(str) if "segment" in tracks.columns else pd.Series("", index=tracks.index)
    key = (seg + "#" + tracks["track_id"].astype(str)).to_numpy()
    seg_of_row = seg.to_numpy()
    times = tracks["time_s"].to_numpy(float)
    xyz_all = tracks[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
    finite = np.all(np.isfinite(xyz_all), axis=1)
    group_keys = ["index", "t_start_s", "t_stop_s", "segment"]
    by = out.assign(segment="") if "segment" not in out.columns else out
    for (_index, t0, t1, segment), at in by.groupby(group_keys, sort=True).indices.items():
        sel = (times >= t0) & (times <= t1) & finite
        if segment and "segment" in tracks.columns:
            sel &= seg_of_row == segment
        if not sel.any():
            continue
        order = np.argsort(times[sel], kind="stable")  # time order within each track, for settled_samples
        keys = key[sel][order]
        xyz = xyz_all[sel][order]
        ids = np.unique(keys)
        medians = np.array([np.median(xyz[keys == k], axis=0) for k in ids])
        cmd = by[["x_cmd_mm", "y_cmd_mm", "z_cmd_mm"]].to_numpy(float)[at]
        dist = np.linalg.norm(cmd[:, None, :] - medians[None, :, :], axis=2)
        r_idx, c_idx = linear_sum_assignment(dist)
        for r, c in zip(r_idx, c_idx, strict=True):
            if dist[r, c] > gate_mm:
                continue
            samples = xyz[keys == ids[c]]
            settled = settled_samples(samples)
            pts = samples[settled]
            n, row = len(pts), at[r]
            meas[row] = pts.mean(axis=0)
            if n > 1:
                u[row] = pts.std(axis=0, ddof=1) / np.sqrt(n)
            n_samples[row] = n
            n_unsettled[row] = np.count_nonzero(~settled)
            track_id[row] = int(str(ids[c]).rsplit("#", 1)[1])
    for k, col in enumerate(("x_meas_mm", "y_meas_mm", "z_meas_mm")):
        out[col] = meas[:, k]
    for k, col in enumerate(("u_x_mm", "u_y_mm", "u_z_mm")):
        out[col] = u[:, k]
    out["n_samples"] = n_samples
    out["n_unsettled"] = n_unsettled
    out["track_id"] = track_id
    if "segment" not in out.columns:
        out["segment"] = ""
    return out


def position_errors(matched: pd.DataFrame) -> pd.DataFrame:
    """Add ``ex_mm``, ``ey_mm``, ``ez_mm`` (measured − commanded), ``error_mm`` (norm) and ``u_error_mm``.

    ``u_error_mm`` is the Type A standard uncertainty of ``error_mm`` propagated from the per-axis standard
    errors (sensitivities e_i/|e|; the root-mean-square of the axes when |e| = 0).
    """
    out = matched.copy()
    e = np.stack(
        [out[f"{a}_meas_mm"].to_numpy(float) - out[f"{a}_cmd_mm"].to_numpy(float) for a in XYZ], axis=1
    )
    u = out[["u_x_mm", "u_y_mm", "u_z_mm"]].to_numpy(float)
    norm = np.linalg.norm(e, axis=1)
    for i, a in enumerate(XYZ):
        out[f"e{a}_mm"] = e[:, i]
    out["error_mm"] = norm
    with np.errstate(invalid="ignore", divide="ignore"):
        sens = np.where(norm[:, None] > 0, e / norm[:, None], 1.0 / np.sqrt(3.0))
    out["u_error_mm"] = np.sqrt(np.sum((sens * u) ** 2, axis=1))
    return out


def add_geometry(errors: pd.DataFrame, centres_mm: dict[str, np.ndarray]) -> pd.DataFrame:
    """Add ``distance_mm`` (from the midpoint of the camera centres) and ``off_axis_mm``.

    ``off_axis_mm`` is the distance from the viewing axis, the line from the cameras' midpoint through the
    centroid of all commanded positions (the centre of the tested volume). NaN without two calibrated cameras.
    """
    out = errors.copy()
    cmd = out[["x_cmd_mm", "y_cmd_mm", "z_cmd_mm"]].to_numpy(float)
    if len(centres_mm) < 2 or len(cmd) == 0:
        out["distance_mm"] = np.nan
        out["off_axis_mm"] = np.nan
        return out
    mid = np.mean(np.stack(list(centres_mm.values())), axis=0)
    axis = cmd.mean(axis=0) - mid
    axis = axis / np.linalg.norm(axis)
    rel = cmd - mid
    along = rel @ axis
    out["distance_mm"] = np.linalg.norm(rel, axis=1)
    out["off_axis_mm"] = np.linalg.norm(rel - along[:, None] * axis, axis=1)
    return out


def position_summary(errors: pd.DataFrame) -> dict[str, float]:
    """Mean, RMS, max and 95th percentile (linear interpolation) of ``error_mm`` over matched poses, in mm."""
    e = errors["error_mm"].to_numpy(float)
    found = e[np.isfinite(e)]
    summary: dict[str, float] = {
        "n_commanded": len(e), "n_matched": len(found), "n_missing": int(len(e) - len(found))
    }
    if len(found):
        summary |= {
            "mean_mm": float(found.mean()),
            "rms_mm": float(np.sqrt(np.mean(found**2))),
            "max_mm": float(found.max()),
            "p95_mm": float(np.percentile(found, 95)),
        }
    else:
        summary |= {"mean_mm": np.nan, "rms_mm": np.nan, "max_mm": np.nan, "p95_mm": np.nan}
    return summary


def iso9283(errors: pd.DataFrame) -> pd.DataFrame:
    """ISO 9283 position accuracy AP_P and repeatability RP_l per (target, marker) over the cycles.

    AP_P = ‖p̄ − p_c‖ (p̄ the mean attained position over n cycles, p_c commanded), AP_x/y/z its
    components; RP_l = l̄ + 3·S_l with l_j = ‖p_j − p̄‖ and S_l the sample standard deviation (n − 1).
    Targets measured in fewer than 2 cycles get NaN repeatability.
    """
    rows = []
    ok = errors.dropna(subset=["x_meas_mm", "y_meas_mm", "z_meas_mm"])
    for (target, marker_id), g in ok.groupby(["target", "marker_id"], sort=True):
        p = g[["x_meas_mm", "y_meas_mm", "z_meas_mm"]].to_numpy(float)
        c = g[["x_cmd_mm", "y_cmd_mm", "z_cmd_mm"]].to_numpy(float).mean(axis=0)
        p_bar = p.mean(axis=0)
        ap = p_bar - c
        dist = np.linalg.norm(p - p_bar, axis=1)
        s_l = float(np.std(dist, ddof=1)) if len(dist) > 1 else np.nan
        rows.append(
            {
                "target": target,
                "marker_id": marker_id,
                "n_cycles": len(p),
                "x_cmd_mm": c[0],
                "y_cmd_mm": c[1],
                "z_cmd_mm": c[2],
                "ap_x_mm": ap[0],
                "ap_y_mm": ap[1],
                "ap_z_mm": ap[2],
                "ap_p_mm": float(np.linalg.norm(ap)),
                "l_mean_mm": float(dist.mean()),
                "s_l_mm": s_l,
                "rp_l_mm": float(dist.mean() + 3 * s_l) if len(dist) > 1 else np.nan,
            }
        )
    cols = [
        "target",
        "marker_id",
        "n_cycles",
        "x_cmd_mm",
        "y_cmd_mm",
        "z_cmd_mm",
        "ap_x_mm",
        "ap_y_mm",
        "ap_z_mm",
        "ap_p_mm",
        "l_mean_mm",
        "s_l_mm",
        "rp_l_mm",
    ]
    return pd.DataFrame(rows, columns=cols)


def length_errors(errors: pd.DataFrame) -> pd.DataFrame:
    """VDI/VDE 2634-1 length measurement error ΔL = L_measured − L_calibrated for every marker pair of a pose.

    Within one pose (same event ``index``) every pair of matched markers is a test length; the calibrated
    length is the distance between the commanded positions. ``u_length_mm`` is the Type A standard
    uncertainty of L_measured from the two endpoints' standard errors projected on the pair's direction.
    """
    rows = []
    ok = errors.dropna(subset=["x_meas_mm", "y_meas_mm", "z_meas_mm"])
    for index, group in ok.groupby("index", sort=True):
        g = group.sort_values("marker_id")
        cmd = g[["x_cmd_mm", "y_cmd_mm", "z_cmd_mm"]].to_numpy(float)
        meas = g[["x_meas_mm", "y_meas_mm", "z_meas_mm"]].to_numpy(float)
        unc = g[["u_x_mm", "u_y_mm", "u_z_mm"]].to_numpy(float)
        ids = g["marker_id"].tolist()
        for i in range(len(g)):
            for j in range(i + 1, len(g)):
                d_meas = meas[j] - meas[i]
                l_meas = float(np.linalg.norm(d_meas))
                l_cal = float(np.linalg.norm(cmd[j] - cmd[i]))
                direction = d_meas / l_meas if l_meas > 0 else np.zeros(3)
                u_len = float(np.sqrt(np.sum((direction * unc[i]) ** 2) + np.sum((direction * unc[j]) ** 2)))
                rows.append(
                    {
                        "index": int(index),
                        "cycle": int(g["cycle"].iloc[0]),
                        "target": g["target"].iloc[0],
                        "marker_a": ids[i],
                        "marker_b": ids[j],
                        "length_cal_mm": l_cal,
                        "length_meas_mm": l_meas,
                        "length_error_mm": l_meas - l_cal,
                        "u_length_mm": u_len,
                    }
                )
    cols = [
        "index",
        "cycle",
        "target",
        "marker_a",
        "marker_b",
        "length_cal_mm",
        "length_meas_mm",
        "length_error_mm",
        "u_length_mm",
    ]
    return pd.DataFrame(rows, columns=cols)
