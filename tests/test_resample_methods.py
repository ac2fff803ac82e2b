"""Resampling: the exact linear-interpolation gain (the paper's loss), cubic and band-limited accuracy."""

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
from rig.stereo.resample import bandlimited, bridging_filter, resample
from rig.stereo.sinefit import fit_sine

FS_HZ = 60.0
T_S = 1 / FS_HZ


def _gain_linear(alpha, f_hz):
    """|H(α)| = sqrt(1 − 4α(1−α)·sin²(πf/fs)) (metrology notes §5)."""
    return np.sqrt(1 - 4 * alpha * (1 - alpha) * np.sin(np.pi * f_hz / FS_HZ) ** 2)


def _fit_gain(method, f_hz, alpha, *, n=720, trim=40):
    t = np.arange(n) * T_S
    x = np.sin(2 * np.pi * f_hz * t + 0.2)
    t_dst = t[trim:-trim] + alpha * T_S
    y = resample(t, x, t_dst, method)
    fit = fit_sine(t_dst, y, frequency_hz=f_hz, t_ref_s=0.0)
    # phase of the ideal signal at t_dst is the same sinusoid: ideal gain 1, phase 0.2 − π/2 (cos form)
    return fit.amplitude, np.angle(np.exp(1j * (fit.phase_rad - (0.2 - np.pi / 2))))


@pytest.mark.parametrize("f_hz", [1.0, 3.5, 10.0, 15.0, 20.0, 25.0, 29.0])
@pytest.mark.parametrize("alpha", [0.0, 0.1, 0.25, 0.5, 0.8])
def test_linear_interpolation_gain_and_phase_equal_the_exact_formula(f_hz, alpha):
    amp, phase = _fit_gain("linear", f_hz, alpha)
    theta = 2 * np.pi * f_hz / FS_HZ
    H = (1 - alpha) + alpha * np.exp(1j * theta)
    assert amp == pytest.approx(_gain_linear(alpha, f_hz), abs=1e-9)
    # H multiplies the delayed sinusoid: phase of H minus the ideal delay αθ.
    assert phase == pytest.approx(np.angle(H) - alpha * theta, abs=1e-9)


@pytest.mark.parametrize("f_hz", [3.5, 10.0, 25.0])
def test_cubic_beats_linear_and_bandlimited_is_within_one_percent_up_to_25_hz(f_hz):
    lin, _ = _fit_gain("linear", f_hz, 0.5)
    cub, _ = _fit_gain("cubic", f_hz, 0.5)
    bl, bl_phase = _fit_gain("bandlimited", f_hz, 0.5)
    assert abs(1 - cub) < abs(1 - lin)
    # Kaiser-windowed sinc, 65 taps, ~60 dB: pass band flat to ~1e-3 up to 0.47·fs.
    assert abs(1 - bl) < 2e-3
    assert abs(bl_phase) < 2e-3


def test_bandlimited_handles_irregular_rolling_shutter_instants():
    rng = np.random.default_rng(3)
    n = 900
    # Row-corrected instants: frame grid + a smoothly varying row delay up to 0.4 frame + 30 ppm drift.
    tau = np.arange(n) * T_S * (1 + 30e-6)
    t_src = tau + 0.4 * T_S * (0.5 + 0.5 * np.sin(2 * np.pi * 0.3 * tau + rng.uniform(0, 6)))
    f_hz = 25.0

    def signal(t):
        return 500.0 + 40.0 * np.sin(2 * np.pi * f_hz * t) + 10 * np.sin(2 * np.pi * 3.0 * t)

    t_dst = np.arange(60, n - 60) * T_S + 0.37 * T_S
    y = resample(t_src, signal(t_src), t_dst, "bandlimited")
    err = y - signal(t_dst)
    # Amplitude 40 at 0.42·fs: the kernel's pass-band ripple (~1e-3) bounds the error.
    assert np.max(np.abs(err)) < 40 * 2e-3
    lin = resample(t_src, signal(t_src), t_dst, "linear")
    assert np.max(np.abs(lin - signal(t_dst))) > 10 * np.max(np.abs(err))


