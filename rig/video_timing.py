"""Relating two video files' clocks: which track is which marker, a coarse offset, then the joint estimate.

Two cameras recording to files start at different moments and stamp frames with their own clocks, so the
offset between the files can be seconds. :func:`estimate_video_timing`:

1. **pairs tracks without time**: each 2-D track (:func:`rig.tracks2d.tracks_2d`) is summarised by its
   median image position; a marker oscillating about a rest position has its median near the image of the
   rest position in both cameras, so tracks pair by the symmetric epipolar distance of their medians
   (optimal one-to-one assignment within ``gate_px``);
2. **coarse offset** by cross-correlating the paired moving tracks' image velocities (u and v, every pair,
   on a common grid of one frame period): the lag of the largest normalised correlation within
   ± ``max_offset_s``. A steady periodic motion correlates equally at whole periods: when the second best
   peak (more than 2 frames away) reaches 95 % of the best, the offset is reported ambiguous (amplitudes and
   frequencies of a steady vibration are unaffected; absolute timing is) — film the start of the motion;
3. the **joint estimate** (:func:`rig.stereo.estimate_offset`, method "joint": offset, rolling-shutter line
   time, drift) from the coarse offset, on the moving pairs (undistorted pixels). When the motion cannot
   reveal the line time (the estimator raises :class:`rig.stereo.errors.LineTimeNotObservableError`, e.g.
   markers moving along their rows; or its estimate lies outside 0 … frame period / image height) it is
   taken as 0 (global shutter) and the estimate repeated, with a note in ``details["line_time_note"]``.

Units: s, px. Pure functions of observation frames (no I/O).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment
from scipy.signal import correlate

from rig.stereo import estimate_offset, fundamental_from_projections
from rig.stereo.dlt import DLTCamera
from rig.stereo.epipolar import epipolar_distance_px
from rig.stereo.errors import LineTimeNotObservableError, StereoError
from rig.stereo.timing import TimingResult
from rig.tracks2d import tracks_2d

__all__ = ["VideoTimingError", "coarse_offset", "estimate_video_timing", "pair_by_median"]


class VideoTimingError(ValueError):
    """The two videos' clocks could not be related (the message says what to do)."""


def _medians(obs: pd.DataFrame) -> pd.DataFrame:
    g = obs[obs["track_id"] >= 0].groupby("track_id")
    out = g.agg(u_px=("u_px", "median"), v_px=("v_px", "median"), n=("u_px", "size"),
                su=("u_px", "std"), sv=("v_px", "std"))
    out["motion_px"] = np.hypot(out["su"].fillna(0.0), out["sv"].fillna(0.0))
    return out


def pair_by_median(obs_a: pd.DataFrame, obs_b: pd.DataFrame, cam_a: DLTCamera, cam_b: DLTCamera,
                   *, gate_px: float = 8.0) -> pd.DataFrame:
    """Pairs (track_a, track_b, distance_px, motion_a_px, motion_b_px) of tracks whose median positions
    satisfy the epipolar constraint within ``gate_px`` (undistorted pixels), one-to-one."""
    ma, mb = _medians(obs_a), _medians(obs_b)
    cols = ["track_a", "track_b", "distance_px", "motion_a_px", "motion_b_px"]
    if ma.empty or mb.empty:
        return pd.DataFrame(columns=cols)
    F = fundamental_from_projections(cam_a.P, cam_b.P)
    ua = cam_a.undistort_px(ma[["u_px", "v_px"]].to_numpy(float))
    ub = cam_b.undistort_px(mb[["u_px", "v_px"]].to_numpy(float))
    d = epipolar_distance_px(F, ua, ub)
    cost = np.where(d <= gate_px, d, 1e6)
    r, c = linear_sum_assignment(cost)
    ok = cost[r, c] <= gate_px
    r, c = r[ok], c[ok]
    return pd.DataFrame({"track_a": ma.index.to_numpy()[r], "track_b": mb.index.to_numpy()[c],
                         "distance_px": d[r, c], "motion_a_px": ma["motion_px"].to_numpy()[r],
                         "motion_b_px": mb["motion_px"].to_numpy()[c]})


