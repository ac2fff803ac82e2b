"""Per-camera 2-D tracking: link one camera's marker detections from frame to frame into tracks.

:func:`tracks_2d` works on an observations frame (the run folder's columns, contracts.md): frames are taken
in ``frame_index`` order within each recording segment (``segment`` and ``session`` columns when present;
a track never crosses a segment). Each frame's detections are assigned to the live tracks by an optimal
one-to-one assignment (``scipy.optimize.linear_sum_assignment``) on the distance to each track's predicted
position, within a gate:

- prediction: the track's last position and the constant-velocity extrapolation over the frames elapsed
  are both candidates, and the nearer one counts. Constant velocity follows smooth motion; the last
  position is better at a reversal of a fast oscillation (at 20 Hz and 60 fps the velocity changes by more
  than the step between frames), so taking the nearer keeps both kinds of motion inside a tight gate;
- dropped frames: the frames elapsed come from the time stamps (gap / median frame period), so a track
  survives ``max_gap_frames`` missing frames; its prediction spans the gap and the gate grows in
  proportion to the frames elapsed (the prediction error grows with the gap);
- duplicated frames (a camera repeating an image with the same time stamp, metrology notes §3): their
  observations get track id −1 and are not used (they carry no new information and would repeat an instant);
- tracks with fewer than ``min_length`` observations get −1 (spurious detections).

Units: pixels, seconds. Track ids are integers ≥ 0, unique within the frame given (over all segments).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

from rig.analysis_errors import AnalysisError

REQUIRED_COLUMNS = ("frame_index", "timestamp_s", "u_px", "v_px")
NOT_TRACKED = -1


def _positive(name: str, value: float) -> float:
    if isinstance(value, bool) or not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
        raise AnalysisError(f"{name}={value!r}: pass a positive finite number")
    return float(value)


def _is_int(value: object) -> bool:
    return not isinstance(value, bool) and isinstance(value, int | np.integer)


def check_observations(obs: pd.DataFrame, columns: tuple[str, ...] = REQUIRED_COLUMNS,
                       what: str = "observations") -> None:
    """Raise :class:`AnalysisError` naming the missing columns or the first non-finite value."""
    if not isinstance(obs, pd.DataFrame):
        raise AnalysisError(f"{what} must be a pandas DataFrame, got {type(obs).__name__}")
    missing = [c for c in columns if c not in obs.columns]
    if missing:
        raise AnalysisError(f"{what} lack column(s) {missing}; needed: {list(columns)}")
    for c in columns:
        values = obs[c].to_numpy(dtype=float)
        bad = ~np.isfinite(values)
        if bad.any():
            first = int(np.flatnonzero(bad)[0])
            raise AnalysisError(f"{what}: column {c!r} holds NaN or inf (first at row {first})")


def segment_keys(obs: pd.DataFrame) -> list[str]:
    """The grouping columns present: ``segment`` and ``session`` (a track never crosses them)."""
    return [c for c in ("segment", "session") if c in obs.columns]


def tracks_2d(
    obs: pd.DataFrame,
    *,
    gate_px: float = 25.0,
    max_gap_frames: int = 5,
    min_length: int = 3,
) -> pd.Series:
    """Track id per observation (a Series aligned with ``obs.index``, int64, −1 = not in a track).

    ``obs``: one camera's observations with ``frame_index``, ``timestamp_s`` (camera clock, s), ``u_px``,
    ``v_px`` (and optionally ``segment``/``session``). ``gate_px``: largest distance (px) from a track's
    prediction to a detection it may take — above the frame-to-frame prediction error of the motion,
    below half the image distance between markers. ``max_gap_frames``: frames a track may miss (dropped
    frames, a marker briefly lost) before it ends. ``min_length``: shortest track kept.
    """
    check_observations(obs)
    gate = _positive("gate_px", gate_px)
    if not _is_int(max_gap_frames) or max_gap_frames < 0:
        raise AnalysisError(f"max_gap_frames={max_gap_frames!r}: pass an integer ≥ 0")
    if not _is_int(min_length) or min_length < 1:
        raise AnalysisError(f"min_length={min_length!r}: pass an integer ≥ 1")
    out = pd.Series(np.full(len(obs), NOT_TRACKED, dtype=np.int64), index=obs.index, name="track_id")
    if len(obs) == 0:
        return out
    keys = segment_keys(obs)
    groups = obs.groupby(keys, sort=True, dropna=False).indices if keys else {None: np.arange(len(obs))}
    next_id = 0
    ids = out.to_numpy().copy()
    for _, positions in sorted(groups.items(), key=lambda kv: int(kv[1].min())):
        labels, n = _track_group(obs.iloc[positions], gate, int(max_gap_frames), int(min_length))
        ids[positions] = np.where(labels >= 0, labels + next_id, NOT_TRACKED)
        next_id += n
    out[:] = ids
    return out


def _track_group(obs: pd.DataFrame, gate: float, max_gap: int, min_length: int) -> tuple[np.ndarray, int]:
    """Labels (local ids ≥ 0 or −1) for one segment's observations, and the number of ids used."""
    frame = obs["frame_index"].to_numpy(np.int64)
    stamp = obs["timestamp_s"].to_numpy(float)
    uv = obs[["u_px", "v_px"]].to_numpy(float)
    order = np.lexsort((np.arange(len(frame)), frame))
    frames, starts = np.unique(frame[order], return_index=True)
    bounds = np.append(starts, len(order))
    frame_stamps = stamp[order][starts]
    steps = np.diff(frame_stamps)
    period = float(np.median(steps[steps > 0])) if np.any(steps > 0) else 1.0
    labels = np.full(len(frame), NOT_TRACKED, dtype=np.int64)
    # live tracks: id, last position, velocity (px per frame period), slot (frame count) of the last hit
    ids: list[int] = []
    last: list[np.ndarray] = []
    vel: list[np.ndarray] = []
    slot: list[float] = []
    n_ids = 0
    prev_stamp = -np.inf
    for k in range(len(frames)):
        rows = order[bounds[k]:bounds[k + 1]]
        now = frame_stamps[k]
        if now <= prev_stamp:  # duplicated frame (same time stamp again) or a stamp going backwards
            continue
        prev_stamp = now
        s_now = now / period
        alive = [i for i in range(len(ids)) if s_now - slot[i] <= max_gap + 1.5]
        ids, last, vel, slot = ([x[i] for i in alive] for x in (ids, last, vel, slot))
        det = uv[rows]
        assigned = np.full(len(rows), -1)
        if ids:
            L = np.array(last)
            gap = s_now - np.array(slot)
            pred = L + np.array(vel) * gap[:, None]
            d_last = np.linalg.norm(det[None, :, :] - L[:, None, :], axis=2)
            d_pred = np.linalg.norm(det[None, :, :] - pred[:, None, :], axis=2)
            cost = np.minimum(d_last, d_pred)
            feasible = cost <= gate * np.maximum(gap, 1.0)[:, None]  # the prediction error grows with the gap
            if feasible.any():
                big = float(np.max(np.where(feasible, cost, 0.0))) ** 2 * (min(cost.shape) + 1.0) + 1.0
                r, c = linear_sum_assignment(np.where(feasible, cost**2, big))
                for ti, di in zip(r, c, strict=True):
                    if feasible[ti, di]:
                        assigned[di] = ti
                        vel[ti] = (det[di] - last[ti]) / max(gap[ti], 1e-9)
                        last[ti] = det[di]
                        slot[ti] = s_now
        for di in range(len(rows)):
            if assigned[di] < 0:
                ids.append(n_ids)
                last.append(det[di])
                vel.append(np.zeros(2))
                slot.append(s_now)
                assigned[di] = len(ids) - 1
                n_ids += 1
            labels[rows[di]] = ids[assigned[di]]
    # drop short tracks, renumber by first appearance
    tracked = labels >= 0
    uniq, counts = np.unique(labels[tracked], return_counts=True)
    keep = set(uniq[counts >= min_length].tolist())
    first_pos = {}
    for pos in order:
        lab = labels[pos]
        if lab in keep and lab not in first_pos:
            first_pos[lab] = len(first_pos)
    return np.array([first_pos.get(lab, NOT_TRACKED) for lab in labels], dtype=np.int64), len(first_pos)
