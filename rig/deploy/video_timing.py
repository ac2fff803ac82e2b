"""Relating two video files' clocks: which track is which marker, a coarse offset, then the joint estimate.

Two cameras recording to files start at different moments and stamp frames with their own clocks, so the
offset between the files can be seconds. :func:`estimate_video_timing`:

1. **pairs tracks without time**: each 2-D track (:func:`rig.analysis.tracks2d.tracks_2d`) is summarised by
its
   median image position; a marker oscillating about a rest position has its median near the image of the
   rest position in both cameras, so tracks pair by the symmetric epipolar distance of their medians
   (optimal one-to-one assignment within ``gate_px`` + a fifth of the motion);
   A marker the 2-D tracking breaks into pieces (a rotor moving tens of pixels per frame) is taken whole:
   when a camera's moving detections number at most one per frame, they are one marker
   (:func:`merge_lone_mover`), whatever the tracking made of them;
2. **candidate offsets** by cross-correlating the paired moving tracks' image velocities (u and v, every
   pair, on a common grid of one frame period): the peaks of the normalised correlation within the prior
   window ``prior_offset_s`` ± ``max_offset_s`` (cameras started independently within that window);
3. **each candidate scored** by the joint model's epipolar cost (all used pairs jointly, so several markers,
   amplitude and frequency changes all count): Δχ² against the best, and a relative likelihood
   exp(−z²/2) with z = Δχ² / (2√n) — 2√n being the spread of the cost between two offsets that explain the
   data equally well but interpolate different noise (:mod:`rig.stereo.timing_joint`). A candidate with
   Δχ² < 25 + 10√n cannot be told from the best: the offset is then **ambiguous** (a steady periodic motion
   repeats every period); the most likely is used — among equals the one nearest ``prior_offset_s`` — and
   every candidate is listed with its likelihood in ``details["coarse"]["candidates"]``. Whole periods of a
   steady motion change neither amplitudes nor frequencies (both candidates explain the 3-D motion equally
   well); they change absolute timing;
4. the **joint estimate** (:func:`rig.stereo.estimate_offset`, method "joint": offset, rolling-shutter line
   time, drift) around the chosen candidate, on the moving pairs (undistorted pixels), the line time with
   the prior 0 … frame period / image height: when the motion cannot reveal it the offset uncertainty
   includes all the line time can do (``details["line_time"]``).

Units: s, px. Pure functions of observation frames (no I/O).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

from rig.analysis.tracks2d import tracks_2d
from rig.stereo import estimate_offset, fundamental_from_projections, triangulate
from rig.stereo.dlt import DLTCamera
from rig.stereo.epipolar import epipolar_distance_px
from rig.stereo.errors import StereoError
from rig.stereo.resample import bandlimited
from rig.stereo.timing import TimingResult
from rig.stereo.timing_joint import CHI2_DISTINCT, JointTiming

__all__ = ["VideoTimingError", "coarse_offset", "estimate_video_timing", "merge_lone_mover", "pair_by_median",
           "rotor_timing", "tracked"]

MAX_CANDIDATES = 8
#: Candidates are scored up to this many frames from B's record ends (the joint estimate keeps 34): a
#: motion's start is often near an end, and it is what tells whole periods apart.
SCORE_EDGE_FRAMES = 4


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
    satisfy the epipolar constraint within ``gate_px`` + a fifth of their motion (undistorted pixels),
    one-to-one."""
    ma, mb = _medians(obs_a), _medians(obs_b)
    cols = ["track_a", "track_b", "distance_px", "motion_a_px", "motion_b_px"]
    if ma.empty or mb.empty:
        return pd.DataFrame(columns=cols)
    F = fundamental_from_projections(cam_a.P, cam_b.P)
    ua = cam_a.undistort_px(ma[["u_px", "v_px"]].to_numpy(float))
    ub = cam_b.undistort_px(mb[["u_px", "v_px"]].to_numpy(float))
    d = epipolar_distance_px(F, ua, ub)
    # a moving marker's median is its rest position's image only to within a fraction of its motion (a
    # circle sampled at a few phases per turn): the gate widens by a fifth of the larger motion
    gate = gate_px + 0.2 * np.maximum.outer(ma["motion_px"].to_numpy(float), mb["motion_px"].to_numpy(float))
    cost = np.where(d <= gate, d, 1e6)
    r, c = linear_sum_assignment(cost)
    ok = cost[r, c] <= gate[r, c]
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


