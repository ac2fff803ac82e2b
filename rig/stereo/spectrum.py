"""Amplitude-correct windowed DFT with an interpolated peak, and the STFT of a sweep.

Scaling: the returned amplitude of a bin is the **peak amplitude** of a sinusoid centred on that bin,
``2·|Σ w_k x_k e^{-j2πf t_k}| / Σ w_k`` (normalised by the window's coherent gain; DC is not doubled).
Between bins a tone loses the window's scalloping loss (rectangular 36 %, Hann 15 %, flat-top 0.1 %,
metrology notes §8); the *interpolated* peak removes it: the peak of the windowed DTFT is located by a
bounded search within ±1 bin of the largest bin (of the Hann-windowed DTFT for the flat-top window, whose
flat main lobe cannot locate a tone), so its frequency and amplitude are exact for a single tone
apart from leakage of the tone's negative-frequency image (small for records of several periods with a
Hann or flat-top window; use :func:`rig.stereo.sinefit.fit_sine` for the least-squares optimum).

Units follow the inputs: times in seconds, frequencies in hertz, amplitudes in the unit of ``x``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize

from rig.stereo._arrays import FloatArray
from rig.stereo._series import as_times, as_values, uniform_grid
from rig.stereo.errors import InputArrayError, TooFewSamplesError

WINDOWS = ("rect", "hann", "flattop", "blackmanharris")
# the cosine terms of scipy.signal.windows' hann, flattop and blackmanharris; the windows are computed as
# scipy computes them (its general cosine window), bit for bit (tests/test_stereo_spectrum.py), because
# importing scipy.signal costs ≈ 1 CPU-s in every process that measures
_COSINE_TERMS = {"hann": (0.5, 0.5),
                 "flattop": (0.21557895, 0.41663158, 0.277263158, 0.083578947, 0.006947368),
                 "blackmanharris": (0.35875, 0.48829, 0.14128, 0.01168)}


@dataclass(frozen=True)
class Spectrum:
    """One-sided amplitude spectrum of a uniformly sampled record.

    ``amplitude`` is the peak amplitude (unit of x) per bin of ``frequency_hz`` (0 … fs/2);
    ``peak_frequency_hz``/``peak_amplitude`` come from the interpolated peak (see module doc), searched
    above ``min_frequency_hz``. ``resolution_hz`` is the bin spacing fs/N.
    """

    frequency_hz: FloatArray
    amplitude: FloatArray
    peak_frequency_hz: float
    peak_amplitude: float
    window: str
    sample_rate_hz: float
    resolution_hz: float


def window_weights(name: str, n: int) -> FloatArray:
    """The window of ``name`` (one of WINDOWS) with ``n`` points (symmetric=False, i.e. DFT-even)."""
    if name == "rect":
        return np.ones(n)
    if name not in _COSINE_TERMS:
        raise InputArrayError(f"window must be one of {WINDOWS}, got {name!r}")
    if n <= 1:
        return np.ones(n)
    phase = np.linspace(-np.pi, np.pi, n + 1)  # n + 1 points, the last dropped: DFT-even
    w = np.zeros(n + 1)
    for k, a_k in enumerate(_COSINE_TERMS[name]):
        w += a_k * np.cos(k * phase)
    return w[:-1]


def dtft_amplitude(t_s: FloatArray, x: FloatArray, w: FloatArray, frequency_hz: float) -> float:
    """Amplitude-correct magnitude 2·|Σ w x e^{-j2πft}|/Σw at one frequency (any time stamps)."""
    phase = np.exp(-2j * np.pi * frequency_hz * (t_s - t_s[0]))
    return float(2.0 * np.abs(np.sum(w * x * phase)) / np.sum(w))


def refine_peak(
    t_s: FloatArray, x: FloatArray, w: FloatArray, f0_hz: float, half_width_hz: float
) -> tuple[float, float]:
    """Maximise the windowed DTFT magnitude within f0 ± half_width; return (frequency_hz, amplitude)."""
    lo, hi = max(f0_hz - half_width_hz, 0.0), f0_hz + half_width_hz
    res = optimize.minimize_scalar(
        lambda f: -dtft_amplitude(t_s, x, w, f),
        bounds=(lo, hi),
        method="bounded",
        options={"xatol": 1e-9 * max(hi, 1.0)},
    )
    return float(res.x), float(-res.fun)


def spectrum(
    t_s: object,
    x: object,
    *,
    window: str = "hann",
    detrend: bool = True,
    min_frequency_hz: float | None = None,
) -> Spectrum:
    """Windowed DFT of a uniformly sampled record with amplitude-correct scaling and an interpolated peak.

    ``t_s``: strictly increasing, uniform within 2 % of a period and without gaps (s); ``x``: values.
    ``detrend`` removes the mean first. ``min_frequency_hz`` (default: 1.5 bins) excludes the DC region from
    the peak search. Raises TooFewSamplesError for fewer than 8 samples, NonUniformSamplingError for
    irregular time stamps (resample first, or use fit_sine which takes any time stamps).
    """
    t = as_times(t_s, min_count=8)
    xv = as_values(x, t.size)
    if xv.ndim != 1:
        raise InputArrayError(f"x must be 1-D, got shape {xv.shape}")
    _t0, period, n_idx = uniform_grid(t)
    if n_idx[-1] != t.size - 1:
        raise InputArrayError(
            f"t_s has gaps ({int(n_idx[-1]) + 1 - t.size} missing samples); fill or resample before the DFT"
        )
    n = t.size
    fs = 1.0 / period
    if detrend:
        xv = xv - xv.mean()
    w = window_weights(window, n)
    X = np.fft.rfft(w * xv)
    amp = 2.0 * np.abs(X) / w.sum()
    amp[0] /= 2.0
    if n % 2 == 0:
        amp[-1] /= 2.0
    freq = np.asarray(np.fft.rfftfreq(n, d=period), dtype=np.float64)
    f_min = 1.5 * fs / n if min_frequency_hz is None else float(min_frequency_hz)
    search = freq >= f_min
    if not np.any(search):
        raise TooFewSamplesError(f"no DFT bin above min_frequency_hz = {f_min} Hz (record too short)")
    k = int(np.flatnonzero(search)[np.argmax(amp[search])])
    tg = t[0] + n_idx * period  # the fitted uniform grid: no jitter in the refinement
    # A flat-top window's main lobe is flat by design, so its maximum does not locate the tone: the
    # frequency comes from the Hann-windowed DTFT, the amplitude from the requested window at it.
    w_locate = window_weights("hann", n) if window == "flattop" else w
    f_peak, _ = refine_peak(tg, xv, w_locate, float(freq[k]), fs / n)
    a_peak = dtft_amplitude(tg, xv, w, f_peak)
    return Spectrum(freq, amp, f_peak, a_peak, window, fs, fs / n)


@dataclass(frozen=True)
class Spectrogram:
    """Short-time amplitude spectra: ``amplitude[i, j]`` at ``time_s[i]`` (window centre),
    ``frequency_hz[j]``;
    ``peak_frequency_hz[i]``/``peak_amplitude[i]`` are each window's interpolated peak."""

    time_s: FloatArray
    frequency_hz: FloatArray
    amplitude: FloatArray
    peak_frequency_hz: FloatArray
    peak_amplitude: FloatArray


