"""Per-camera 2-D tracking: link one camera's marker detections from frame to frame into tracks.

:func:`tracks_2d` works on an observations frame (the run folder's columns, contracts.md): frames are taken
in ``frame_index`` order within each recording segment (``segment`` and ``session`` columns when present;
a track never crosses a segment). Each frame's detections are assigned to the live tracks by an optimal
one-to-one assignment (``scipy.optimize.linear_sum_assignment``) on the distance to each track's predicted
position, within a gate:

- prediction: the track's last position, the constant-velocity extrapolation and, once the track has
  ``AR_MIN`` consecutive frames, the linear recurrence of a sinusoid x_{k+1} = λ·x_k − x_{k−1} + d fitted to
  its recent frames (exact for an oscillation or a rotation at one frequency and for straight uniform
  motion) are candidates, and the nearest counts. The recurrence follows a 10 Hz rotor whose marker
  moves 60° (≈ 100 px) per frame, where any polynomial prediction is off by the radius; the last
  position is best for a still marker. A track young or fast enough that every prediction misses takes a
  detection up to ``acquire_gate_px`` away when the two are each other's only candidate within it;
- dropped frames: the frames elapsed come from the time stamps (gap / median frame period), so a track
  survives ``max_gap_frames`` missing frames; its prediction spans the gap and the gate grows in
  proportion to the frames elapsed (the prediction error grows with the gap);
- duplicated frames (a camera repeating an image with the same time stamp, metrology notes §3): their
  observations get track id −1 and are not used (they carry no new information and would repeat an instant);
- tracks with fewer than ``min_length`` observations get −1 (spurious detections).

The usual frame — each track's last position or constant-velocity extrapolation has its one detection
within the gate, one to one — is tracked by compiled code (:mod:`rig.analysis.tracks2d_kernel`, the same
labels); the others as above.

Units: pixels, seconds. Track ids are integers ≥ 0, unique within the frame given (over all segments).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

from rig.analysis.errors import AnalysisError

__all__ = ["NOT_TRACKED", "REQUIRED_COLUMNS", "check_observations", "circle_prediction", "segment_keys",
           "tracks_2d"]

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
    acquire_gate_px: float = 150.0,
    max_gap_frames: int = 5,
    min_length: int = 2,
) -> pd.Series:
    """Track id per observation (a Series aligned with ``obs.index``, int64, −1 = not in a track).

    ``obs``: one camera's observations with ``frame_index``, ``timestamp_s`` (camera clock, s), ``u_px``,
    ``v_px`` (and optionally ``segment``/``session``). ``gate_px``: largest distance (px) from a track's
    prediction to a detection it may take — above the frame-to-frame prediction error of the motion,
    below half the image distance between markers. ``acquire_gate_px``: a track whose predictions miss
    every detection still takes a detection within this distance of its last position when each is the
    other's only candidate there (a lone fast marker, e.g. a 10 Hz rotor moving ~100 px per frame before its
    periodic prediction is established). ``max_gap_frames``: frames a track may miss (dropped
    frames, a marker briefly lost) before it ends. ``min_length``: shortest track kept.
    """
    check_observations(obs)
    gate = _positive("gate_px", gate_px)
    acquire = _positive("acquire_gate_px", acquire_gate_px)
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
        labels, n = _track_group(obs.iloc[positions], gate, int(max_gap_frames), int(min_length), acquire)
        ids[positions] = np.where(labels >= 0, labels + next_id, NOT_TRACKED)
        next_id += n
    out[:] = ids
    return out


HISTORY = 10  # positions kept per track for the prediction
AR_MIN = 5  # consecutive frames needed before the periodic (AR(2)) prediction is used


def _periodic_prediction(slots: list[float], pos: list[np.ndarray], s_now: float) -> np.ndarray | None:
    """After ``AR_MIN`` consecutive frames, the linear recurrence of a sinusoid (or of a straight line):
    x_{k+1} + x_{k−1} = λ·x_k + d, λ = 2 cos(2πf/fs) and d fitted to the track's recent frames; else None."""
    gap = s_now - slots[-1]
    run = 1
    while run < len(slots) and round(slots[-run] - slots[-run - 1]) == 1:
        run += 1
    if run >= AR_MIN:
        P = np.asarray(pos[-run:])
        m = run - 2
        A = np.zeros((2 * m, 3))
        A[:m, 0], A[m:, 0] = P[1:-1, 0], P[1:-1, 1]
        A[:m, 1] = A[m:, 2] = 1.0
        b = np.concatenate([P[2:, 0] + P[:-2, 0], P[2:, 1] + P[:-2, 1]])
        N = A.T @ A
        if abs(np.linalg.det(N)) <= 1e-9 * max(np.trace(N), 1e-300) ** 3:
            return None  # a still marker: the recurrence is undetermined (and not needed)
        lam, du, dv = np.linalg.solve(N, A.T @ b)
        prev, cur = P[-2], P[-1]
        for _ in range(max(1, min(round(gap), 50))):
            prev, cur = cur, lam * cur - prev + np.array([du, dv])
        return cur
    return None