def merge_lone_mover(obs: pd.DataFrame, *, min_motion_px: float = 0.5) -> pd.DataFrame:
    """``obs`` (with ``track_id``) where the moving tracks of a camera that never shows two moving markers in
    one frame are joined into one track (the lowest id): one fast marker the tracking broke into pieces."""
    tid = obs["track_id"].to_numpy()
    med = _medians(obs)
    moving = med.index[med["motion_px"] >= min_motion_px].to_numpy()
    if moving.size < 2:
        return obs
    sel = np.isin(tid, moving)
    if obs.loc[sel, "frame_index"].duplicated().any():
        return obs
    out = obs.copy()
    out.loc[sel, "track_id"] = int(moving.min())
    return out


def tracked(obs: pd.DataFrame, *, track_gate_px: float = 25.0, min_motion_px: float = 0.5) -> pd.DataFrame:
    """A copy of one camera's observations with ``track_id`` (:func:`rig.analysis.tracks2d.tracks_2d`, then
    :func:`merge_lone_mover`)."""
    o = obs.copy()
    o["track_id"] = tracks_2d(o, gate_px=track_gate_px).to_numpy()
    return merge_lone_mover(o, min_motion_px=min_motion_px)


def coarse_offset(obs_a: pd.DataFrame, obs_b: pd.DataFrame, pairs: pd.DataFrame, period_s: float,
                  *, max_offset_s: float = 600.0, prior_offset_s: float = 0.0) -> dict[str, Any]:
    """Offset (s) to add to camera B's time stamps to put them on A's clock, to about one frame, within
    ``prior_offset_s`` ± ``max_offset_s``: ``{"offset_s", "correlation", "second_correlation",
    "second_offset_s", "ambiguous", "peaks"}``; ``peaks`` are the correlation's local maxima (offset_s,
    correlation), best first, at most :data:`MAX_CANDIDATES`, each ≥ half the best. ``ambiguous``: the
    second peak reaches 95 % of the best (a hint; :func:`estimate_video_timing` decides by the epipolar
    cost)."""
    t_lo = min(obs_a["timestamp_s"].min(), obs_b["timestamp_s"].min())
    t_hi = max(obs_a["timestamp_s"].max(), obs_b["timestamp_s"].max())
    grid = np.arange(t_lo, t_hi + period_s, period_s)
    n = len(grid)
    if n - 8 < 1:
        raise VideoTimingError(f"the videos are too short ({n} frames) to relate their clocks")
    from scipy.signal import correlate  # ≈ 1 CPU-s to import: paid only when the timing is estimated

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
    in_window = np.abs(lags * period_s - prior_offset_s) <= max_offset_s + 0.5 * period_s
    sel = in_window & (np.abs(lags) <= n - 8)
    if not sel.any():
        raise VideoTimingError(f"no offset within {prior_offset_s:+.3f} ± {max_offset_s:.3f} s leaves the "
                               "videos overlapping; widen --max-offset-s")
    corr, lags = corr[sel], lags[sel]
    best = int(np.argmax(corr))
    far = np.abs(lags - lags[best]) > 2
    second = int(np.flatnonzero(far)[np.argmax(corr[far])]) if far.any() else best
    ambiguous = bool(far.any() and corr[second] >= 0.95 * corr[best])
    padded = np.r_[-np.inf, corr, -np.inf]
    is_peak = (padded[1:-1] >= padded[:-2]) & (padded[1:-1] > padded[2:])
    peaks = [j for j in np.argsort(-corr) if is_peak[j] and corr[j] >= 0.5 * corr[best]][:MAX_CANDIDATES]
    return {"offset_s": float(lags[best] * period_s), "correlation": float(corr[best]),
            "second_offset_s": float(lags[second] * period_s), "second_correlation": float(corr[second]),
            "ambiguous": ambiguous,
            "peaks": [(float(lags[j] * period_s), float(corr[j])) for j in peaks]}


