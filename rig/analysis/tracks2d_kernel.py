"""The usual frame of :mod:`rig.analysis.tracks2d`, compiled (numba): every live track's simple prediction
(its last position or its constant-velocity extrapolation) has the one detection it continues within the
gate, and every detection has one track. Such frames are most of a record; each costs ≈ 40 µs as numpy
calls on a few rows and ≈ 2.5 µs here (a 20-s 1080p benchmark video's 1,200 frames: 0.051 → 0.003 CPU-s).

Every number is computed with the floating-point operations of the numpy expressions in
:class:`rig.analysis.tracks2d._LiveTracks` (the same terms in the same order), so the labels are those of
the frame-by-frame path (tests/test_analysis_tracks2d.py: the costs, the frames taken and the step on, to
the bit, and the labels of random scenes). Any other frame — a track ended or started, a
prediction missing, a detection with two candidates — goes back to that path.

Imported by :func:`rig.analysis.tracks2d.tracks_2d` when it first tracks (numba is loaded then); compiled
once into numba's on-disk cache (:mod:`rig.warm_kernels`).
"""

from __future__ import annotations

import numpy as np

from rig.stereo.markers_kernel import jit_kernel


@jit_kernel
def _distance(point_u: float, point_v: float, centre_u: float, centre_v: float) -> float:
    """|point − centre| (px) as ``tracks2d._distances`` computes it."""
    du, dv = point_u - centre_u, point_v - centre_v
    return float(np.sqrt(du * du + dv * dv))


@jit_kernel
def simple_costs(  # noqa: PLR0917 (numba: no keyword-only arguments)
        det: np.ndarray, s_now: float, last: np.ndarray, prev: np.ndarray, s_last: np.ndarray,
        s_prev: np.ndarray, cost: np.ndarray) -> None:
    """``cost[t, j]`` ← the distance (px) of detection j from track t's nearer simple prediction, its last
    position or its constant-velocity extrapolation to ``s_now`` (frame slots): the first ``cost`` of
    :meth:`rig.analysis.tracks2d._LiveTracks.assign`, to the bit."""
    for t in range(last.shape[0]):
        gap = s_now - s_last[t]
        step = max(s_last[t] - s_prev[t], 1e-9)
        pred_u = last[t, 0] + (last[t, 0] - prev[t, 0]) / step * gap
        pred_v = last[t, 1] + (last[t, 1] - prev[t, 1]) / step * gap
        for j in range(det.shape[0]):
            cost[t, j] = min(_distance(det[j, 0], det[j, 1], last[t, 0], last[t, 1]),
                             _distance(det[j, 0], det[j, 1], pred_u, pred_v))


@jit_kernel
def assign_one_to_one(cost: np.ndarray, gaps: np.ndarray, gate: float, assigned: np.ndarray) -> bool:
    """``assigned[j]`` ← the track whose simple prediction is detection j's only candidate, from the
    :func:`simple_costs` ``cost`` (px) and each track's frames elapsed ``gaps``; False (``assigned``
    undefined) unless every track's nearest detection lies within 0.2 × ``gate`` (px: else the periodic and
    circle predictions are tried), each track and detection has at most one candidate within the gate (× the
    frames elapsed, at least 1) and every detection has one (else tracks start or the optimal assignment
    chooses)."""
    n_tracks, n_det = cost.shape
    assigned[:n_det] = -1
    for t in range(n_tracks):
        reach = gate * max(gaps[t], 1.0)  # the prediction error grows with the gap
        nearest = np.inf
        candidate = -1
        for j in range(n_det):
            nearest = min(nearest, cost[t, j])
            if cost[t, j] <= reach:
                if candidate >= 0 or assigned[j] >= 0:
                    return False
                candidate = j
        if not nearest <= 0.2 * gate:
            return False
        if candidate >= 0:
            assigned[candidate] = t
    return bool((assigned[:n_det] >= 0).all())