def test_dropped_frames_only_disturb_their_neighbourhood_in_bandlimited_resampling():
    n = 600
    t_all = np.arange(n) * T_S
    t_all = t_all + 0.2 * T_S * np.sin(2 * np.pi * 0.5 * t_all)  # row-corrected jitter
    keep = np.ones(n, bool)
    keep[[200, 401, 402]] = False

    def signal(t):
        return 100.0 + 5.0 * np.sin(2 * np.pi * 10.0 * t)

    t_dst = np.arange(60, n - 60) * T_S + 0.37 * T_S
    dist = np.abs(t_dst[:, None] - t_all[[200, 401]][None, :]).min(axis=1) / T_S
    err = {
        m: np.abs(resample(t_all[keep], signal(t_all[keep]), t_dst, m) - signal(t_dst))
        for m in ("cubic", "bandlimited")
    }
    # Beyond the kernel's half-width the dropped frames' influence is a 1/d tail of a cubic-spline error.
    assert err["bandlimited"][dist > 32].max() < 5.0 * 1e-3
    # Next to the gap nothing knows the missing sample; band-limited is no worse than cubic there.
    assert err["bandlimited"][dist < 2].max() < 1.2 * err["cubic"][dist < 2].max()


def test_shapes_nan_outside_and_exact_at_source_instants():
    t = np.arange(50) * T_S
    vals = np.column_stack([np.sin(t), np.cos(3 * t)])
    t_dst = np.r_[-0.1, t[10], t[20] + 0.001, t[-1] + 0.5]
    for method in ("linear", "cubic", "bandlimited"):
        out = resample(t, vals, t_dst, method)
        assert out.shape == (4, 2)
        assert np.isnan(out[0]).all() and np.isnan(out[3]).all()
        np.testing.assert_allclose(out[1], vals[10], atol=1e-9)
    assert resample(t, vals[:, 0], t_dst, "cubic").shape == (4,)


@settings(max_examples=40, deadline=None)
@given(
    slope=st.floats(-100, 100),
    intercept=st.floats(-1e3, 1e3),
    frac=st.floats(0.0, 1.0),
)
def test_all_methods_reproduce_a_straight_line(slope, intercept, frac):
    t = np.arange(80) * T_S + 3.0
    x = intercept + slope * t
    t_dst = t[5:-5] + frac * T_S
    for method in ("linear", "cubic", "bandlimited"):
        y = resample(t, x, t_dst, method)
        tol = 1e-8 * (1 + abs(intercept) + abs(slope))
        np.testing.assert_allclose(y, intercept + slope * t_dst, atol=tol)


def test_bad_inputs_raise_specific_errors():
    t = np.arange(20) * T_S
    x = np.sin(t)
    with pytest.raises(InputArrayError, match="method"):
        resample(t, x, t, "spline")
    with pytest.raises(NonMonotonicTimestampsError, match=r"t_src_s\[7\]"):
        resample(np.r_[t[:7], t[5], t[8:]], x, t)
    with pytest.raises(TooFewSamplesError):
        resample(t[:3], x[:3], t, "cubic")
    with pytest.raises(InputArrayError, match="rows"):
        resample(t, x[:-1], t)
    with pytest.raises(InputArrayError, match="NaN"):
        resample(t, np.r_[x[:-1], np.nan], t)
    bunched = t.copy()
    bunched[3] = t[2] + 0.1 * T_S  # two instants in one sampling slot: no stable band-limited fit
    with pytest.raises(NonUniformSamplingError, match="deviate"):
        resample(bunched, x, t, "bandlimited")


def _bridged_record(gap_lengths, spacings, *, f1_hz, f2_hz, jitter_hz, n=400):
    """Row-jittered instants with gaps (1–3 slots, ``spacings`` apart) from slot 40 on; a two-tone signal."""
    t_all = np.arange(n) * T_S
    t_all = t_all + 0.2 * T_S * np.sin(2 * np.pi * jitter_hz * t_all)
    keep = np.ones(n, bool)
    pos = 40
    for length, spacing in zip(gap_lengths, spacings, strict=False):
        if pos + length >= n - 40:
            break
        keep[pos : pos + length] = False
        pos += length + spacing

    def signal(t):
        return 100.0 + 50.0 * np.sin(2 * np.pi * f1_hz * t) + 5.0 * np.cos(2 * np.pi * f2_hz * t + 0.3)

    return t_all, keep, signal


