"""A live preview estimate from a short window of both cameras' marker tracks: the markers paired between the
cameras, triangulated, and per window the amplitude and frequency of a vibrating marker or the phase of a
rotating one.

A preview, not the measurement: the window is short (a few periods), the other camera's pixels are
interpolated to the reference camera's times by a cubic spline (poor near half the frame rate),
triangulation is linear (no refinement) and the clocks are related by ``timing.json`` when the run has
one, else by the recordings' first frames (±1 frame). The certificate's numbers come from the full
analysis of the run folder afterwards (:mod:`rig.analysis`).
Every function here is bounded by the window's size: a few markers × a few hundred samples.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from rig.stereo import DLTCamera, TimingError, fit_sine, match_epipolar, triangulate
from rig.stereo.sinefit import fit_chirp

__all__ = ["MarkerPath", "TrackSamples", "VibrationEstimate", "paired_paths", "rotor_turns",
           "vibration_estimate"]

# a camera's markers over a window: track id → (times (n,) on the common clock, s; pixels (n, 2))
TrackSamples = dict[int, tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class MarkerPath:
    """One marker seen by both cameras over a window: the reference camera's times ``t_s`` (n,) and the
    triangulated positions ``xyz_mm`` (n, 3); ``tracks`` its (reference, other) 2-D track ids."""

    t_s: np.ndarray
    xyz_mm: np.ndarray
    tracks: tuple[int, int]

    @property
    def motion_mm(self) -> float:
        """RMS distance of the positions from their mean (mm): 0 for a still marker."""
        return float(np.sqrt(np.mean(np.sum((self.xyz_mm - self.xyz_mm.mean(axis=0)) ** 2, axis=1))))


@dataclass(frozen=True)
class VibrationEstimate:
    """A sine fitted to a marker's displacement along its main direction of motion over one window."""

    t_mid_s: float
    frequency_hz: float
    amplitude_mm: float


def paired_paths(cameras: tuple[DLTCamera, DLTCamera], tracks: tuple[TrackSamples, TrackSamples], *,
                 gate_px: float = 8.0, min_samples: int = 8) -> list[MarkerPath]:
    """The markers of the reference camera (``tracks[0]``) paired with the other camera's by the epipolar
    distance of their mean pixels over the window (``gate_px``; ambiguous pairs dropped), the other's
    pixels interpolated to the reference's times by a cubic spline (samples outside its time span dropped),
    triangulated.
    Tracks with fewer than ``min_samples`` samples are ignored."""
    ref, other = ({k: v for k, v in t.items() if len(v[0]) >= min_samples} for t in tracks)
    if not ref or not other:
        return []
    ref_ids, other_ids = sorted(ref), sorted(other)
    means = [np.array([np.mean(side[k][1], axis=0) for k in ids]) for side, ids in
             ((ref, ref_ids), (other, other_ids))]
    matches = match_epipolar(cameras[0], cameras[1], means[0], means[1], gate_px=gate_px)
    paths = []
    for (i, j), ambiguous in zip(matches.pairs, matches.ambiguous, strict=True):
        if ambiguous:
            continue
        (t_a, uv_a), (t_b, uv_b) = ref[ref_ids[i]], other[other_ids[j]]
        inside = (t_a >= t_b[0]) & (t_a <= t_b[-1])
        if inside.sum() < min_samples:
            continue
        t = t_a[inside]
        uv_b_at = CubicSpline(t_b, uv_b, axis=0)(t)
        xyz = triangulate(list(cameras), [uv_a[inside], uv_b_at]).xyz_mm
        keep = np.all(np.isfinite(xyz), axis=1)
        if keep.sum() >= min_samples:
            paths.append(MarkerPath(t[keep], xyz[keep], (ref_ids[i], other_ids[j])))
    return paths


def vibration_estimate(path: MarkerPath) -> VibrationEstimate:
    """The amplitude and frequency (at the window's middle) of the displacement along the path's main
    direction (its first principal axis): a four-parameter sine fit (frequency free), refined as a linear
    chirp (a sweep's frequency changes within the window). The window must span at least one period."""
    centred = path.xyz_mm - path.xyz_mm.mean(axis=0)
    axis = np.linalg.svd(centred, full_matrices=False)[2][0]
    x = centred @ axis
    t_mid_s = float(0.5 * (path.t_s[0] + path.t_s[-1]))
    sine = fit_sine(path.t_s, x, t_ref_s=t_mid_s, initial_frequency_hz=_spectral_peak_hz(path.t_s, x))
    try:
        p, _, _ = fit_chirp(path.t_s - t_mid_s, x, 2 * np.pi * sine.frequency_hz)
    except TimingError:  # the chirp did not converge: the plain sine fit
        return VibrationEstimate(t_mid_s, float(sine.frequency_hz), float(abs(sine.amplitude)))
    return VibrationEstimate(t_mid_s, float(p[3] / (2 * np.pi)), float(np.hypot(p[0], p[1])))


def _spectral_peak_hz(t_s: np.ndarray, x: np.ndarray, padding: int = 8) -> float:
    """The largest peak of the zero-padded FFT of ``x`` at its mean sampling interval (where the sine fit
    starts: a cheap stand-in for the dense search of :func:`rig.stereo.sinefit.initial_frequency`)."""
    n = padding * len(x)
    power = np.abs(np.fft.rfft(x - x.mean(), n))
    power[0] = 0.0
    return float(np.argmax(power) / (n * np.mean(np.diff(t_s))))


def rotor_turns(path: MarkerPath) -> np.ndarray:
    """The rotating marker's angle about the centre of the circle it describes, in turns (n,), unwrapped
    and increasing, 0 at the window's first sample: the plane is the path's first two principal axes, the
    centre an algebraic circle fit in it. Unwrapping assumes under half a turn between samples (a rotor
    below half the frame rate)."""
    mean = path.xyz_mm.mean(axis=0)
    basis = np.linalg.svd(path.xyz_mm - mean, full_matrices=False)[2][:2]
    xy = (path.xyz_mm - mean) @ basis.T
    # x² + y² = 2ax + 2by + c: the circle's centre (a, b), linear least squares
    design = np.column_stack([2 * xy, np.ones(len(xy))])
    (a, b, _), *_ = np.linalg.lstsq(design, np.sum(xy**2, axis=1), rcond=None)
    angle = np.unwrap(np.arctan2(xy[:, 1] - b, xy[:, 0] - a))
    turns = (angle - angle[0]) / (2 * np.pi)
    return turns if turns[-1] >= 0 else -turns  # the plane's orientation is arbitrary: count forwards
