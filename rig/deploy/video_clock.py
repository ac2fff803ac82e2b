"""Relating a video's clock to the controller's record, for videos recorded on the cameras and imported later.

A camcorder's file carries its own time stamps only; the run record (``record.jsonl``) says when the
controller moved things. The procedure's motion is visible in the video, so the two clocks are related by
**cross-correlating the motion seen with the motion commanded**:

- seen: the summed image speed (px/s) of the video's marker tracks (:func:`rig.analysis.tracks2d.tracks_2d`),
on a
  uniform grid of one frame period, smoothed over ``smooth_s`` (an envelope: an oscillation's speed
  averages to a level proportional to frequency × amplitude);
- commanded: from the record's ``arm`` events (1 while a move runs, ``t_start_s`` … ``t_end_s``) and
  ``exciter``/``rotor`` events (the polled frequency, normalised, held until the next event), on the same
  grid on the controller clock;
- their time derivatives (the starts and stops of motion: levels would let long steady stretches outweigh
  the edges) are made zero-mean and unit-norm and cross-correlated (FFT); the lag of the peak, refined by
  a parabola through its neighbours, is the offset **controller time − video time** (s).

The peak's height is the correlation coefficient (1 = the same shape). The offset inherits the latency
between a command and visible motion (an arm accelerating, an exciter spinning up): a few frames at most
for moves, more for slow ramps. ``uncertainty_s`` (a bound, not a standard uncertainty) is one frame period
for the sampling plus one for a rolling shutter's readout (a marker's row is exposed up to a frame after the
frame's time stamp); the method is recorded so a report can say how the clocks were related.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from rig.analysis.tracks2d import tracks_2d

__all__ = ["VideoClockError", "image_motion", "record_motion", "relate_to_record"]


class VideoClockError(ValueError):
    """The video's motion cannot be related to the record's events (the message says why)."""


def _smooth(x: np.ndarray, n: int) -> np.ndarray:
    if n <= 1:
        return x
    return np.convolve(x, np.ones(n) / n, mode="same")


def image_motion(obs: pd.DataFrame, period_s: float, *, smooth_s: float = 0.2,
                 track_gate_px: float = 25.0) -> tuple[np.ndarray, np.ndarray]:
    """(grid_s, speed_px_s): summed, smoothed image speed of all tracks on the video's clock."""
    o = obs.copy()
    if "track_id" not in o.columns:
        o["track_id"] = tracks_2d(o, gate_px=track_gate_px).to_numpy()
    o = o[o["track_id"] >= 0]
    if o.empty:
        raise VideoClockError("the video shows no marker track; its clock cannot be related to the record")
    t0, t1 = float(o["timestamp_s"].min()), float(o["timestamp_s"].max())
    grid = t0 + period_s * np.arange(int(np.floor((t1 - t0) / period_s)) + 1)
    speed = np.zeros(len(grid))
    for _, group in o.groupby("track_id"):
        tr = group.sort_values("timestamp_s").drop_duplicates("timestamp_s")
        if len(tr) < 3:
            continue
        t = tr["timestamp_s"].to_numpy(float)
        uv = tr[["u_px", "v_px"]].to_numpy(float)
        v = np.hypot(*np.gradient(uv, t, axis=0).T)
        speed += np.interp(grid, t, v, left=0.0, right=0.0)
    return grid, _smooth(speed, round(smooth_s / period_s))