def test_the_noise_gain_of_a_bridged_reconstruction_is_its_variance_for_unit_white_noise():
    rng = np.random.default_rng(7)
    t_all, keep, signal = _bridged_record([1, 3, 2, 1, 3, 2] * 12, [2, 5, 9, 3] * 18, f1_hz=7.0,
                                          f2_hz=14.0, jitter_hz=0.5)
    t_src, t_dst = t_all[keep], np.arange(40, t_all.size - 40) * T_S + 0.37 * T_S
    taps, _ = bridging_filter(t_src, signal(t_src), max_gap_samples=3)
    bridge = {"bridge_max_samples": 3, "bridge_filter": taps}
    clean, gain = bandlimited(t_src, signal(t_src), t_dst, noise_gain=True, **bridge)
    trials = np.array([bandlimited(t_src, signal(t_src) + rng.normal(0.0, 1.0, t_src.size), t_dst, **bridge)
                       - clean for _ in range(400)])
    ratio = trials.var(axis=0) / gain  # each a variance estimate of 400 samples: ± 7 % (1 σ)
    assert np.median(ratio) == pytest.approx(1.0, abs=0.05)
    assert np.all((ratio > 0.65) & (ratio < 1.35))
    assert np.ptp(gain) > 0.2  # the bridged gaps change the gain near them (the check is not vacuous)


def _bridged_track(rng: np.random.Generator) -> tuple[float, float, float, float]:
    """One marker track (a tone of 3–12 Hz with a harmonic of 0–5 px, row-time jitter of ±0.05 frame at the
    motion's frequency, σ = 0.1 px) losing frames in 60 gaps of 1–3 frames, 2–11 apart (≈ 20–30 % lost),
    bridged by its own prediction filter (``bridging_filter``, fitted to the noisy gappy track): (fraction
    lost, RMS of the errors at other instants in units of the stated σ·√(noise gain), largest noise gain,
    the filter's prediction gain)."""
    gaps = [(int(rng.integers(1, 4)), int(rng.integers(2, 12))) for _ in range(60)]
    f_hz, harmonic_px = float(rng.uniform(3.0, 12.0)), float(rng.uniform(0.0, 5.0))
    n, sigma_px = 240, 0.1
    slots = np.arange(n)
    keep = np.ones(n, bool)
    pos = 2
    for length, spacing in gaps:
        if pos + length >= n - 2:
            break
        keep[pos : pos + length] = False
        pos += length + spacing

    def track(t):
        phase = 2 * np.pi * f_hz * t
        return np.column_stack([300 + 60 * np.cos(phase) + harmonic_px * np.cos(2 * phase + 1.0),
                                500 + 40 * np.sin(phase)])

    t_exposed = slots * T_S + 0.05 * T_S * np.sin(2 * np.pi * f_hz * slots * T_S + 0.4)
    uv = track(t_exposed[keep]) + rng.normal(0.0, sigma_px, (int(keep.sum()), 2))
    taps, prediction_gain = bridging_filter(slots[keep] * T_S, uv, max_gap_samples=3)  # stamps: frames
    t_dst = np.arange(34, n - 34) * T_S + 0.3 * T_S
    bridged, gain = bandlimited(t_exposed[keep], uv, t_dst, noise_gain=True, bridge_max_samples=3,
                                bridge_filter=taps)
    z = (bridged - track(t_dst)) / (sigma_px * np.sqrt(gain))[:, None]
    return 1.0 - float(keep.mean()), float(np.sqrt(np.mean(z**2))), float(gain.max()), prediction_gain


def test_line_spectrum_tracks_bridged_by_their_own_prediction_filter_stay_within_the_stated_bounds():
    """200 random gappy tracks (:func:`_bridged_track`): each a line spectrum to the joint sync (prediction
    gain ≥ 10³), well-conditioned (noise gain ≤ 4), and their bridged errors noise-like as
    ``bridging_filter``'s docstring states them — measured over 800 such tracks (two other seeds): RMS in
    units of σ·√gain median 1.10, 95th percentile 1.46, largest 4.2 (an unlucky gap pattern: 1 track in ≈ 150
    above 2.5; the excess over 1 is the filter's model error). A distribution, not one bound per track: a
    hypothesis test asserting 2.5 per track found such a pattern (1-in-3 frames lost, 30 %: 3.2)."""
    rows = np.array([_bridged_track(np.random.default_rng([2026, k])) for k in range(200)])
    lost, rms, gain, prediction_gain = rows.T
    assert lost.min() > 0.15 and lost.max() < 0.35  # the regime the docstring states
    assert prediction_gain.min() >= 1e3
    assert gain.max() <= 4.0
    assert np.median(rms) <= 1.25
    assert np.quantile(rms, 0.95) <= 1.75
    assert rms.max() <= 6.0