@dataclass(frozen=True)
class _Views:
    """Both cameras' tracked observations, the pairs used for timing and how much of the record; ``series``:
    each used track's time stamps (s, sorted, each once) and observed centres (px), by (camera, track id)."""

    tracked: dict[str, pd.DataFrame]
    use: pd.DataFrame
    cameras: dict[str, DLTCamera]
    reference: str
    other: str
    window_s: float
    series: dict[tuple[str, int], tuple[np.ndarray, np.ndarray]]


def _series(obs: pd.DataFrame, track: int) -> tuple[np.ndarray, np.ndarray]:
    """One track's time stamps (s, sorted, duplicates left out) and its observed centres (N, 2) px."""
    tr = obs[obs["track_id"] == track].sort_values("timestamp_s").drop_duplicates("timestamp_s")
    return tr["timestamp_s"].to_numpy(float), tr[["u_px", "v_px"]].to_numpy(float)


def _views(tracks: dict[str, pd.DataFrame], use: pd.DataFrame, cameras: dict[str, DLTCamera], *,
           reference: str, other: str, window_s: float) -> _Views:
    """The :class:`_Views` of the pairs ``use``, each used track's series taken out once."""
    series = {(name, int(tid)): _series(tracks[name], int(tid))
              for name, column in ((reference, "track_a"), (other, "track_b")) for tid in use[column]}
    return _Views(tracks, use, cameras, reference, other, window_s, series)


def _joint_tracks(views: _Views, offset_s: float
                  ) -> tuple[list[tuple[np.ndarray, ...]], list[tuple[np.ndarray, ...]], list]:
    """The joint estimate's tracks for a coarse offset: the used pairs, and for long records a window of
    ``window_s`` at each end (the drift needs the span, the offset only a few periods)."""
    by_camera, use, cameras, reference, other = (views.tracked, views.use, views.cameras, views.reference,
                                                 views.other)
    window_s = views.window_s
    t_b = by_camera[other]["timestamp_s"].to_numpy(float)
    t0, t1 = float(t_b.min()) + offset_s, float(t_b.max()) + offset_s
    windows = [(t0, t1)] if t1 - t0 <= 2 * window_s else [(t0, t0 + window_s), (t1 - window_s, t1)]
    tracks_a: list[tuple[np.ndarray, ...]] = []
    tracks_b: list[tuple[np.ndarray, ...]] = []
    for a, b in zip(use["track_a"], use["track_b"], strict=True):
        for lo, hi in windows:
            for name, tid, dest, shift in ((reference, a, tracks_a, 0.0), (other, b, tracks_b, offset_s)):
                t, uv_all = views.series[name, int(tid)]
                sel = (t + shift >= lo) & (t + shift <= hi)
                uv = uv_all[sel]
                # undistorted centres for the geometry, observed rows for the rolling-shutter instant
                dest.append((t[sel], cameras[name].undistort_px(uv), uv[:, 1]))
    # a piece too short for the joint estimate in one camera is left out with its partner
    keep = [i for i, (ta, tb) in enumerate(zip(tracks_a, tracks_b, strict=True))
            if len(ta[0]) >= 30 and len(tb[0]) >= 30]
    return [tracks_a[i] for i in keep], [tracks_b[i] for i in keep], windows


def _use_pairs(moving: pd.DataFrame, max_pairs: int) -> pd.DataFrame:
    """The most moving pairs (the joint estimate's cost grows with the samples)."""
    return moving.assign(m=np.minimum(moving["motion_a_px"], moving["motion_b_px"])).nlargest(max_pairs, "m")


