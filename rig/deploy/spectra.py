"""Multi-tone and non-stationary records: Welch spectrum, significant peaks, fitted amplitudes, STFT table.

A structure has several modes, and a record may hold tones one after another or a sweep. On a uniformly
sampled displacement (s, mm):

- :func:`welch` — the whole record's amplitude spectrum (Welch: Hann segments of a quarter of the record,
  50 % overlap). Scaling: ``amplitude = sqrt(mean over segments |2·Σ w x e^{−j2πft}|² / (Σ w)²)``, the
  **peak amplitude** of a steady tone on a bin (up to 15 % less between bins, the Hann scalloping); a tone
  present during a fraction p of the record shows ≈ amplitude·√p. The noise floor is the running median of
  the power over ±``FLOOR_HALF_BINS`` bins, turned into the mean noise power by the median of χ²_ν/ν
  (ν: the equivalent degrees of freedom of the overlapped Hann average, Welch 1967);
- :func:`tone_peaks` — every peak above the significance threshold, strongest first, one at a time: a bin is
  significant when its power exceeds the χ²_ν quantile at which the whole spectrum would hold a false
  alarm with probability ``false_alarm`` (Bonferroni over the bins). Each peak's active interval comes from
  the STFT of the record (windows whose amplitude at the peak reaches ``ACTIVE_FRACTION`` of its largest),
  its amplitude and frequency from a four-parameter sine fit over that interval (three-parameter at the
  spectral peak if the fit leaves it) after the tones already found are subtracted; the fitted tone is then
  subtracted and the spectrum of the residual searched again (the leakage of a strong tone never counts as
  a peak). A final pass refits every tone with all the others subtracted; a tone whose fitted amplitude is
  below ``FIT_SIGNIFICANCE`` of its standard uncertainties is dropped (significant in the spectrum of a
  residual, but not as a tone of the record);
- :func:`time_frequency` — the STFT amplitude table (window :func:`stft_window_s`, step a quarter window).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage, special

from rig.stereo import fit_sine
from rig.stereo.errors import StereoError
from rig.stereo.sinefit import SineFit
from rig.stereo.spectrum import Spectrogram, window_weights

__all__ = ["Peak", "WelchSpectrum", "chi2_median", "stft_window_s", "time_frequency", "tone_peaks", "welch"]

FLOOR_HALF_BINS = 6
ACTIVE_FRACTION = 0.8
MAX_PEAKS = 12
FIT_SIGNIFICANCE = 3.0  # a tone's fitted amplitude must also exceed this many of its standard uncertainties
HANN_OVERLAP_CORRELATION = 0.167  # correlation of Hann segments overlapping by 50 % (Welch 1967)


def chi2_median(dof: float) -> float:
    """The median of the χ² distribution with ``dof`` degrees of freedom: ``scipy.stats.chi2.median`` bit
    for bit (its ``2·gammaincinv(dof/2, ½)``; the χ² tail and its inverse are ``special.chdtrc`` and
    ``special.chdtri``, which ``scipy.stats.chi2`` calls too), without importing scipy.stats (≈ 0.8 CPU-s
    in every process that measures)."""
    return float(2.0 * special.gammaincinv(dof / 2.0, 0.5))


@dataclass(frozen=True)
class WelchSpectrum:
    """Welch amplitude spectrum (module doc): ``amplitude``, ``noise_floor`` (mean noise amplitude) and
    ``threshold`` (amplitude a bin must exceed to be significant) per ``frequency_hz``; ``dof``: ν."""

    frequency_hz: np.ndarray
    amplitude: np.ndarray
    noise_floor: np.ndarray
    threshold: np.ndarray
    resolution_hz: float
    dof: float
    false_alarm: float


@dataclass(frozen=True)
class Peak:
    """One significant tone: fitted amplitude and frequency (with standard uncertainties) over its active
    interval [t_start_s, t_stop_s]; ``welch_amplitude``/``noise_floor`` where it was found; ``method``:
    "4-parameter fit" or "3-parameter fit at the spectral peak"."""

    frequency_hz: float
    frequency_std_hz: float
    amplitude: float
    amplitude_std: float
    t_start_s: float
    t_stop_s: float
    welch_amplitude: float
    noise_floor: float
    false_alarm_probability: float
    method: str


def welch(t_s: np.ndarray, x: np.ndarray, *, false_alarm: float = 1e-3) -> WelchSpectrum:
    """Welch amplitude spectrum of a uniform record (see the module docstring)."""
    n = len(x)
    period = float(np.median(np.diff(t_s)))
    seg = max(16, n // 4)
    if seg > n:
        raise StereoError(f"{n} samples; the Welch spectrum needs at least 16")
    step = seg // 2
    starts = range(0, n - seg + 1, step)
    w = window_weights("hann", seg)
    xc = x - np.mean(x)
    power = np.mean([np.abs(np.fft.rfft(w * (xc[s:s + seg] - np.mean(xc[s:s + seg])))) ** 2 for s in starts],
                    axis=0) * (2.0 / w.sum()) ** 2
    k = len(starts)
    rho = HANN_OVERLAP_CORRELATION if k > 1 else 0.0
    dof = 2.0 * k / (1.0 + 2.0 * rho**2 - 2.0 * rho**2 / k)
    mean_noise = ndimage.median_filter(power, size=2 * FLOOR_HALF_BINS + 1, mode="nearest") / (
        chi2_median(dof) / dof)
    n_bins = len(power)
    level = float(special.chdtri(dof, false_alarm / n_bins)) / dof
    freq = np.fft.rfftfreq(seg, d=period)
    return WelchSpectrum(freq, np.sqrt(power), np.sqrt(mean_noise), np.sqrt(mean_noise * level),
                         1.0 / (seg * period), dof, false_alarm)


def stft_window_s(duration_s: float, period_s: float) -> float:
    """STFT window: 1 s or a sixteenth of the record if longer, at least 16 samples, at most the record."""
    return float(min(duration_s, max(1.0, duration_s / 16.0, 16 * period_s)))


def time_frequency(t_s: np.ndarray, x: np.ndarray) -> Spectrogram:
    """STFT of a uniform record: Hann windows of :func:`stft_window_s`, step ¼ window, amplitude-correct as
    :func:`rig.stereo.stft` (peak amplitude of a tone on a bin); each window's peak is its largest bin above
    DC (not interpolated: :func:`rig.stereo.stft` does that, one optimisation per window)."""
    period = float(np.median(np.diff(t_s)))
    n_win = max(8, min(len(x), round(stft_window_s(float(t_s[-1] - t_s[0]) + period, period) / period)))
    n_step = max(1, n_win // 4)
    xc = np.asarray(x, float) - np.mean(x)
    segs = np.lib.stride_tricks.sliding_window_view(xc, n_win)[::n_step]
    segs = segs - segs.mean(axis=1, keepdims=True)
    w = window_weights("hann", n_win)
    amp = 2.0 * np.abs(np.fft.rfft(segs * w, axis=1)) / w.sum()
    amp[:, 0] /= 2.0
    freq = np.asarray(np.fft.rfftfreq(n_win, d=period), dtype=np.float64)
    centres = t_s[0] + period * (np.arange(len(segs)) * n_step + 0.5 * (n_win - 1))
    k = 1 + np.argmax(amp[:, 1:], axis=1)
    return Spectrogram(centres, freq, amp, freq[k], amp[np.arange(len(k)), k])


def _active_interval(sg: Spectrogram, frequency_hz: float, t_s: np.ndarray,
                     window_s: float) -> tuple[float, float]:
    """Where the tone is on: from the first to the last STFT window whose amplitude near the frequency
    reaches ACTIVE_FRACTION of its largest (centres; the record's ends when the first/last window is on)."""
    df = sg.frequency_hz[1] - sg.frequency_hz[0]
    near = np.abs(sg.frequency_hz - frequency_hz) <= df
    level = sg.amplitude[:, near].max(axis=1)
    on = np.flatnonzero(level >= ACTIVE_FRACTION * level.max())
    a, b = int(on[0]), int(on[-1])
    start = float(t_s[0]) if a == 0 else float(sg.time_s[a])
    stop = float(t_s[-1]) if b == len(sg.time_s) - 1 else float(sg.time_s[b])
    if stop - start < window_s / 2:  # a short burst: its one window
        start, stop = float(sg.time_s[a]) - window_s / 2, float(sg.time_s[b]) + window_s / 2
    return start, stop


@dataclass
class _Tone:
    """A tone while the search runs (refitted at the end)."""

    span: tuple[float, float]
    fit: SineFit
    method: str
    welch_amplitude: float
    noise_floor: float
    false_alarm_probability: float


def _fit(t_s: np.ndarray, r: np.ndarray, f0: float, resolution_hz: float) -> tuple[SineFit, str]:
    try:
        fit = fit_sine(t_s, r, initial_frequency_hz=f0)
        if abs(fit.frequency_hz - f0) <= resolution_hz:
            return fit, "4-parameter fit"
    except StereoError:
        pass
    return fit_sine(t_s, r, frequency_hz=f0), "3-parameter fit at the spectral peak"


def _tone(fit: SineFit, t_s: np.ndarray, span: tuple[float, float]) -> np.ndarray:
    """The fitted tone (without its offset) within its active interval, 0 outside."""
    inside = (t_s >= span[0]) & (t_s <= span[1])
    return np.where(inside, fit.evaluate(t_s) - fit.offset, 0.0)


def _strongest(ws: WelchSpectrum, found: list[float]) -> int | None:
    """Index of the strongest significant local maximum not within 1.5 bins of a tone already found."""
    a = ws.amplitude
    f = ws.frequency_hz
    local = np.r_[False, (a[1:-1] >= a[:-2]) & (a[1:-1] >= a[2:]), False]
    ok = local & (a > ws.threshold) & (f >= 1.5 * ws.resolution_hz)
    for fk in found:
        ok &= np.abs(f - fk) > 1.5 * ws.resolution_hz
    if not ok.any():
        return None
    return int(np.flatnonzero(ok)[np.argmax(a[ok])])


def tone_peaks(t_s: np.ndarray, x: np.ndarray, *, samples: tuple[np.ndarray, np.ndarray] | None = None,
               false_alarm: float = 1e-3,
               sg: Spectrogram | None = None) -> tuple[list[Peak], WelchSpectrum]:
    """Significant tones of a uniform record (``t_s``, ``x``), strongest first, and its Welch spectrum
    (module doc). ``samples``: the measured (times, values) the uniform record was interpolated from; the
    sine fits use them (no interpolation bias), the spectra the uniform record. ``sg``: the record's
    :func:`time_frequency` if already computed."""
    x = np.asarray(x, float) - np.mean(x)
    ts, xs = samples if samples is not None else (t_s, x)
    xs = np.asarray(xs, float) - np.mean(xs)
    whole = welch(t_s, x, false_alarm=false_alarm)
    period = float(np.median(np.diff(t_s)))
    win = stft_window_s(float(t_s[-1] - t_s[0]) + period, period)
    resid, resid_s = x.copy(), xs.copy()
    found: list[_Tone] = []
    for _ in range(MAX_PEAKS):
        ws = welch(t_s, resid, false_alarm=false_alarm)
        k = _strongest(ws, [tone.fit.frequency_hz for tone in found])
        if k is None:
            break
        f0 = _refine_bin(ws, k)
        rsg = sg if not found and sg is not None else time_frequency(t_s, resid)
        span = _active_interval(rsg, f0, t_s, win)
        inside = (ts >= span[0]) & (ts <= span[1])
        fit, how = _fit(ts[inside], resid_s[inside], f0, ws.resolution_hz)
        resid -= _tone(fit, t_s, span)
        resid_s -= _tone(fit, ts, span)
        ratio2 = (ws.amplitude[k] / ws.noise_floor[k]) ** 2
        p_fa = min(1.0, len(ws.amplitude) * float(special.chdtrc(ws.dof, ws.dof * ratio2)))
        found.append(_Tone(span, fit, how, float(ws.amplitude[k]), float(ws.noise_floor[k]), p_fa))
    for i, tone in enumerate(found):  # refit each tone with every other one subtracted
        inside = (ts >= tone.span[0]) & (ts <= tone.span[1])
        others = xs - sum((_tone(g.fit, ts, g.span) for j, g in enumerate(found) if j != i),
                          np.zeros_like(xs))
        tone.fit, tone.method = _fit(ts[inside], others[inside], tone.fit.frequency_hz, whole.resolution_hz)
    peaks = [Peak(t.fit.frequency_hz, t.fit.frequency_std_hz, abs(t.fit.amplitude), t.fit.amplitude_std,
                  t.span[0], t.span[1], t.welch_amplitude, t.noise_floor, t.false_alarm_probability, t.method)
             for t in found]
    return [p for p in peaks if p.amplitude >= FIT_SIGNIFICANCE * p.amplitude_std], whole


def _refine_bin(ws: WelchSpectrum, k: int) -> float:
    """Frequency of a spectral peak: parabola through the log amplitudes of the bin and its neighbours."""
    a = np.log(np.maximum(ws.amplitude[k - 1:k + 2], 1e-300))
    den = a[0] - 2 * a[1] + a[2]
    shift = 0.5 * (a[0] - a[2]) / den if den < 0 else 0.0
    return float(ws.frequency_hz[k] + max(-0.5, min(0.5, shift)) * ws.resolution_hz)


def false_alarm_text(false_alarm: float) -> str:
    """How significance is stated in notes and reports."""
    return (f"peaks: significant above the Welch noise floor at a false-alarm probability of {false_alarm:g} "
            f"per spectrum (χ² test, Bonferroni over the bins); amplitudes from sine fits over each tone's "
            f"active interval, the other tones subtracted")