def circle_prediction(slots: list[float], pos: list[np.ndarray], s_now: float) -> np.ndarray | None:
    """From the last three positions on consecutive frames: the circle through them, turned on by the same
    angle per frame (a rotor before the periodic prediction has frames enough); None if they are not on a
    turning circle (collinear, or the two angle steps disagree by more than 20 %)."""
    if len(pos) < 3 or round(slots[-1] - slots[-2]) != 1 or round(slots[-2] - slots[-3]) != 1:
        return None
    a, b, c = (np.asarray(p, float) for p in pos[-3:])
    d = 2.0 * ((a[0] - c[0]) * (b[1] - c[1]) - (b[0] - c[0]) * (a[1] - c[1]))
    span = max(np.linalg.norm(b - a), np.linalg.norm(c - b))
    if abs(d) <= 1e-6 * span**2:
        return None
    a2, b2 = a - c, b - c
    centre = c + np.array([(b2[1] * (a2 @ a2) - a2[1] * (b2 @ b2)),
                           (a2[0] * (b2 @ b2) - b2[0] * (a2 @ a2))]) / d
    ang = [math.atan2(*(p - centre)[::-1]) for p in (a, b, c)]
    step1 = (ang[1] - ang[0] + math.pi) % (2 * math.pi) - math.pi
    step2 = (ang[2] - ang[1] + math.pi) % (2 * math.pi) - math.pi
    if step1 * step2 <= 0 or abs(step2 - step1) > 0.2 * abs(step2):
        return None
    turn = step2 * (s_now - slots[-1])
    rot = np.array([[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]])
    return centre + rot @ (c - centre)


def _acquire(assigned: np.ndarray, det: np.ndarray, last: np.ndarray, acquire_gate: float) -> None:
    """Tracks and detections the gated assignment left over: a track takes a detection within
    ``acquire_gate`` of its last position (``last``: each live track's, px) when, among the leftovers, each
    is the other's only candidate (a lone fast marker before its motion model has frames enough; the still
    markers around it were taken by their own tracks first)."""
    free_d = np.flatnonzero(assigned < 0)
    free_t = np.setdiff1d(np.arange(len(last)), assigned[assigned >= 0])
    if not len(free_t):
        return
    near = _distances(det[free_d], last[free_t]) <= acquire_gate
    lone = near & (near.sum(axis=1) == 1)[:, None] & (near.sum(axis=0) == 1)[None, :]
    for ti, di in zip(*np.nonzero(lone), strict=True):
        assigned[free_d[di]] = free_t[ti]