def _velocity_on_grid(obs: pd.DataFrame, track: int, grid_s: np.ndarray) -> np.ndarray:
    tr = obs[obs["track_id"] == track].sort_values("timestamp_s")
    t = tr["timestamp_s"].to_numpy(float)
    t, keep = np.unique(t, return_index=True)
    out = np.zeros((len(grid_s), 2))
    if len(t) < 3:
        return out
    for k, col in enumerate(("u_px", "v_px")):
        x = np.interp(grid_s, t, tr[col].to_numpy(float)[keep], left=np.nan, right=np.nan)
        v = np.gradient(x, grid_s)
        out[:, k] = np.where(np.isfinite(v), v, 0.0)
    return out


def coarse_offset(obs_a: pd.DataFrame, obs_b: pd.DataFrame, pairs: pd.DataFrame, period_s: float,
                  *, max_offset_s: float = 600.0) -> dict[str, Any]:
    """Offset (s) to add to camera B's time stamps to put them on A's clock, to about one frame:
    ``{"offset_s", "correlation", "second_correlation", "second_offset_s", "ambiguous"}``."""
    t_lo = min(obs_a["timestamp_s"].min(), obs_b["timestamp_s"].min())
    t_hi = max(obs_a["timestamp_s"].max(), obs_b["timestamp_s"].max())
    grid = np.arange(t_lo, t_hi + period_s, period_s)
    n = len(grid)
    max_lag = int(min(np.ceil(max_offset_s / period_s), n - 8))
    if max_lag < 1:
        raise VideoTimingError(f"the videos are too short ({n} frames) to relate their clocks")
    num = np.zeros(2 * n - 1)
    va_all = vb_all = 0.0
    for a, b in zip(pairs["track_a"], pairs["track_b"], strict=True):
        va, vb = _velocity_on_grid(obs_a, int(a), grid), _velocity_on_grid(obs_b, int(b), grid)
        for k in range(2):
            num += correlate(va[:, k], vb[:, k], mode="full", method="fft")
        va_all += float(np.sum(va**2))
        vb_all += float(np.sum(vb**2))
    if va_all <= 1e-9 * n or vb_all <= 1e-9 * n:  # below rounding: no motion at all
        raise VideoTimingError("no paired marker moves in both videos: the clocks cannot be related from "
                               "motion; give --timing timing.json")
    lags = np.arange(-(n - 1), n)  # lag L: a[i + L] ~ b[i] → t_a = t_b + L·period
    corr = num / np.sqrt(va_all * vb_all)
    sel = np.abs(lags) <= max_lag
    corr, lags = corr[sel], lags[sel]
    best = int(np.argmax(corr))
    far = np.abs(lags - lags[best]) > 2
    second = int(np.flatnonzero(far)[np.argmax(corr[far])]) if far.any() else best
    ambiguous = bool(far.any() and corr[second] >= 0.95 * corr[best])
    return {"offset_s": float(lags[best] * period_s), "correlation": float(corr[best]),
            "second_offset_s": float(lags[second] * period_s), "second_correlation": float(corr[second]),
            "ambiguous": ambiguous}