def score_candidates(views: _Views, peaks: list[tuple[float, float]], *, prior_offset_s: float
                     ) -> list[dict[str, Any]]:
    """Every correlation peak scored by the joint model's epipolar cost (module doc, step 3); best first.
    Each: offset_s (the cost's minimum near the peak), correlation, delta_chi2, relative_likelihood,
    distinct (told apart from the best), or an ``error`` when the cost cannot be evaluated there."""
    scored: list[dict[str, Any]] = []
    for off, corr in peaks:
        ta, tb, _ = _joint_tracks(views, off)
        try:
            prob = JointTiming(views.cameras[views.reference], views.cameras[views.other], ta, tb,
                               offset_guess_s=off, edge_margin_frames=SCORE_EDGE_FRAMES)
            prob.coarse_search()
        except (StereoError, ValueError) as exc:
            scored.append({"offset_s": off, "correlation": corr, "error": str(exc)})
            continue
        scored.append({"offset_s": float(prob.grid[prob.k]), "correlation": corr,
                       "mean_cost_px2": float(prob.costs[prob.k]) / prob.res.n, "n": prob.res.n})
    ok = [c for c in scored if "error" not in c]
    if not ok:
        return scored
    best = min(ok, key=lambda c: c["mean_cost_px2"])
    s2 = best["mean_cost_px2"]
    for c in ok:
        n = min(c["n"], best["n"])
        d = n * (c["mean_cost_px2"] - s2) / s2
        c["delta_chi2"] = float(d)
        c["relative_likelihood"] = float(np.exp(-0.5 * (d / (2 * np.sqrt(n))) ** 2))
        c["distinct"] = bool(d >= CHI2_DISTINCT + 10 * np.sqrt(n))
    # the best first, then those the data cannot tell from it (nearest the expected offset first)
    ok.sort(key=lambda c: (c is not best, c["distinct"], abs(c["offset_s"] - prior_offset_s)))
    if not ok[1:] or ok[1]["distinct"]:
        return ok + [c for c in scored if "error" in c]
    equal = [c for c in ok if not c["distinct"]]
    equal.sort(key=lambda c: abs(c["offset_s"] - prior_offset_s))
    return equal + [c for c in ok if c["distinct"]] + [c for c in scored if "error" in c]


def _ambiguity_note(candidates: list[dict[str, Any]]) -> str | None:
    equal = [c for c in candidates if "error" not in c and not c["distinct"]]
    if len(equal) < 2:
        return None
    listed = ", ".join(f"{c['offset_s']:+.4f} s (likelihood {c['relative_likelihood']:.2f}, "
                       f"Δχ² {c['delta_chi2']:.0f})" for c in equal)
    more = (f" (only the {MAX_CANDIDATES} highest correlation peaks are scored: further whole periods "
            "within the window fit as well)" if len(candidates) >= MAX_CANDIDATES else "")
    return (f"offset ambiguous: {len(equal)} offsets explain the motion equally well{more} — {listed}; "
            f"{equal[0]['offset_s']:+.4f} s used (the nearest the expected offset among those the data "
            "cannot tell apart). They differ by whole periods of a steady motion: amplitudes and frequencies "
            "are the same under each, absolute timing between the cameras is not; film a change of motion "
            "(start, stop, another tone), narrow --max-offset-s, or give --timing")