def _distances(points: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """(len(centres), len(points)) distances (px) of 2-D ``points`` from each of ``centres``: the numbers of
    ``np.linalg.norm(points[None] - centres[:, None], axis=2)`` without its generality."""
    d = points[None, :, :] - centres[:, None, :]
    return np.sqrt(np.add.reduce(d * d, axis=2))


class _LiveTracks:
    """The live tracks of one segment: ids; the last ``HISTORY`` frame slots (time stamp / frame period) and
    positions (px) of each, right-aligned (the last ``known`` of them are filled); and each track's last two
    positions and slots (the second-last: the last again and one slot earlier for a new track)."""

    def __init__(self) -> None:
        self.ids = np.empty(0, np.int64)
        self.recent_slots, self.recent_px = np.empty((0, HISTORY)), np.empty((0, HISTORY, 2))
        self.known = np.empty(0, np.int64)
        self.last, self.prev = np.empty((0, 2)), np.empty((0, 2))
        self.s_last, self.s_prev = np.empty(0), np.empty(0)
        self.next_id = 0

    def _keep(self, rows: np.ndarray) -> None:
        self.ids, self.known = self.ids[rows], self.known[rows]
        self.last, self.prev = self.last[rows], self.prev[rows]
        self.recent_slots, self.recent_px = self.recent_slots[rows], self.recent_px[rows]
        self.s_last, self.s_prev = self.s_last[rows], self.s_prev[rows]

    def end_lost(self, s_now: float, max_gap: int) -> None:
        """Drop the tracks that missed more than ``max_gap`` frames (most frames: none)."""
        alive = s_now - self.s_last <= max_gap + 1.5
        if not alive.all():
            self._keep(np.flatnonzero(alive))

    def history(self, row: int) -> tuple[list[float], list[np.ndarray]]:
        """Track ``row``'s known slots and positions, oldest first (the predictions' arguments)."""
        first = HISTORY - int(self.known[row])
        return self.recent_slots[row, first:].tolist(), list(self.recent_px[row, first:])

    def assign(self, det: np.ndarray, s_now: float, gate: float, acquire_gate: float) -> np.ndarray:
        """The live track (row) each detection of ``det`` (px) continues, −1 for none: the gated optimal
        assignment on the distance to the nearest prediction, then :func:`_acquire`."""
        assigned = np.full(len(det), -1)
        if not len(self.ids):
            return assigned
        gap = s_now - self.s_last
        velocity = (self.last - self.prev) / np.maximum(self.s_last - self.s_prev, 1e-9)[:, None]  # px/period
        cost = np.minimum(_distances(det, self.last), _distances(det, self.last + velocity * gap[:, None]))
        for ti in np.flatnonzero(cost.min(axis=1) > 0.2 * gate).tolist():  # simple predictions miss
            for model in (_periodic_prediction, circle_prediction):
                predicted = model(*self.history(ti), s_now)
                if predicted is not None:
                    cost[ti] = np.minimum(cost[ti], np.linalg.norm(det - predicted, axis=1))
        feasible = cost <= gate * np.maximum(gap, 1.0)[:, None]  # the prediction error grows with the gap
        if feasible.sum(axis=0).max() <= 1 and feasible.sum(axis=1).max() <= 1:
            # each track and detection has at most one candidate (the usual frame): those pairs are what the
            # assignment below chooses (it takes as many feasible pairs as it can, and there is one way)
            r, c = np.nonzero(feasible)
            assigned[c] = r
        else:
            big = float(np.max(np.where(feasible, cost, 0.0))) ** 2 * (min(cost.shape) + 1.0) + 1.0
            r, c = linear_sum_assignment(np.where(feasible, cost**2, big))
            ok = feasible[r, c]
            assigned[c[ok]] = r[ok]
        if acquire_gate > gate and (assigned < 0).any():
            _acquire(assigned, det, self.last, acquire_gate)
        return assigned

    def advance(self, assigned: np.ndarray, det: np.ndarray, s_now: float) -> np.ndarray:
        """The assigned tracks move on to their detections, the other detections start tracks; returns the
        track id of each detection."""
        taken = assigned >= 0
        rows = assigned[taken]
        self.recent_slots[rows, :-1] = self.recent_slots[rows, 1:]  # one frame older
        self.recent_px[rows, :-1] = self.recent_px[rows, 1:]
        self.recent_slots[rows, -1], self.recent_px[rows, -1] = s_now, det[taken]
        self.known[rows] = np.minimum(self.known[rows] + 1, HISTORY)
        self.prev[rows], self.s_prev[rows] = self.last[rows], self.s_last[rows]
        self.last[rows], self.s_last[rows] = det[taken], s_now
        if taken.all():
            return self.ids[assigned]
        new = ~taken
        count = int(new.sum())
        assigned = assigned.copy()
        assigned[new] = np.arange(len(self.ids), len(self.ids) + count)
        slots, px = np.zeros((count, HISTORY)), np.zeros((count, HISTORY, 2))
        slots[:, -1], px[:, -1] = s_now, det[new]
        self.recent_slots = np.concatenate([self.recent_slots, slots])
        self.recent_px = np.concatenate([self.recent_px, px])
        self.known = np.concatenate([self.known, np.ones(count, np.int64)])
        self.ids = np.concatenate([self.ids, np.arange(self.next_id, self.next_id + count)])
        self.next_id += count
        self.last, self.prev = np.concatenate([self.last, det[new]]), np.concatenate([self.prev, det[new]])
        self.s_last = np.concatenate([self.s_last, np.full(count, s_now)])
        self.s_prev = np.concatenate([self.s_prev, np.full(count, s_now - 1.0)])
        return self.ids[assigned]

    def arrays(self) -> tuple[np.ndarray, ...]:
        """The arrays :func:`rig.analysis.tracks2d_kernel.easy_frames` changes in place."""
        return (self.ids, self.recent_slots, self.recent_px, self.known, self.last, self.prev, self.s_last,
                self.s_prev)


def _track_group(obs: pd.DataFrame, gate: float, max_gap: int, min_length: int,
                 acquire_gate: float, *, compiled: bool = True) -> tuple[np.ndarray, int]:
    """Labels (local ids ≥ 0 or −1) for one segment's observations, and the number of ids used.
    ``compiled``: the usual frames by :func:`rig.analysis.tracks2d_kernel.easy_frames` (the same labels;
    False: every frame by :class:`_LiveTracks`, which the tests compare it with)."""
    from rig.analysis.tracks2d_kernel import easy_frames  # numba: loaded by the first tracking

    frame = obs["frame_index"].to_numpy(np.int64)
    stamp = obs["timestamp_s"].to_numpy(float)
    uv = np.ascontiguousarray(obs[["u_px", "v_px"]].to_numpy(float))
    order = np.lexsort((np.arange(len(frame)), frame))
    frames, starts = np.unique(frame[order], return_index=True)
    bounds = np.append(starts, len(order))
    frame_stamps = stamp[order][starts]
    steps = np.diff(frame_stamps)
    period = float(np.median(steps[steps > 0])) if np.any(steps > 0) else 1.0
    labels = np.full(len(frame), NOT_TRACKED, dtype=np.int64)
    live = _LiveTracks()
    prev_stamp = -np.inf
    k = 0
    while k < len(frames):
        if compiled:
            k, prev_stamp = easy_frames(k, prev_stamp, order, bounds, uv, frame_stamps, period, gate, max_gap,
                                        live.arrays(), labels)
            if k == len(frames):
                break
        rows = order[bounds[k]:bounds[k + 1]]
        now = frame_stamps[k]
        k += 1
        if now <= prev_stamp:  # duplicated frame (same time stamp again) or a stamp going backwards
            continue
        prev_stamp = now
        s_now = now / period
        live.end_lost(s_now, max_gap)
        det = uv[rows]
        labels[rows] = live.advance(live.assign(det, s_now, gate, acquire_gate), det, s_now)
    return _renumbered(labels, order, min_length)


def _renumbered(labels: np.ndarray, order: np.ndarray, min_length: int) -> tuple[np.ndarray, int]:
    """``labels`` with the tracks shorter than ``min_length`` dropped (−1) and the others numbered 0, 1, …
    by first appearance in ``order``; and how many are left."""
    ids, counts = np.unique(labels[labels >= 0], return_counts=True)
    in_order = labels[order]
    kept = in_order[np.isin(in_order, ids[counts >= min_length])]
    first_ids, first_at = np.unique(kept, return_index=True)
    number = np.full(int(labels.max(initial=NOT_TRACKED)) + 2, NOT_TRACKED, dtype=np.int64)  # [−1]: −1
    number[first_ids[np.argsort(first_at)]] = np.arange(len(first_ids))
    return number[labels], len(first_ids)
