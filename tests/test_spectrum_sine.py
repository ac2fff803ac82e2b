"""Spectrum (amplitude-correct DFT, interpolated peak, STFT) and IEEE 1057 sine fits against known tones."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig.stereo.errors import (
    InputArrayError,
    NonMonotonicTimestampsError,
    NonUniformSamplingError,
    TooFewSamplesError,
)
from rig.stereo.sinefit import fit_sine, sliding_sine_fit
from rig.stereo.spectrum import spectrum, stft

FS_HZ = 60.0


def _tone(f_hz, amp, *, n=600, phase=0.4, offset=3.0, sigma=0.0, seed=0):
    t = np.arange(n) / FS_HZ + 12.3
    rng = np.random.default_rng(seed)
    return t, amp * np.cos(2 * np.pi * f_hz * t + phase) + offset + rng.normal(0, sigma, n)


def _crb_frequency_std_hz(amp, sigma, n, duration_s):
    """Cramér–Rao bound of the frequency of a real tone in white noise (Kay): var ω = 24σ²/(A²N(N²−1)Ts²)."""
    ts = duration_s / (n - 1)
    return np.sqrt(24 * sigma**2 / (amp**2 * n * (n**2 - 1) * ts**2)) / (2 * np.pi)


@pytest.mark.parametrize("window", ["rect", "hann", "flattop", "blackmanharris"])
@pytest.mark.parametrize("f_hz", [3.5, 10.0, 10.037, 25.0])
def test_interpolated_peak_is_exact_for_a_clean_tone_between_bins(window, f_hz):
    t, x = _tone(f_hz, 2.5)
    sp = spectrum(t, x, window=window)
    # Remaining error: leakage of the negative-frequency image 2f away. The rectangular window's side lobes
    # fall as 1/(π·k) (k = 2f·duration bins) and shift the peak by a comparable fraction of a bin; the
    # other windows' side lobes fall at least as 1/k³.
    k = 2 * f_hz * (t[-1] - t[0])
    leak = 1 / (np.pi * k) if window == "rect" else 1 / (np.pi * k) ** 3 + 1e-6
    assert sp.peak_frequency_hz == pytest.approx(f_hz, abs=2 * leak * sp.resolution_hz)
    assert sp.peak_amplitude == pytest.approx(2.5, rel=2 * leak)


def test_bin_amplitudes_show_the_textbook_scalloping_loss_at_half_a_bin():
    n = 600
    f_half = (100 + 0.5) * FS_HZ / n
    t, x = _tone(f_half, 1.0, n=n, offset=0.0)
    loss = {w: 1 - spectrum(t, x, window=w).amplitude[100] for w in ("rect", "hann", "flattop")}
    # Harris 1978: 3.92 dB, 1.42 dB, ≈0.01 dB.
    assert loss["rect"] == pytest.approx(1 - 10 ** (-3.92 / 20), abs=3e-3)
    assert loss["hann"] == pytest.approx(1 - 10 ** (-1.42 / 20), abs=3e-3)
    assert abs(loss["flattop"]) < 2e-3


@pytest.mark.parametrize("f_hz", [3.5, 10.0])
def test_frequency_error_on_a_10_s_record_meets_the_5_millihertz_target_and_the_noise_floor(f_hz):
    amp, sigma = 1.0, 0.1
    t, x = _tone(f_hz, amp, sigma=sigma, seed=int(f_hz * 10))
    floor = _crb_frequency_std_hz(amp, sigma, t.size, t[-1] - t[0])
    fit = fit_sine(t, x)
    assert abs(fit.frequency_hz - f_hz) <= 5 * floor
    assert abs(fit.frequency_hz - f_hz) <= 0.005
    assert fit.frequency_std_hz == pytest.approx(floor, rel=0.2)
    sp = spectrum(t, x, window="hann")
    assert abs(sp.peak_frequency_hz - f_hz) <= max(10 * floor, 0.002)
    assert abs(fit.amplitude - amp) <= 5 * sigma * np.sqrt(2 / t.size)
    assert fit.amplitude_std == pytest.approx(sigma * np.sqrt(2 / t.size), rel=0.2)


def test_three_parameter_fit_recovers_phase_offset_and_evaluates_on_irregular_times():
    rng = np.random.default_rng(5)
    t = np.sort(rng.uniform(0, 4, 300))
    x = 0.7 * np.cos(2 * np.pi * 7.0 * (t - 2.0) - 1.1) - 4.0
    fit = fit_sine(t, x, frequency_hz=7.0, t_ref_s=2.0)
    assert (fit.amplitude, fit.phase_rad, fit.offset) == pytest.approx((0.7, -1.1, -4.0), abs=1e-9)
    assert fit.frequency_std_hz == 0.0
    np.testing.assert_allclose(fit.evaluate(t), x, atol=1e-9)


@settings(max_examples=30, deadline=None)
@given(
    f_hz=st.floats(0.8, 27.0),
    amp=st.floats(0.01, 100.0),
    phase=st.floats(-3.1, 3.1),
    offset=st.floats(-1e3, 1e3),
)
def test_four_parameter_fit_is_exact_on_noise_free_tones(f_hz, amp, phase, offset):
    t = np.arange(300) / FS_HZ
    x = amp * np.cos(2 * np.pi * f_hz * t + phase) + offset
    fit = fit_sine(t, x, t_ref_s=0.0)
    assert fit.frequency_hz == pytest.approx(f_hz, rel=1e-7)
    assert fit.amplitude == pytest.approx(amp, rel=1e-6)
    assert np.angle(np.exp(1j * (fit.phase_rad - phase))) == pytest.approx(0.0, abs=1e-5)


def test_sliding_fits_follow_a_linear_sweep_in_frequency_and_amplitude():
    t = np.arange(0, 20, 1 / FS_HZ)
    f0, rate = 2.0, 0.5  # Hz, Hz/s
    amp = 3.0 + 0.1 * t
    x = amp * np.sin(2 * np.pi * (f0 * t + 0.5 * rate * t**2))
    sl = sliding_sine_fit(t, x, window_s=2.0, step_s=1.0)
    f_true = f0 + rate * sl.time_s
    # The chirp model matches the sweep's phase exactly; the amplitude ramp (linear, symmetric about the
    # window centre) leaves a bias of second order only.
    np.testing.assert_allclose(sl.frequency_hz, f_true, atol=2e-4)
    # The rate feels the real tone's negative-frequency image most at the lowest frequency (5 periods).
    np.testing.assert_allclose(sl.frequency_rate_hz_s, rate, atol=3e-3)
    np.testing.assert_allclose(sl.amplitude, 3.0 + 0.1 * sl.time_s, rtol=1e-3)
    # A plain four-parameter fit is biased by the quadratic phase π·rate·(W/2)² = 1.6 rad at the edges.
    plain = sliding_sine_fit(t, x, window_s=2.0, step_s=1.0, chirp=False)
    assert np.max(np.abs(plain.frequency_hz - f_true)) > 5 * np.max(np.abs(sl.frequency_hz - f_true))
    spg = stft(t, x, window_s=4.0, step_s=2.0)
    np.testing.assert_allclose(spg.peak_frequency_hz, f0 + rate * spg.time_s, atol=0.02)
    assert spg.amplitude.shape == (spg.time_s.size, spg.frequency_hz.size)


def test_bad_inputs_raise_specific_errors():
    t, x = _tone(5.0, 1.0, n=100)
    with pytest.raises(NonMonotonicTimestampsError, match=r"t_s\[51\]"):
        spectrum(np.r_[t[:51], t[50], t[52:]], x)
    with pytest.raises(TooFewSamplesError):
        spectrum(t[:5], x[:5])
    with pytest.raises(NonUniformSamplingError):
        spectrum(t + np.r_[0, 0.3 / FS_HZ, np.zeros(98)], x)
    with pytest.raises(InputArrayError, match="window"):
        spectrum(t, x, window="kaiser")
    with pytest.raises(InputArrayError, match="gaps"):
        spectrum(np.delete(t, 40), np.delete(x, 40))
    with pytest.raises(TooFewSamplesError, match="6 samples"):
        fit_sine(t[:5], x[:5])
    with pytest.raises(TooFewSamplesError, match="exceeds"):
        sliding_sine_fit(t, x, window_s=10.0, step_s=1.0)
    with pytest.raises(InputArrayError, match="NaN"):
        fit_sine(t, np.r_[x[:-1], np.nan])
    with pytest.raises(InputArrayError, match="frequency_hz"):
        fit_sine(t, x, frequency_hz=-1.0)


@settings(max_examples=60, deadline=None)
@given(n=st.integers(0, 5000), window=st.sampled_from(["hann", "flattop", "blackmanharris"]))
def test_windows_are_scipys_bit_for_bit(n, window):
    # rig.stereo.spectrum computes the windows itself (importing scipy.signal costs ≈ 1 CPU-s per process)
    from scipy.signal import windows

    from rig.stereo.spectrum import window_weights

    ours, scipys = window_weights(window, n), getattr(windows, window)(n, sym=False)
    assert ours.dtype == scipys.dtype and ours.shape == scipys.shape
    assert np.array_equal(ours, scipys)