def record_motion(events: dict[str, pd.DataFrame], period_s: float, *, smooth_s: float = 0.2,
                  margin_s: float = 0.0) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(grid_s, activity, streams used) on the controller clock from ``arm``/``exciter``/``rotor`` events."""
    arm = events.get("arm")
    spans = []
    if arm is not None and not arm.empty and {"t_start_s", "t_end_s"} <= set(arm.columns):
        spans = [(float(a), float(b)) for a, b in zip(arm["t_start_s"], arm["t_end_s"], strict=True)
                 if np.isfinite(a) and np.isfinite(b) and b > a]
    freqs = []
    for stream in ("exciter", "rotor"):
        ev = events.get(stream)
        if ev is not None and not ev.empty and "frequency_hz" in ev.columns:
            f = ev[["time_s", "frequency_hz"]].dropna().sort_values("time_s")
            if len(f) and f["frequency_hz"].abs().max() > 0:
                freqs.append((stream, f["time_s"].to_numpy(float), np.abs(f["frequency_hz"].to_numpy(float))))
    used = (["arm"] if spans else []) + [s for s, _, _ in freqs]
    if not used:
        raise VideoClockError("the record has no motion events (arm moves with t_start_s/t_end_s, or exciter/"
                              "rotor frequencies) to relate the video's clock to")
    times = [t for s in spans for t in s] + [t for _, ts, _ in freqs for t in ts]
    t0, t1 = min(times) - margin_s, max(times) + margin_s
    grid = t0 + period_s * np.arange(int(np.floor((t1 - t0) / period_s)) + 1)
    act = np.zeros(len(grid))
    for a, b in spans:
        act[(grid >= a) & (grid <= b)] += 1.0
    for _, ts, fs in freqs:
        k = np.searchsorted(ts, grid, side="right") - 1
        act += np.where(k >= 0, fs[np.clip(k, 0, None)], 0.0) / fs.max()
    return grid, _smooth(act, round(smooth_s / period_s)), used


def _unit(x: np.ndarray) -> np.ndarray:
    x = x - x.mean()
    n = float(np.linalg.norm(x))
    return x / n if n > 0 else x


def relate_to_record(obs: pd.DataFrame, events: dict[str, pd.DataFrame], period_s: float, *,
                     smooth_s: float = 0.2, min_correlation: float = 0.5) -> dict[str, Any]:
    """Offset controller − video clock (s) from one video's observations and the record's events (module doc).

    Returns ``{"offset_s", "correlation", "uncertainty_s", "streams", "method"}``; raises
    :class:`VideoClockError` when the best correlation is below ``min_correlation`` (the video does not
    show the recorded motion, or shows too little of it).
    """
    tv, sv = image_motion(obs, period_s, smooth_s=smooth_s)
    video_span = tv[-1] - tv[0]
    tr, sr, used = record_motion(events, period_s, smooth_s=smooth_s, margin_s=video_span)
    if sv.max() <= 0:
        raise VideoClockError("no marker moves in the video; its clock cannot be related to the record")
    # the changes of the motion (starts and stops) are what locate the clocks: levels would let a long
    # stretch of steady motion outweigh the edges, and a mean removed over unequal spans biases the peak
    from scipy.signal import correlate  # ≈ 1 CPU-s to import: paid only where a clock is related

    c = correlate(_unit(np.gradient(sr)), _unit(np.gradient(sv)), mode="full", method="fft")
    # c[k] = Σ_i sr[i + L] sv[i] with L = k − (len(sv) − 1): record sample i + L ↔ video sample i
    k = int(np.argmax(c))
    lag = float(k - (len(sv) - 1))
    if 0 < k < len(c) - 1:
        den = c[k - 1] - 2 * c[k] + c[k + 1]
        if den < 0:
            lag += 0.5 * (c[k - 1] - c[k + 1]) / den
    corr = float(c[k])
    if corr < min_correlation:
        raise VideoClockError(f"the video's motion correlates at most {corr:.2f} (< {min_correlation}) with "
                              f"the record's {'/'.join(used)} events: it does not show the recorded "
                              "procedure")
    offset = float(tr[0] + lag * period_s - tv[0])
    # one frame period for the sampling of both signals, plus up to one for a rolling shutter (a marker's
    # row is exposed up to the readout time after the frame's time stamp)
    return {"offset_s": offset, "correlation": corr, "uncertainty_s": 2.0 * period_s, "streams": used,
            "method": "cross-correlation of the video's image speed with the record's motion events"}
