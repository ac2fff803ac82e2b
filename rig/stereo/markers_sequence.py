"""Tracking over many frames in one call: the per-call cost of :func:`track_markers` paid once per batch.

:func:`track_markers` costs a fixed ~50–100 µs of Python and numpy per call, whatever the number of
markers (its windows are measured by one compiled call); measuring the windows of many frames together
pays it once. :func:`track_markers_batch` measures
given predictions in each of several frames; :func:`track_markers_sequence` follows markers through a run
of frames, each frame's prediction being the previous frame's result — exactly what calling
:func:`track_markers` frame by frame gives (tests/test_stereo_markers_sequence.py), computed
speculatively, each marker on its own: a chunk of its frames is measured with windows at its last known
centre, and kept up to the first frame whose window (the rounded previous result) would have been placed
differently; its next chunk starts there. A marker that moves less than about half a pixel per frame (a
structure's vibration, a slow drift) keeps its window for many frames, and whole chunks are kept; one
that moves a pixel or more per frame needs a round per frame, as frame-by-frame tracking does.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from rig.stereo.errors import InputArrayError
from rig.stereo.markers import (
    FLAG_LOST,
    MARKER_DTYPE,
    MAX_EDGE_RMS_PX,
    MAX_SKEWNESS,
    TrackOptions,
    check_gray,
    track_rows,
)

MAX_CHUNK_FRAMES = 32  # frames measured together at most (the stack of windows stays in cache)


def _frames(frames: Sequence[np.ndarray] | np.ndarray) -> list[np.ndarray]:
    """The frames checked: uint8 2-D, all of one shape."""
    checked = [check_gray(f, f"frames[{i}]") for i, f in enumerate(frames)]
    if checked and any(f.shape != checked[0].shape for f in checked):
        shapes = sorted({f.shape for f in checked})
        raise InputArrayError(f"frames have different shapes {shapes}; give frames of one camera")
    return checked


def track_markers_batch(frames: Sequence[np.ndarray] | np.ndarray, predicted_uv_px: np.ndarray, *,
                        window_px: int = 41, polarity: str = "bright", min_area_px: float = 20.0,
                        max_area_px: float = 20000.0, min_roundness: float = 0.5, min_contrast: float = 20.0,
                        centre: str = "centroid", max_skewness: float = MAX_SKEWNESS,
                        outline_check: bool = False, max_edge_rms_px: float = MAX_EDGE_RMS_PX) -> np.ndarray:
    """:func:`track_markers` of F frames at once: rows (F, K) of :data:`MARKER_DTYPE`.

    frames: F uint8 frames of one shape (a sequence or an (F, H, W) array). predicted_uv_px: (F, K, 2),
    the predictions (u, v) px in each frame, or (K, 2) for the same ones in every frame. Row [f, k] is what
    ``track_markers(frames[f], predicted_uv_px[f])[k]`` gives; other options as there.
    """
    images = _frames(frames)
    options = TrackOptions.checked(window_px=window_px, polarity=polarity, min_area_px=min_area_px,
                                   max_area_px=max_area_px, min_roundness=min_roundness,
                                   min_contrast=min_contrast, centre=centre, max_skewness=max_skewness,
                                   outline_check=outline_check, max_edge_rms_px=max_edge_rms_px)
    pred = np.asarray(predicted_uv_px, dtype=np.float64)
    if pred.ndim == 2 and pred.shape[1] == 2:
        pred = np.broadcast_to(pred, (len(images), *pred.shape))
    if pred.ndim != 3 or pred.shape[2] != 2 or pred.shape[0] != len(images):
        raise InputArrayError(f"predicted_uv_px has shape {pred.shape}; give ({len(images)}, K, 2) or (K, 2) "
                              f"(u, v) in px for {len(images)} frames")
    return _batch(images, pred, options)


def _batch(images: list[np.ndarray], pred: np.ndarray, options: TrackOptions) -> np.ndarray:
    n_frames, k = pred.shape[:2]
    if n_frames == 0 or k == 0:
        return np.empty((n_frames, k), dtype=MARKER_DTYPE)
    frame = np.repeat(np.arange(n_frames), k)
    return track_rows(images, pred.reshape(-1, 2), frame, options).reshape(n_frames, k)


def track_markers_sequence(frames: Sequence[np.ndarray] | np.ndarray, start_uv_px: np.ndarray, *,
                           window_px: int = 41, polarity: str = "bright", min_area_px: float = 20.0,
                           max_area_px: float = 20000.0, min_roundness: float = 0.5,
                           min_contrast: float = 20.0, centre: str = "centroid",
                           max_skewness: float = MAX_SKEWNESS, outline_check: bool = False,
                           max_edge_rms_px: float = MAX_EDGE_RMS_PX, hold_px: float | None = None,
                           ) -> np.ndarray:
    """Follow K markers through consecutive frames: rows (n, K) of :data:`MARKER_DTYPE`, n ≤ F.

    Frame 0 is searched around ``start_uv_px`` (K, 2) (u, v px). hold_px None (default): every later frame
    around the previous frame's result — row [f] equals ``track_markers(frames[f], prev)``, prev the
    (u, v) of row [f − 1]. hold_px a number (0.5–2 px): a marker's window stays where it is while the
    marker's centre stays within hold_px of the window's centre in u and in v, and is moved to the
    rounded centre otherwise (its prediction for the next frame) — row [f] equals
    ``track_markers(frames[f], window_centres)``; the same measurement with the marker up to hold_px
    instead of 0.5 px off its window's centre (make window_px 2·hold_px larger), and whole runs of frames
    measured together when the markers move little (vibration about a position).
    The run stops after the first frame in which a marker is lost (FLAG_LOST; that frame's rows are the
    last returned), so n < F tells the caller to search that frame whole. Options as in
    :func:`track_markers`.
    """
    images = _frames(frames)
    options = TrackOptions.checked(window_px=window_px, polarity=polarity, min_area_px=min_area_px,
                                   max_area_px=max_area_px, min_roundness=min_roundness,
                                   min_contrast=min_contrast, centre=centre, max_skewness=max_skewness,
                                   outline_check=outline_check, max_edge_rms_px=max_edge_rms_px)
    pos = np.asarray(start_uv_px, dtype=np.float64)
    if pos.ndim != 2 or pos.shape[1] != 2:
        raise InputArrayError(f"start_uv_px has shape {pos.shape}; give a (K, 2) array of (u, v) in px")
    if hold_px is not None and not (0.5 <= hold_px <= 0.5 * (window_px - 7)):
        raise InputArrayError(f"hold_px={hold_px}; give None (re-centre every frame) or 0.5 px up to "
                              f"(window_px − 7)/2 = {0.5 * (window_px - 7)} px")
    return _sequence(images, pos if hold_px is None else np.rint(pos), options, hold_px)


def _sequence(images: list[np.ndarray], start: np.ndarray, options: TrackOptions,
              hold_px: float | None) -> np.ndarray:
    """Speculative frame-by-frame tracking, each marker on its own (its windows depend only on its own
    previous results): every round measures, for each marker still behind, a chunk of its next frames
    in a window at its last prediction, and keeps them up to the first frame whose window would have been
    placed differently — the next round starts that marker there. ``start``: the first predictions,
    rounded when hold_px is set (predictions are then window centres)."""
    n_frames, k = len(images), len(start)
    out = np.empty((n_frames, k), dtype=MARKER_DTYPE)
    if n_frames == 0 or k == 0:
        return out
    height, width = images[0].shape
    limit = np.array([width - 0.5, height - 0.5])
    done = np.zeros(k, dtype=np.int64)  # frames finished, per marker
    pos = start.copy()
    stop = n_frames  # frames wanted: up to and including the first frame with a lost marker
    chunk = np.full(k, 4, dtype=np.int64)  # frames per round, per marker: doubles while all are kept
    while True:
        active = np.flatnonzero(done < stop)
        if len(active) == 0:
            return out[:stop]
        # (A, chunk) frames of each active marker (beyond ``stop``: not measured), measured in frame order
        width_frames = int(chunk[active].max())
        frame = done[active, None] + np.arange(width_frames)
        marker = np.repeat(active[:, None], width_frames, axis=1)
        wanted = (frame < stop) & (np.arange(width_frames) < chunk[active, None])
        order = np.argsort(frame[wanted], kind="stable")
        rows = np.empty(len(order), dtype=MARKER_DTYPE)
        rows[order] = track_rows(images, pos[marker[wanted][order]], frame[wanted][order], options)
        rec = np.zeros(frame.shape, dtype=MARKER_DTYPE)
        rec[wanted] = rows
        uv = np.stack([rec["u_px"], rec["v_px"]], axis=-1)  # (A, chunk, 2)
        prev = pos[active, None, :]
        # frame j ≥ 1 is right when frame j − 1's result puts the window where it was: within hold_px
        # of it, or (hold_px None) the same rounded centre and the same usability (inside the frame);
        # and nothing lost in frame j − 1
        with np.errstate(invalid="ignore"):
            if hold_px is None:
                same = (np.rint(uv[:, :-1]) == np.rint(prev)).all(axis=2)
                same &= ((uv[:, :-1] > -0.5) & (uv[:, :-1] < limit)).all(axis=2) == (
                    (prev > -0.5) & (prev < limit)).all(axis=2)
            else:
                same = (np.abs(uv[:, :-1] - prev) <= hold_px).all(axis=2)
        lost = (rec["flags"] & FLAG_LOST).astype(bool) & wanted
        same &= ~lost[:, :-1] & wanted[:, 1:]
        kept = 1 + np.cumprod(same, axis=1).sum(axis=1)  # (A,) frames kept per marker
        sel = np.arange(width_frames)[None, :] < kept[:, None]
        out[frame[sel], marker[sel]] = rec[sel]
        if (lost & sel).any():
            stop = min(stop, int(frame[lost & sel].min()) + 1)
        last = uv[np.arange(len(active)), kept - 1]
        with np.errstate(invalid="ignore"):
            if hold_px is None:
                held = (np.rint(last) == np.rint(pos[active])).all(axis=1)
                pos[active] = last
            else:  # the window moves when the marker left its hold (else it stays)
                held = (np.abs(last - pos[active]) <= hold_px).all(axis=1)
                pos[active] = np.where(held[:, None], pos[active], np.rint(last))
        done[active] += kept
        # a marker whose chunk was all kept and whose window stays doubles its chunk, else takes what was
        # kept (a marker moving a pixel per frame comes down to one frame per round, as frame-by-frame
        # tracking, without measuring frames in vain)
        chunk[active] = np.where((kept == wanted.sum(axis=1)) & held,
                                 np.minimum(2 * chunk[active], MAX_CHUNK_FRAMES), kept)