@jit_kernel
def advance(  # noqa: PLR0917 (numba: no keyword-only arguments)
        det: np.ndarray, rows: np.ndarray, s_now: float, assigned: np.ndarray, ids: np.ndarray,
        recent_slots: np.ndarray, recent_px: np.ndarray, known: np.ndarray, last: np.ndarray,
        prev: np.ndarray, s_last: np.ndarray, s_prev: np.ndarray, labels: np.ndarray) -> None:
    """Each track moves on to the detection assigned to it (``_LiveTracks.advance`` with every detection
    taken); ``labels[rows[j]]`` ← its id."""
    history = recent_slots.shape[1]
    for j in range(det.shape[0]):
        t = assigned[j]
        for h in range(history - 1):  # one frame older
            recent_slots[t, h] = recent_slots[t, h + 1]
            recent_px[t, h, 0], recent_px[t, h, 1] = recent_px[t, h + 1, 0], recent_px[t, h + 1, 1]
        recent_slots[t, history - 1] = s_now
        recent_px[t, history - 1, 0], recent_px[t, history - 1, 1] = det[j, 0], det[j, 1]
        known[t] = min(known[t] + 1, history)
        prev[t, 0], prev[t, 1], s_prev[t] = last[t, 0], last[t, 1], s_last[t]
        last[t, 0], last[t, 1], s_last[t] = det[j, 0], det[j, 1], s_now
        labels[rows[j]] = ids[t]


@jit_kernel
def easy_frames(  # noqa: PLR0917 (numba: no keyword-only arguments)
        k: int, prev_stamp: float, order: np.ndarray, bounds: np.ndarray, uv: np.ndarray,
        frame_stamps: np.ndarray, period: float, gate: float, max_gap: int, tracks: tuple[np.ndarray, ...],
        labels: np.ndarray) -> tuple[int, float]:
    """Frames ``k``, ``k`` + 1, … of a segment tracked in place while each is easy (module docstring); a frame
    stamped at or before ``prev_stamp`` (the last tracked frame's stamp, s) is skipped, as
    ``tracks2d._track_group`` skips it. Returns (the first frame not tracked — the number of frames when all
    were —, the last tracked frame's stamp). ``order``, ``bounds``, ``uv``, ``frame_stamps``, ``period``,
    ``gate``, ``max_gap``: as in ``_track_group``; ``tracks``: the live tracks' arrays (ids, recent_slots,
    recent_px, known, last, prev, s_last, s_prev), changed in place."""
    ids, recent_slots, recent_px, known, last, prev, s_last, s_prev = tracks
    n_tracks = ids.shape[0]
    assigned = np.empty(n_tracks, np.int64)
    det = np.empty((n_tracks, 2))
    cost = np.empty((n_tracks, n_tracks))
    gaps = np.empty(n_tracks)
    while k < frame_stamps.shape[0]:
        now = frame_stamps[k]
        if now <= prev_stamp:  # a duplicated frame or a stamp going backwards
            k += 1
            continue
        s_now = now / period
        for t in range(n_tracks):
            gaps[t] = s_now - s_last[t]
            if not gaps[t] <= max_gap + 1.5:
                return k, prev_stamp  # a track ends
        rows = order[bounds[k]:bounds[k + 1]]
        if n_tracks == 0 or rows.shape[0] != n_tracks:
            return k, prev_stamp  # tracks start or miss a detection
        for j in range(n_tracks):
            det[j, 0], det[j, 1] = uv[rows[j], 0], uv[rows[j], 1]
        simple_costs(det, s_now, last, prev, s_last, s_prev, cost)
        if not assign_one_to_one(cost, gaps, gate, assigned):
            return k, prev_stamp
        prev_stamp = now
        advance(det, rows, s_now, assigned, ids, recent_slots, recent_px, known, last, prev, s_last, s_prev,
                 labels)
        k += 1
    return k, prev_stamp