def estimate_video_timing(obs: dict[str, pd.DataFrame], cameras: dict[str, DLTCamera], fps: dict[str, float],
                          *, reference: str, gate_px: float = 8.0, max_offset_s: float = 600.0,
                          min_motion_px: float = 0.5, track_gate_px: float = 25.0, max_pairs: int = 2,
                          window_s: float = 1.5, line_time_s: float | None = None) -> TimingResult:
    """Timing of the other camera relative to ``reference`` from the videos' observations (module doc).

    ``obs``: camera → observations (``frame_index``, ``timestamp_s``, ``u_px``, ``v_px``; duplicates already
    left out). At most ``max_pairs`` pairs (the most moving) go to the joint estimate, and of records longer
    than 2 × ``window_s`` only a window of ``window_s`` at each end. ``line_time_s``: the cameras' known
    rolling-shutter line time (s), else estimated — and taken as 0 with a note in ``details`` when the motion
    cannot identify it (the estimator reports it not observable, or an estimate outside 0 … frame period /
    image height). ``details`` hold the coarse step.
    """
    names = list(obs)
    if len(names) != 2 or reference not in names:
        raise VideoTimingError(f"timing from videos needs exactly 2 cameras including {reference!r}, "
                               f"got {names}")
    other = names[1] if names[0] == reference else names[0]
    tracked = {}
    for c in names:
        o = obs[c].copy()
        o["track_id"] = tracks_2d(o, gate_px=track_gate_px).to_numpy()
        tracked[c] = o
    pairs = pair_by_median(tracked[reference], tracked[other], cameras[reference], cameras[other],
                           gate_px=gate_px)
    moving = pairs[(pairs["motion_a_px"] >= min_motion_px) & (pairs["motion_b_px"] >= min_motion_px)]
    if moving.empty:
        raise VideoTimingError(
            f"no marker moves by ≥ {min_motion_px} px in both videos ({len(pairs)} static pair(s)); the "
            "clocks "
            "cannot be estimated from motion — give --timing timing.json")
    coarse = coarse_offset(tracked[reference], tracked[other], moving, 1.0 / fps[other],
                           max_offset_s=max_offset_s)
    # the joint estimate's cost grows with the samples: the most moving pairs, and for long records a
    # window at each end (the drift needs the span, the offset only a few periods)
    use = moving.assign(m=np.minimum(moving["motion_a_px"], moving["motion_b_px"])).nlargest(max_pairs, "m")
    t_b = tracked[other]["timestamp_s"].to_numpy(float)
    t0, t1 = float(t_b.min()) + coarse["offset_s"], float(t_b.max()) + coarse["offset_s"]
    windows = [(t0, t1)] if t1 - t0 <= 2 * window_s else [(t0, t0 + window_s), (t1 - window_s, t1)]
    tracks_a, tracks_b = [], []
    for a, b in zip(use["track_a"], use["track_b"], strict=True):
        for lo, hi in windows:
            for cam, name, tid, dest, shift in ((cameras[reference], reference, a, tracks_a, 0.0),
                                                (cameras[other], other, b, tracks_b, coarse["offset_s"])):
                tr = tracked[name]
                tr = tr[tr["track_id"] == tid].sort_values("timestamp_s").drop_duplicates("timestamp_s")
                t = tr["timestamp_s"].to_numpy(float)
                sel = (t + shift >= lo) & (t + shift <= hi)
                dest.append((t[sel], cam.undistort_px(tr[["u_px", "v_px"]].to_numpy(float)[sel])))
    line_max_s = 1.0 / (max(fps.values()) * max(c.image_size[1] for c in cameras.values()))
    note = None
    fallback = " assumed 0 (global shutter) — give --line-time-s for a rolling-shutter camera"
    try:
        try:
            result = estimate_offset(cameras[reference], cameras[other], tracks_a, tracks_b, method="joint",
                                     names=(reference, other), offset_guess_s=coarse["offset_s"],
                                     line_time_s=line_time_s, line_time_guess_s=0.5 * line_max_s)
        except LineTimeNotObservableError as exc:
            note = (f"line time not observable from this motion (estimate {exc.estimate_s * 1e6:+.2f} ± "
                    f"{exc.uncertainty_s * 1e6:.2f} µs{', at the bound of the fit' if exc.at_bound else ''}; "
                    f"rows differ by {exc.row_difference_spread_px:.2f} px std between the cameras);"
                    + fallback)
        else:
            lt = result.line_time_s.get(other, 0.0)
            if line_time_s is None and not -0.05 * line_max_s <= lt <= 1.05 * line_max_s:
                note = (f"line time not identifiable from this motion (estimate {lt * 1e6:.2f} µs outside "
                        f"0…{line_max_s * 1e6:.2f} µs = frame period / image height);" + fallback)
        if note:
            result = estimate_offset(cameras[reference], cameras[other], tracks_a, tracks_b, method="joint",
                                     names=(reference, other), offset_guess_s=coarse["offset_s"],
                                     line_time_s=0.0)
    except StereoError as exc:
        raise VideoTimingError(f"joint timing estimate from the coarse offset {coarse['offset_s']:+.4f} s "
                               f"failed: {exc}; give --timing timing.json") from exc
    if note:
        result.details = {**result.details, "line_time_note": note}
    result.details = {**result.details, "coarse": coarse, "pairs_used": len(use), "windows_s": windows,
                      "source": "rig measure --estimate-timing (video motion)"}
    return result