def estimate_video_timing(obs: dict[str, pd.DataFrame], cameras: dict[str, DLTCamera], fps: dict[str, float],
                          *, reference: str, gate_px: float = 8.0, max_offset_s: float = 10.0,
                          prior_offset_s: float = 0.0, min_motion_px: float = 0.5,
                          track_gate_px: float = 25.0, max_pairs: int = 5, window_s: float = 3.0,
                          line_time_s: float | None = None) -> TimingResult:
    """Timing of the other camera relative to ``reference`` from the videos' observations (module doc).

    ``obs``: camera → observations (``frame_index``, ``timestamp_s``, ``u_px``, ``v_px``; duplicates already
    left out). ``prior_offset_s`` ± ``max_offset_s``: the window the offset lies in (the cameras started
    within it). At most ``max_pairs`` pairs (the most moving) go to the joint estimate, and of records
    longer than 2 × ``window_s`` only a window of ``window_s`` at each end. ``line_time_s``: the cameras'
    known rolling-shutter line time (s), else estimated with the prior 0 … frame period / image height.
    ``details`` hold the candidates (``coarse``) and, when it applies, the ambiguity and line-time notes.
    """
    names = list(obs)
    if len(names) != 2 or reference not in names:
        raise VideoTimingError(f"timing from videos needs exactly 2 cameras including {reference!r}, "
                               f"got {names}")
    if not (np.isfinite(max_offset_s) and max_offset_s > 0 and np.isfinite(prior_offset_s)):
        raise VideoTimingError(f"max_offset_s must be > 0 s and prior_offset_s finite, got {max_offset_s!r}, "
                               f"{prior_offset_s!r}")
    other = names[1] if names[0] == reference else names[0]
    tracks = {c: tracked(obs[c], track_gate_px=track_gate_px, min_motion_px=min_motion_px) for c in names}
    pairs = pair_by_median(tracks[reference], tracks[other], cameras[reference], cameras[other],
                           gate_px=gate_px)
    moving = pairs[(pairs["motion_a_px"] >= min_motion_px) & (pairs["motion_b_px"] >= min_motion_px)]
    if moving.empty:
        raise VideoTimingError(
            f"no marker moves by ≥ {min_motion_px} px in both videos ({len(pairs)} static pair(s)); the "
            "clocks "
            "cannot be estimated from motion — give --timing timing.json")
    coarse = coarse_offset(tracks[reference], tracks[other], moving, 1.0 / fps[other],
                           max_offset_s=max_offset_s, prior_offset_s=prior_offset_s)
    use = _use_pairs(moving, max_pairs)
    views = _views(tracks, use, cameras, reference=reference, other=other, window_s=window_s)
    candidates = score_candidates(views, coarse["peaks"], prior_offset_s=prior_offset_s)
    chosen = next((c["offset_s"] for c in candidates if "error" not in c), coarse["offset_s"])
    ambiguity = _ambiguity_note(candidates)
    tracks_a, tracks_b, windows = _joint_tracks(views, chosen)
    line_max_s = 1.0 / (max(fps.values()) * max(c.image_size[1] for c in cameras.values()))
    try:
        result = estimate_offset(cameras[reference], cameras[other], tracks_a, tracks_b, method="joint",
                                 names=(reference, other), offset_guess_s=chosen, line_time_s=line_time_s,
                                 line_time_guess_s=0.5 * line_max_s, line_time_prior_s=(0.0, line_max_s))
    except StereoError as exc:
        raise VideoTimingError(f"joint timing estimate from the coarse offset {chosen:+.4f} s failed: "
                               f"{exc}; give --timing timing.json") from exc
    coarse = {**coarse, "candidates": candidates, "chosen_offset_s": chosen,
              "ambiguous": ambiguity is not None,
              "window_s": [prior_offset_s - max_offset_s, prior_offset_s + max_offset_s]}
    extra: dict[str, Any] = {"coarse": coarse, "pairs_used": len(use), "windows_s": windows,
                             "source": "rig measure --estimate-timing (video motion)"}
    if ambiguity:
        extra["ambiguity_note"] = ambiguity
    if "line_time" in result.details:
        extra["line_time_note"] = result.details["line_time"]["statement"]
    elif line_time_s is None:  # estimated and observable: how well, from what, and what it does to the offset
        extra["line_time_precision"] = line_time_precision(result, tracks_a, tracks_b, other, windows)
        extra["line_time_note"] = extra["line_time_precision"]["statement"]
    result.details = {**result.details, **extra}
    return result


