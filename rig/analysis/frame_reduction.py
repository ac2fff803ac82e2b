"""Frames → marker observations, one frame at a time: the reduction shared by live recordings and video files.

:class:`MarkerReducer` keeps the state of one camera stream: the first frame is searched whole
(:func:`rig.stereo.detect_markers`), later frames only in a window around each marker's last position
(:func:`rig.stereo.track_markers`), with a whole-frame search again when a marker is lost and every
``redetect_every`` frames (markers entering the view). A marker that moved more than a quarter window in
the last frame (a rotor, ≈ 100 px per frame at 10 Hz) is searched where the circle through its last three
positions puts it (:func:`rig.analysis.tracks2d.circle_prediction`), so it is followed in its window rather
than
found by a whole-frame search every frame. ``mode="detect"`` searches every frame whole. Each marker gets a
``track_2d`` number that it keeps while it is followed; a whole-frame detection hands the previous numbers
on to the detections within half a window of where each was expected (one-to-one, Hungarian assignment),
new markers get new numbers (a fast marker's first frames, before its motion is known, included: the 2-D
tracking of :mod:`rig.analysis.tracks2d` joins them).

Used by :mod:`rig.run.acquire` (cameras of the rig, reduced while recording) and
:mod:`rig.deploy.video_markers` (video files of a deployment).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import linear_sum_assignment

from rig.analysis.reduce_options import DETECT_ONLY_KEYS, TRACK_KEYS, ReduceOptions, track_options
from rig.analysis.tracks2d import circle_prediction
from rig.stereo import FLAG_LOST, detect_markers, track_markers
from rig.stereo.markers_kernel import jit_kernel

__all__ = ["DETECT_ONLY_KEYS", "TRACK_KEYS", "MarkerReducer", "ReduceOptions", "track_options", "warm_up"]

#: distance (px) within which a lone leftover marker continues its motion history across a whole-frame search
ACQUIRE_PX = 150.0


@jit_kernel  # one compiled call per frame: each numpy call costs tens of µs after a frame's decoding
def _last_positions(hist: np.ndarray, depth: np.ndarray, quarter_window_px: float,
                    max_uv_px: tuple[float, float], out: np.ndarray) -> int:
    """``out`` ← each marker's last position ``hist[:, 2]`` clipped to [0, ``max_uv_px``] px (as ``np.clip``);
    returns how many of them moved more than ``quarter_window_px`` in the last frame (a NaN step counts) with
    two positions known or more: those need their motion model (:meth:`MarkerReducer._predicted`)."""
    fast = 0
    max_u_px, max_v_px = max_uv_px
    for j in range(hist.shape[0]):
        du, dv = hist[j, 2, 0] - hist[j, 1, 0], hist[j, 2, 1] - hist[j, 1, 1]
        if depth[j] >= 2 and not math.sqrt(du * du + dv * dv) <= quarter_window_px:
            fast += 1
        u, v = hist[j, 2, 0], hist[j, 2, 1]
        out[j, 0] = max_u_px if u > max_u_px else (0.0 if u <= 0.0 else u)  # NaN stays NaN
        out[j, 1] = max_v_px if v > max_v_px else (0.0 if v <= 0.0 else v)
    return fast


@jit_kernel
def _follow(hist: np.ndarray, depth: np.ndarray, tracked: np.ndarray, lost_flag: int) -> bool:
    """When no row of ``tracked`` (``MARKER_DTYPE``, one per marker, in order) has ``lost_flag``: each
    marker's history moves on by one in place (``hist`` (n, 3, 2) px, ``depth`` ≤ 3 positions known) and
    True; else False, nothing changed."""
    for j in range(tracked.shape[0]):
        if tracked[j].flags & lost_flag:
            return False
    for j in range(tracked.shape[0]):
        hist[j, 0, 0], hist[j, 0, 1] = hist[j, 1, 0], hist[j, 1, 1]
        hist[j, 1, 0], hist[j, 1, 1] = hist[j, 2, 0], hist[j, 2, 1]
        hist[j, 2, 0], hist[j, 2, 1] = tracked[j].u_px, tracked[j].v_px
        depth[j] = min(depth[j] + 1, 3)
    return True


class MarkerReducer:
    """Per camera stream (and segment): frame → marker rows (``MARKER_DTYPE``) and their ``track_2d`` numbers.

    first_id: the number the first new marker gets (continue a segment over several recordings).
    """

    def __init__(self, options: ReduceOptions, first_id: int = 0) -> None:
        self.options = options
        self._track_kw = track_options(options.detect)
        self._ids = np.empty(0, dtype=np.int64)
        self._next_id = int(first_id)
        self._since_detect = 0
        # the last three positions of each marker of the last frame (oldest first, (n, 3, 2) px; the last
        # frame's positions are ``_hist[:, 2]``), of which the last ``_depth`` are known: arrays, not lists of
        # rows (a frame's Python is microseconds per marker, tens after a frame's decoding)
        self._hist = np.zeros((0, 3, 2))
        self._depth = np.zeros(0, dtype=np.int64)
        self.whole_frame_searches = 0  # frames searched whole (the costly path), for diagnostics

    @property
    def next_id(self) -> int:
        """The number the next new marker gets (continue from it in a later recording of the segment)."""
        return self._next_id

    def _predicted(self, shape: tuple[int, ...]) -> np.ndarray:
        """Where each followed marker should be in this frame: its last position, or — when it moved more
        than a quarter window in the last frame (a rotor, ≈ 100 px per frame at 10 Hz) — the circle through
        its last three positions turned on by the same angle (constant velocity if they are collinear)."""
        out = np.empty((len(self._hist), 2))
        limits = (float(shape[1] - 1), float(shape[0] - 1))
        if _last_positions(self._hist, self._depth, self.options.window_px / 4, limits, out):
            h = self._hist  # markers that moved fast (a rotor): their motion model, in Python
            step = h[:, 2] - h[:, 1]
            moved = np.sqrt(step[:, 0] * step[:, 0] + step[:, 1] * step[:, 1])
            for j in np.flatnonzero((self._depth >= 2) & ~(moved <= self.options.window_px / 4)).tolist():
                p = circle_prediction([0.0, 1.0, 2.0], list(h[j]), 3.0) if self._depth[j] == 3 else None
                out[j] = p if p is not None else 2 * h[j, 2] - h[j, 1]
            np.clip(out, 0, limits, out=out)
        return out

    def _associate(self, found: np.ndarray, predicted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For whole-frame detections: (track numbers, previous row continued or −1). A detection within half
        a window of a marker's predicted position keeps its number; among the markers left on both sides, a
        previous one and a detection within ``ACQUIRE_PX`` of each other, each the other's only candidate
        there, are linked for the motion model only (a fast marker whose motion is not known yet: it gets a
        new number now, and keeps the next one once its motion predicts it); else new."""
        ids = np.full(len(found), -1, dtype=np.int64)
        links = np.full(len(found), -1, dtype=np.int64)
        uv = np.c_[found["u_px"], found["v_px"]]
        if len(predicted) and len(uv):
            cost = np.linalg.norm(uv[:, None, :] - predicted[None, :, :], axis=2)
            r, c = linear_sum_assignment(cost)
            ok = cost[r, c] <= self.options.window_px / 2
            ids[r[ok]] = self._ids[c[ok]]
            links[r[ok]] = c[ok]
            free_d = np.flatnonzero(ids < 0)
            free_p = np.setdiff1d(np.arange(len(predicted)), c[ok])
            near = cost[np.ix_(free_d, free_p)] <= ACQUIRE_PX
            lone = near & (near.sum(axis=1) == 1)[:, None] & (near.sum(axis=0) == 1)[None, :]
            for di, pi in zip(*np.nonzero(lone), strict=True):
                links[free_d[di]] = free_p[pi]
        new = ids < 0
        ids[new] = np.arange(self._next_id, self._next_id + int(new.sum()))
        self._next_id += int(new.sum())
        return ids, links

    def reduce(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Marker rows of one 2-D uint8 frame (in stream order) and their ``track_2d`` numbers (int64)."""
        opts = self.options
        predicted = self._predicted(image.shape)
        if opts.mode == "track" and len(predicted) and self._since_detect < opts.redetect_every:
            tracked = track_markers(image, predicted, window_px=opts.window_px, **self._track_kw)
            if _follow(self._hist, self._depth, tracked, FLAG_LOST):  # every marker followed
                self._since_detect += 1
                return tracked, self._ids
        found = detect_markers(image, **opts.detect)
        self.whole_frame_searches += 1
        ids, links = self._associate(found, predicted)
        self._since_detect = 1
        self._restart(found, ids, links)
        return found, ids

    def _restart(self, found: np.ndarray, ids: np.ndarray, links: np.ndarray) -> None:
        """After a whole-frame search: the history of the detections that continue a marker of the last frame
        (``links`` ≥ 0: its row) goes on, the others start one."""
        hist = np.zeros((len(found), 3, 2))
        depth = np.ones(len(found), dtype=np.int64)
        kept = links >= 0
        hist[kept, :2] = self._hist[links[kept], 1:]
        depth[kept] = np.minimum(self._depth[links[kept]] + 1, 3)
        hist[:, 2, 0], hist[:, 2, 1] = found["u_px"], found["v_px"]
        self._ids, self._hist, self._depth = ids, hist, depth


def warm_up(options: ReduceOptions) -> None:
    """Load (or compile) the marker kernels before a camera runs: reduce two frames of a synthetic bright
    disc (detection, then tracking) through a throwaway reducer. The first call of the compiled kernels
    costs 0.5 s from numba's disk cache and 20–30 s of CPU without it — long enough, inside a live
    recording, to fill a camera's bounded queue and lose its first frames."""
    yy, xx = np.mgrid[0:96, 0:96]
    frame = np.where((xx - 48.0) ** 2 + (yy - 48.0) ** 2 <= 36.0, 220, 30).astype(np.uint8)
    reducer = MarkerReducer(options)
    for _ in range(2):
        reducer.reduce(frame)