def stft(t_s: object, x: object, *, window_s: float, step_s: float, window: str = "hann") -> Spectrogram:
    """Sliding windowed DFT (amplitude-correct, interpolated peak per window) of a uniform record.

    ``window_s`` should hold several periods of the lowest frequency of interest (resolution ≈ 1/window_s);
    the instantaneous frequency of a sweep is the ridge ``peak_frequency_hz`` at the window centres.
    """
    t = as_times(t_s, min_count=8)
    xv = as_values(x, t.size)
    _t0, period, n_idx = uniform_grid(t)
    if n_idx[-1] != t.size - 1:
        raise InputArrayError("t_s has gaps; fill or resample before the STFT")
    n_win = round(window_s / period)
    n_step = max(1, round(step_s / period))
    if n_win < 8 or n_win > t.size:
        raise TooFewSamplesError(
            f"window_s = {window_s} s spans {n_win} samples; need 8 … {t.size} (the record length)"
        )
    starts = np.arange(0, t.size - n_win + 1, n_step)
    rows, f_pk, a_pk, centres = [], [], [], []
    freq = np.empty(0)
    for s in starts:
        sl = slice(int(s), int(s) + n_win)
        sp = spectrum(t[sl], xv[sl], window=window)
        rows.append(sp.amplitude)
        f_pk.append(sp.peak_frequency_hz)
        a_pk.append(sp.peak_amplitude)
        centres.append(0.5 * (t[sl][0] + t[sl][-1]))
        freq = sp.frequency_hz
    return Spectrogram(np.array(centres), freq, np.array(rows), np.array(f_pk), np.array(a_pk))
