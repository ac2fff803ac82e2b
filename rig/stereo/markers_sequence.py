"""Tracking over many frames in one call: the per-call cost of :func:`track_markers` paid once per batch.

:func:`track_markers` costs a fixed ~100 small array operations per call, whatever the number of
markers; measuring the windows of many frames together pays it once. :func:`track_markers_batch` measures
given predictions in each of several frames; :func:`track_markers_sequence` follows markers through a run
of frames, each frame's prediction being the previous frame's result — exactly what calling
:func:`track_markers` frame by frame gives (tests/test_stereo_markers_sequence.py), computed
speculatively: a chunk of frames is measured with windows at the last known centres, and the frames are
kept up to the first whose window (the rounded previous result) would have been placed differently; the
next chunk starts there. Markers that move less than about half a pixel per frame (a structure's
vibration, a slow drift) keep their windows for many frames, and whole chunks are kept.
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
                           max_edge_rms_px: float = MAX_EDGE_RMS_PX) -> np.ndarray:
    """Follow K markers through consecutive frames: rows (n, K) of :data:`MARKER_DTYPE`, n ≤ F.

    Frame 0 is searched around ``start_uv_px`` (K, 2) (u, v px), every later frame around the previous
    frame's result: row [f] equals ``track_markers(frames[f], prev)``, prev the (u, v) of row [f − 1].
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
    out = np.empty((len(images), len(pos)), dtype=MARKER_DTYPE)
    done, chunk = 0, 4
    height, width = images[0].shape if images else (0, 0)
    limit = np.array([width - 0.5, height - 0.5])
    while done < len(images):
        n = min(chunk, len(images) - done)
        rec = _batch(images[done : done + n], np.broadcast_to(pos, (n, *pos.shape)), options)
        uv = np.stack([rec["u_px"], rec["v_px"]], axis=-1)  # (n, K, 2)
        # frame j ≥ 1 of the chunk is right when frame j − 1's result would have put its windows where
        # they were: the same rounded centres, and the same usable (inside the frame) predictions
        with np.errstate(invalid="ignore"):
            same = (np.rint(uv[:-1]) == np.rint(pos)).all(axis=(1, 2))
            same &= (((uv[:-1] > -0.5) & (uv[:-1] < limit)).all(axis=2)
                     == ((pos > -0.5) & (pos < limit)).all(axis=1)).all(axis=1)
        kept = 1 + int(np.argmin(same)) if not same.all() else n
        lost = (rec["flags"][:kept] & FLAG_LOST).any(axis=1)
        if lost.any():
            kept = int(np.argmax(lost)) + 1
        out[done : done + kept] = rec[:kept]
        done += kept
        if lost.any():
            return out[:done]
        pos = uv[kept - 1]
        chunk = min(2 * chunk, MAX_CHUNK_FRAMES) if kept == n else max(kept, 2)
    return out[:done]
