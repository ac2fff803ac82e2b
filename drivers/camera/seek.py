"""Frame-exact seeking in a video file: start decoding at frame k without decoding frames 0 … k − 1.

A frame is identified by its presentation time stamp. :func:`frame_times_s` lists the time stamps of every
frame of the video stream by demuxing its packets without decoding them (OpenCV's raw-stream mode,
``CAP_PROP_FORMAT`` −1: 5 ms of CPU for 240 frames of a 1080p MP4 (mp4v), whose decoding took 0.9 s),
sorted into presentation order — frame k of a sequential decode is the frame stamped ``times_s[k]``.

:func:`seek_frame` positions an open capture on frame k and **verifies** where it landed: OpenCV's
``CAP_PROP_POS_FRAMES`` seeks to the key frame before a time computed from k and the average frame rate,
then decodes forward, so it is frame-exact only where the time stamps are regular (dropped frames or a
variable frame rate move the landing: tests/test_camera_seek.py). The landed frame's stamp is looked up in
the list: when it is frame k, done; when it is an earlier frame j (unambiguous: its stamp occurs once),
the capture decodes forward k − j frames, each checked against the list (the next stamp in it); otherwise
(a later frame, a stamp not listed) it seeks further back (k − 16, k − 64, k − 256 frames, then the start
of the file) and decodes forward from there. Nothing verified: the caller decodes from the start (the old
way), so a seek never changes which frame is called k.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ["BACK_OFF_FRAMES", "frame_times_s", "seek_frame"]

BACK_OFF_FRAMES = (0, 16, 64, 256)  # seek targets k − n tried in turn before the start of the file
_SAME_STAMP_S = 1e-6  # two stamps this close are the same frame's (containers count in ≥ 1/90000 s)


def frame_times_s(path: str) -> NDArray[np.float64] | None:
    """Presentation time stamps (s) of every frame of the video stream, in presentation order, read from
    the packets without decoding them; None when the file cannot be demuxed this way."""
    cap = cv2.VideoCapture(path, cv2.CAP_FFMPEG)
    try:
        if not cap.isOpened() or not cap.set(cv2.CAP_PROP_FORMAT, -1):
            return None
        stamps_ms = []
        while cap.grab():
            stamps_ms.append(cap.get(cv2.CAP_PROP_POS_MSEC))
    finally:
        cap.release()
    times = np.sort(np.asarray(stamps_ms, dtype=np.float64)) / 1000.0
    return times if len(times) and np.isfinite(times).all() else None


def _frame_at(times_s: NDArray[np.float64], pts_s: float) -> int | None:
    """Index of the frame stamped ``pts_s``, or None when no frame or more than one frame has that stamp."""
    lo = int(np.searchsorted(times_s, pts_s - _SAME_STAMP_S))
    hi = int(np.searchsorted(times_s, pts_s + _SAME_STAMP_S))
    return lo if hi - lo == 1 else None


def _forward(cap: cv2.VideoCapture, times_s: NDArray[np.float64], index: int) -> bool:
    """Grab frames until frame ``index`` is grabbed, from wherever the capture is; True when the grabbed
    frame and each one passed on the way is verified by its stamp."""
    if not cap.grab():
        return False
    at = _frame_at(times_s, float(cap.get(cv2.CAP_PROP_POS_MSEC)) / 1000.0)
    if at is None or at > index:
        return False
    while at < index:  # each frame passed is the next in the list (a repeated stamp included)
        if not cap.grab():
            return False
        at += 1
        if abs(float(cap.get(cv2.CAP_PROP_POS_MSEC)) / 1000.0 - times_s[at]) > _SAME_STAMP_S:
            return False
    return True


def seek_frame(cap: cv2.VideoCapture, times_s: NDArray[np.float64], index: int) -> bool:
    """Leave frame ``index`` grabbed on ``cap`` (read it with ``cap.retrieve()``; the next ``grab()`` gives
    frame index + 1), verified by its stamp in ``times_s`` (:func:`frame_times_s`; module docstring).
    False when no seek could be verified: the capture is then in an unknown position."""
    if not 0 <= index < len(times_s):
        return False
    for back in (*BACK_OFF_FRAMES, index):
        target = max(0, index - back)
        if cap.set(cv2.CAP_PROP_POS_FRAMES, float(target)) and _forward(cap, times_s, index):
            return True
        if target == 0:
            break
    return False