LINE_TIME_TARGET_S = 1e-6  # issue 14: the line time within 1 µs where the motion makes it observable


def line_time_precision(result: TimingResult, tracks_a: list[tuple[np.ndarray, ...]],
                        tracks_b: list[tuple[np.ndarray, ...]], other: str,
                        windows: list[tuple[float, float]]) -> dict[str, Any]:
    """What an estimated (observable) line time rests on, quantified: the row difference v_B − v_A between
    the views over the used observations (the line time enters only through ℓ·(v_B − v_A); the offset
    absorbs its mean, so only its variation — between markers and over time, weighted by the image speed —
    measures ℓ: the line time's u scales as 1 / the size of that variation and 1 / √(time observed); the std
    reported is unweighted), the line time's share of the offset's
    uncertainty (u_offset·|ρ|, ρ their correlation), and what reaching :data:`LINE_TIME_TARGET_S` would need.
    ``windows``: the spans of the record the estimate used (:func:`_joint_tracks`). Rows in px, times in s."""
    offset_s = result.offset_s[other]
    diffs = [np.interp(ta, tb + offset_s, rb) - ra
             for (ta, _, ra), (tb, _, rb) in zip(tracks_a, tracks_b, strict=True)]
    diff = np.concatenate(diffs)
    per_marker = np.array([float(np.mean(d)) for d in diffs])
    u_line_s = float(result.uncertainty["line_time_s"][other])
    u_offset_s = float(result.uncertainty["offset_s"][other])
    labels = list(result.details.get("parameters", []))
    rho = (float(result.details["correlation"][labels.index("offset")][labels.index("line_time")])
           if "offset" in labels and "line_time" in labels else 0.0)
    from_line_s = u_offset_s * abs(rho)
    factor = u_line_s / LINE_TIME_TARGET_S
    used_s = float(sum(hi - lo for lo, hi in windows))
    used = (f"the {used_s:.1f} s used" if len(windows) == 1 else
            f"the {used_s:.1f} s used (windows at the record's two ends; the middle of a long record is not)")
    if factor <= 1.0:
        need = f"within the {LINE_TIME_TARGET_S * 1e6:g} µs target"
    else:
        need = (f"{LINE_TIME_TARGET_S * 1e6:g} µs would need ≈ {factor:.1f}× that variation (markers over "
                f"more of the image height, cameras at different heights or verged) or ≈ {factor ** 2:.0f}× "
                f"{used}, or --line-time-s")
    statement = (f"line time estimated {result.line_time_s[other] * 1e6:.2f} ± {u_line_s * 1e6:.2f} µs from "
                 f"how the views' row difference v_B − v_A varies (std {float(np.std(diff)):.2f} px about "
                 f"{float(np.mean(diff)):+.2f} px over {diff.size} observations; per marker "
                 f"{float(per_marker.min()):+.2f} … {float(per_marker.max()):+.2f} px): its u scales as 1 / "
                 f"the size of that variation; {need}. The offset's u {u_offset_s * 1e3:.4f} ms includes "
                 f"{from_line_s * 1e3:.4f} ms from the line time (correlation {rho:+.2f})")
    return {"observable": True, "uncertainty_s": u_line_s, "time_used_s": used_s,
            "row_difference_mean_px": float(np.mean(diff)), "row_difference_std_px": float(np.std(diff)),
            "row_difference_per_marker_px": per_marker.tolist(), "offset_line_time_correlation": rho,
            "offset_uncertainty_from_line_time_s": from_line_s, "statement": statement}


