"""Multi-tone and non-stationary displacement records: every tone found with its amplitude, the spectrum kept.

Records at 60 samples/s with white noise σ = 0.01 mm along one axis. The amplitude tolerance is the fit's
own standard uncertainty (4σ, from its residuals) — at this noise ≈ 0.1 % of the amplitudes, inside the
issue's 1 % (to 10 Hz) / 2 % (to 25 Hz); the frequency's is 4σ of the fit.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig.deploy.series import summarise
from rig.deploy.spectra import chi2_median, time_frequency, tone_peaks, welch
from rig.stereo.spectrum import window_weights

FS_HZ = 60.0
SIGMA_MM = 0.01


def _displacement(t: np.ndarray, d: np.ndarray) -> pd.DataFrame:
    return pd.DataFrame({"time_s": t, "track_id": 7, "role": "target", "dx_mm": 0.0 * d, "dy_mm": 0.0 * d,
                         "dz_mm": d, "x_mm": 0.0, "y_mm": 0.0, "z_mm": d})


def _check(peaks: pd.DataFrame, truth: list[tuple[float, float]]) -> None:
    assert len(peaks) == len(truth), peaks[["frequency_hz", "amplitude_mm"]]
    for f, a in truth:
        p = peaks.iloc[int(np.argmin(np.abs(peaks["frequency_hz"] - f)))]
        assert abs(p["frequency_hz"] - f) <= 4 * p["frequency_std_hz"] + 1e-9, (f, p["frequency_hz"])
        assert abs(p["amplitude_mm"] - a) <= 4 * p["amplitude_std_mm"], (f, p["amplitude_mm"], a)
        assert abs(p["amplitude_mm"] - a) <= (0.01 if f <= 10 else 0.02) * a
        assert p["false_alarm_probability"] < 1e-3


def test_three_simultaneous_tones_are_each_found_with_their_amplitude() -> None:
    rng = np.random.default_rng(4)
    t = np.arange(int(20 * FS_HZ)) / FS_HZ
    truth = [(3.5, 2.0), (10.0, 1.0), (20.0, 0.5)]
    d = sum(a * np.sin(2 * np.pi * f * t + k) for k, (f, a) in enumerate(truth)) + rng.normal(0, SIGMA_MM,
                                                                                           t.size)
    notes: list[str] = []
    res = summarise(_displacement(t, d), [], notes=notes)
    _check(res.peaks, truth)
    row = res.summary.iloc[0]
    assert row["n_peaks"] == 3 and abs(row["dominant_frequency_hz"] - 3.5) < row["resolution_hz"]
    assert len(res.spectra) and set(res.spectra.columns) >= {"frequency_hz", "amplitude_mm", "noise_floor_mm"}
    assert len(res.time_frequency) and any("false-alarm probability" in n for n in notes)


def test_successive_tones_get_their_own_interval_and_amplitude() -> None:
    rng = np.random.default_rng(5)
    t = np.arange(int(20 * FS_HZ)) / FS_HZ
    truth = [(3.5, 2.0), (10.0, 2.0), (20.0, 2.0), (25.0, 2.0)]
    d = np.zeros_like(t)
    for i, (f, a) in enumerate(truth):
        on = (t >= 5 * i) & (t < 5 * (i + 1))
        d[on] = a * np.sin(2 * np.pi * f * t[on])
    d += rng.normal(0, SIGMA_MM, t.size)
    res = summarise(_displacement(t, d), [])
    _check(res.peaks, truth)
    for i, (f, _) in enumerate(truth):  # each tone's interval lies within the 5 s it played
        p = res.peaks.iloc[int(np.argmin(np.abs(res.peaks["frequency_hz"] - f)))]
        assert 5 * i - 1e-9 <= p["t_start_s"] < p["t_stop_s"] <= 5 * (i + 1), (f, p["t_start_s"])
        assert p["t_stop_s"] - p["t_start_s"] > 3.0


def test_a_chirp_is_followed_by_the_time_frequency_table() -> None:
    rng = np.random.default_rng(6)
    t = np.arange(int(20 * FS_HZ)) / FS_HZ
    f0, rate = 2.0, 0.9  # Hz, Hz/s: 2 → 20 Hz
    d = 2.0 * np.sin(2 * np.pi * (f0 * t + 0.5 * rate * t**2)) + rng.normal(0, SIGMA_MM, t.size)
    sg = time_frequency(t, d)
    bin_hz = sg.frequency_hz[1] - sg.frequency_hz[0]
    assert np.all(np.abs(sg.peak_frequency_hz - (f0 + rate * sg.time_s)) <= bin_hz)
    res = summarise(_displacement(t, d), [])
    assert len(res.spectra) and len(res.time_frequency) == sg.amplitude.size


def test_a_failing_sine_fit_keeps_the_spectrum_and_the_peaks() -> None:
    """Two equal tones: the single-tone fit is not the point; the spectrum and both peaks must stand."""
    rng = np.random.default_rng(7)
    t = np.arange(int(6 * FS_HZ)) / FS_HZ
    d = np.sin(2 * np.pi * 4 * t) + np.sin(2 * np.pi * 9 * t + 1) + rng.normal(0, SIGMA_MM, t.size)
    res = summarise(_displacement(t, d), [])
    assert np.isfinite(res.summary.iloc[0]["dominant_frequency_hz"]) and len(res.spectra)
    _check(res.peaks, [(4.0, 1.0), (9.0, 1.0)])


@pytest.mark.parametrize("seed", range(20))
def test_noise_alone_shows_no_peak(seed: int) -> None:
    """False-alarm probability 1e-3 per spectrum: 20 noise records, each must come out empty (P(any false
    peak) ≈ 2 %; the seeds are fixed)."""
    rng = np.random.default_rng(100 + seed)
    t = np.arange(int(10 * FS_HZ)) / FS_HZ
    peaks, ws = tone_peaks(t, rng.normal(0, SIGMA_MM, t.size))
    assert peaks == []
    # the floor is white noise's mean amplitude per bin under this scaling: 2σ·sqrt(Σw²)/Σw (Hann segments
    # of a quarter record); its estimate scatters by ≈ 1/sqrt(ν · bins in the median) ≈ 10 %
    w = window_weights("hann", len(t) // 4)
    assert np.median(ws.noise_floor) == pytest.approx(2 * SIGMA_MM * np.sqrt(np.sum(w**2)) / w.sum(), rel=0.2)


@settings(max_examples=40, deadline=None)
@given(st.floats(0.01, 100.0), st.integers(2, 60), st.floats(-np.pi, np.pi), st.integers(256, 1024))
def test_welch_reads_the_peak_amplitude_of_a_tone_on_a_bin(amplitude, k, phase, n):
    """The stated scaling: a steady tone centred on a Welch bin shows its peak amplitude there."""
    seg = max(16, n // 4)
    k = min(k, seg // 2 - 2)
    t = np.arange(n) / FS_HZ
    x = amplitude * np.cos(2 * np.pi * k / (seg / FS_HZ) * t + phase)
    ws = welch(t, x)
    assert ws.amplitude[k] == pytest.approx(amplitude, rel=1e-9)
    assert ws.resolution_hz == pytest.approx(FS_HZ / seg)


@settings(max_examples=80, deadline=None)
@given(dof=st.floats(0.5, 400.0), q=st.floats(1e-12, 1.0 - 1e-9), x=st.floats(0.0, 5000.0))
def test_chi2_functions_are_scipy_stats_bit_for_bit(dof, q, x):
    # the Welch significance uses scipy.special's χ² functions (scipy.stats costs ≈ 0.8 CPU-s to import)
    from scipy import special, stats

    assert chi2_median(dof) == float(stats.chi2.median(dof))
    assert float(special.chdtri(dof, q)) == float(stats.chi2.isf(q, dof))
    assert float(special.chdtrc(dof, x)) == float(stats.chi2.sf(x, dof))
