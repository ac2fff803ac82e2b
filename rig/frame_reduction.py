"""Frames → marker observations, one frame at a time: the reduction shared by live recordings and video files.

:class:`MarkerReducer` keeps the state of one camera stream: the first frame is searched whole
(:func:`rig.stereo.detect_markers`), later frames only in a window around each marker's last position
(:func:`rig.stereo.track_markers`), with a whole-frame search again when a marker is lost and every
``redetect_every`` frames (markers entering the view). ``mode="detect"`` searches every frame whole (fast
motion such as the rotor, ≈ 100 px per frame). Each marker gets a ``track_2d`` number that it keeps while
it is followed; a whole-frame detection hands the previous numbers on to the detections within half a
window (one-to-one, Hungarian assignment), new markers get new numbers.

Used by :mod:`procedures._acquire` (cameras of the rig, reduced while recording) and
:mod:`rig.video_markers` (video files of a deployment).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from rig.stereo import FLAG_LOST, detect_markers, track_markers

__all__ = ["DETECT_ONLY_KEYS", "TRACK_KEYS", "MarkerReducer", "ReduceOptions", "track_options"]

#: keyword options that both :func:`detect_markers` and :func:`track_markers` take
TRACK_KEYS = ("polarity", "min_area_px", "max_area_px", "min_roundness", "min_contrast", "centre",
              "max_skewness", "outline_check", "max_edge_rms_px")
#: keyword options of :func:`detect_markers` only (whole-frame search); not passed to the tracker
DETECT_ONLY_KEYS = ("threshold", "roi", "downsample", "require")


def track_options(detect: dict[str, Any]) -> dict[str, Any]:
    """The part of ``detect`` (options of :func:`detect_markers`) that :func:`track_markers` accepts."""
    return {k: v for k, v in detect.items() if k in TRACK_KEYS}


@dataclass(frozen=True)
class ReduceOptions:
    """How frames become marker rows.

    mode: "track" (detect once, then track; re-detect on loss) or "detect" (whole frame every time).
    window_px: tracking window side (px, integer ≥ 7): twice the largest frame-to-frame motion plus a
    marker diameter. redetect_every: frames between whole-frame detections in "track" mode (integer ≥ 1).
    detect: keyword options of :func:`rig.stereo.detect_markers` (:data:`TRACK_KEYS` and
    :data:`DETECT_ONLY_KEYS`); the tracker gets only the :data:`TRACK_KEYS` among them. An unknown key
    raises ``ValueError`` here rather than ``TypeError`` at the first frame.
    """

    mode: str = "track"
    window_px: int = 51
    redetect_every: int = 30
    detect: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.mode not in ("track", "detect"):
            raise ValueError(f"mode={self.mode!r} not allowed; allowed: 'track' or 'detect'")
        if int(self.window_px) != self.window_px or self.window_px < 7:
            raise ValueError(f"window_px={self.window_px!r}: allowed: an integer ≥ 7")
        if int(self.redetect_every) != self.redetect_every or self.redetect_every < 1:
            raise ValueError(f"redetect_every={self.redetect_every!r}: allowed: an integer ≥ 1")
        unknown = sorted(set(self.detect) - set(TRACK_KEYS) - set(DETECT_ONLY_KEYS))
        if unknown:
            raise ValueError(f"detect options {unknown} not known; allowed: "
                             f"{', '.join(TRACK_KEYS + DETECT_ONLY_KEYS)}")


class MarkerReducer:
    """Per camera stream (and segment): frame → marker rows (``MARKER_DTYPE``) and their ``track_2d`` numbers.

    first_id: the number the first new marker gets (continue a segment over several recordings).
    """

    def __init__(self, options: ReduceOptions, first_id: int = 0) -> None:
        self.options = options
        self._track_kw = track_options(options.detect)
        self._uv = np.empty((0, 2))
        self._ids = np.empty(0, dtype=np.int64)
        self._next_id = int(first_id)
        self._since_detect = 0

    @property
    def next_id(self) -> int:
        """The number the next new marker gets (continue from it in a later recording of the segment)."""
        return self._next_id

    def _associate(self, found: np.ndarray) -> np.ndarray:
        """Track numbers for whole-frame detections: the previous marker within half a window, else new."""
        ids = np.full(len(found), -1, dtype=np.int64)
        uv = np.c_[found["u_px"], found["v_px"]]
        if len(self._uv) and len(uv):
            cost = np.linalg.norm(uv[:, None, :] - self._uv[None, :, :], axis=2)
            r, c = linear_sum_assignment(cost)
            ok = cost[r, c] <= self.options.window_px / 2
            ids[r[ok]] = self._ids[c[ok]]
        new = ids < 0
        ids[new] = np.arange(self._next_id, self._next_id + int(new.sum()))
        self._next_id += int(new.sum())
        return ids

    def reduce(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Marker rows of one 2-D uint8 frame (in stream order) and their ``track_2d`` numbers (int64)."""
        opts = self.options
        found: np.ndarray | None = None
        ids: np.ndarray | None = None
        if opts.mode == "track" and len(self._uv) and self._since_detect < opts.redetect_every:
            tracked = track_markers(image, self._uv, window_px=opts.window_px, **self._track_kw)
            if not np.any(tracked["flags"] & FLAG_LOST):
                found, ids = tracked, self._ids
                self._since_detect += 1
        if found is None:
            found = detect_markers(image, **opts.detect)
            ids = self._associate(found)
            self._since_detect = 1
        assert ids is not None
        self._uv = np.c_[found["u_px"], found["v_px"]]
        self._ids = ids
        return found, ids