def rotor_timing(obs: dict[str, pd.DataFrame], cameras: dict[str, DLTCamera], joint: TimingResult, *,
                 reference: str, min_motion_px: float = 0.5, track_gate_px: float = 25.0) -> TimingResult:
    """The paper's rotating-marker phase method, row-corrected (:mod:`rig.stereo.timing_rotor`), on the
    videos' one moving marker (per-frame detections, however the tracking split them).

    The rotor's plane is not known on site: the marker's path is triangulated with the ``joint`` timing
    (:func:`estimate_video_timing`), a plane fitted (SVD) and a circle in it (Kåsa); the phase method then
    gives offset and line time near the joint offset (the same revolution). The joint result is kept in
    ``details["comparison"]``, its candidates and notes in ``details``.
    """
    other = next(c for c in obs if c != reference)
    tracks = {c: tracked(obs[c], track_gate_px=track_gate_px, min_motion_px=min_motion_px)
              for c in (reference, other)}
    pairs = pair_by_median(tracks[reference], tracks[other], cameras[reference], cameras[other])
    both = (pairs["motion_a_px"] >= min_motion_px) & (pairs["motion_b_px"] >= min_motion_px)
    moving = _use_pairs(pairs[both], 1)
    if moving.empty:
        raise VideoTimingError("--sync rotor: no marker moves in both videos")
    series = []
    for cam, tid in ((reference, int(moving["track_a"].iloc[0])), (other, int(moving["track_b"].iloc[0]))):
        tr = tracks[cam]
        tr = tr[tr["track_id"] == tid].sort_values("timestamp_s").drop_duplicates("timestamp_s")
        uv = tr[["u_px", "v_px"]].to_numpy(float)
        series.append((tr["timestamp_s"].to_numpy(float), cameras[cam].undistort_px(uv), uv[:, 1]))
    (ta, ua, ra), (tb, ub, rb) = series
    centre, axis = _rotor_plane(cameras[reference], cameras[other], joint, series, reference=reference,
                                other=other)
    try:
        res = estimate_offset(cameras[reference], cameras[other], (ta, ua), (tb, ub), method="rotor",
                              names=(reference, other), rotor_centre_mm=centre, rotor_axis=axis,
                              offset_guess_s=joint.offset_s[other], estimate_line_time=True, rows_px=(ra, rb))
    except StereoError as exc:
        raise VideoTimingError(f"--sync rotor: the rotating-marker method failed: {exc}") from exc
    res.details = {**res.details, "rotor_centre_mm": centre.tolist(), "rotor_axis": axis.tolist(),
                   "comparison": {"joint": joint.to_dict()},
                   **{k: joint.details[k] for k in ("coarse", "ambiguity_note") if k in joint.details},
                   "source": "rig measure --sync rotor (the paper's rotating-marker phase, row-corrected)"}
    return res


def _rotor_plane(cam_a: DLTCamera, cam_b: DLTCamera, joint: TimingResult, series: list, *, reference: str,
                 other: str) -> tuple[np.ndarray, np.ndarray]:
    """Centre (mm) and unit axis of the circle the marker runs on, triangulated with the joint timing."""
    (ta, ua, ra), (tb, ub, rb) = series
    t_a = joint.times(reference, ta, ra)
    t_b = joint.times(other, tb, rb)
    inside = (t_a > t_b[0] + 0.6) & (t_a < t_b[-1] - 0.6)  # the reconstruction's kernel half-width
    if np.count_nonzero(inside) < 12:
        raise VideoTimingError("--sync rotor: the videos overlap too little to locate the rotor's plane")
    ub_at = np.asarray(bandlimited(t_b, ub, t_a[inside]))
    X = triangulate([DLTCamera(P=cam_a.P), DLTCamera(P=cam_b.P)], [ua[inside], ub_at]).xyz_mm
    X = X[np.isfinite(X).all(axis=1)]
    mean = X.mean(axis=0)
    _, _, vt = np.linalg.svd(X - mean)
    axis = vt[2] / np.linalg.norm(vt[2])
    xy = np.column_stack([(X - mean) @ vt[0], (X - mean) @ vt[1]])
    (a, b, _), *_ = np.linalg.lstsq(np.column_stack([2 * xy, np.ones(len(xy))]), np.sum(xy**2, axis=1),
                                    rcond=None)
    return mean + a * vt[0] + b * vt[1], axis
