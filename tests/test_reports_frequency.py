"""Error versus frequency: sweep phase, per-bin amplitude and phase on exact data, interpolation theory."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import reports_synth as synth
from hypothesis import given, settings
from hypothesis import strategies as st

from reports import frequency
from reports.errors import ReportError


@settings(max_examples=60, deadline=None)
@given(f0=st.floats(0.1, 20), f1=st.floats(0.1, 30), duration=st.floats(0.5, 60), frac=st.floats(0, 1))
def test_sweep_phase_is_the_exact_integral_of_a_linear_ramp(f0, f1, duration, frac) -> None:
    sweep = {"profile": [[10.0, f0], [10.0 + duration, f1]]}
    t = 10.0 + frac * duration
    expected = 2 * np.pi * (f0 * (t - 10) + 0.5 * (f1 - f0) / duration * (t - 10) ** 2)
    assert frequency.sweep_phase_rad(sweep, np.array([t]))[0] == pytest.approx(expected, rel=1e-12, abs=1e-9)


def test_sweep_phase_is_continuous_across_knots_and_outside() -> None:
    sweep = {"profile": [[0.0, 1.0], [2.0, 3.0], [5.0, 3.0]]}
    eps = 1e-9
    for knot in (2.0, 5.0):
        lo, hi = frequency.sweep_phase_rad(sweep, np.array([knot - eps, knot + eps]))
        assert hi - lo == pytest.approx(2 * np.pi * 3.0 * 2 * eps, abs=1e-12)
    # before the profile the first frequency holds
    assert frequency.sweep_phase_rad(sweep, np.array([-1.0]))[0] == pytest.approx(-2 * np.pi)


@pytest.fixture(scope="module")
def bins_by_method():
    sweep = synth.sweep_event()
    return {
        m: frequency.amplitude_by_bin(
            frequency.sweep_samples(synth.make_tracks(m), sweep), sweep, sync_method=m
        )
        for m in synth.SWEEP_COEFFS
    }


def test_only_the_oscillating_tracks_are_analysed(bins_by_method) -> None:
    for bins in bins_by_method.values():
        assert sorted(bins["track"].unique()) == ["sweep#0", "sweep#1"]  # the static sweep#7 is left out
        assert len(bins) == 2 * len(synth.SWEEP_FREQS_HZ)


def test_amplitude_error_per_bin_equals_the_injected_one(bins_by_method) -> None:
    for method, bins in bins_by_method.items():
        f = bins["frequency_hz"].to_numpy(float)
        np.testing.assert_allclose(f, np.tile(synth.SWEEP_FREQS_HZ, 2), atol=1e-12)
        expected = synth.sweep_error_pct(f, method)
        np.testing.assert_allclose(bins["amplitude_error_pct"], expected, atol=1e-7)
        np.testing.assert_allclose(
            bins["amplitude_meas_mm"], synth.SWEEP_AMPLITUDE_MM * (1 + expected / 100), atol=1e-9
        )


def test_phase_shows_the_injected_delay(bins_by_method) -> None:
    for method, bins in bins_by_method.items():
        tau = synth.SWEEP_DELAY_S[method]
        for _, g in bins.groupby("track"):
            f = g["frequency_hz"].to_numpy(float)
            np.testing.assert_allclose(g["phase_deg"], -360.0 * tau * (f - f[0]), atol=1e-6)


def test_measured_frequency_per_bin(bins_by_method) -> None:
    bins = bins_by_method["trajectory"]
    # 3 s of a steady sine: Lomb–Scargle peak on a 0.005 Hz grid with parabolic refinement
    np.testing.assert_allclose(bins["measured_frequency_hz"], bins["frequency_hz"], atol=0.005)


def test_noise_gives_a_consistent_amplitude_uncertainty() -> None:
    sweep = synth.sweep_event()
    tracks = synth.make_tracks("trajectory")
    rng = np.random.default_rng(11)
    sigma = 0.05
    moving = tracks["segment"] == "sweep"
    tracks.loc[moving, "x_mm"] += rng.normal(0, sigma, moving.sum())
    bins = frequency.amplitude_by_bin(frequency.sweep_samples(tracks, sweep), sweep, sync_method="trajectory")
    # LS theory: u(A) ≈ σ·√(2/n) for n samples over whole cycles
    n = bins["n_samples"].to_numpy(float)
    np.testing.assert_allclose(bins["u_amplitude_mm"], sigma * np.sqrt(2 / n), rtol=0.25)
    z = (bins["amplitude_error_pct"] - synth.sweep_error_pct(bins["frequency_hz"], "trajectory")) / bins[
        "u_amplitude_error_pct"
    ]
    assert np.all(np.abs(z) < 4.5)  # 46 bins: a 4.5σ excursion has probability ≈ 3e-4
    assert 0.6 < np.std(z) < 1.4  # the stated uncertainty matches the scatter (46 bins: sd of std ≈ 0.1)


@pytest.mark.parametrize(
    ("f_hz", "alpha", "expected_pct"),
    [(3.5, 0.5, -1.67), (10, 0.5, -13.4), (15, 0.5, -29.3), (20, 0.5, -50.0), (30, 0.5, -100.0)],
)
def test_linear_interpolation_gain_matches_the_notes_table(f_hz, alpha, expected_pct) -> None:
    assert frequency.theory_linear_pct(np.array(f_hz), 60.0, alpha) == pytest.approx(expected_pct, abs=0.05)


def test_linear_interpolation_midpoint_gain_is_cosine() -> None:
    f = np.linspace(0, 29, 50)
    np.testing.assert_allclose(
        frequency.linear_interp_gain(f, 60.0, 0.5), np.cos(np.pi * f / 60.0), atol=1e-12
    )
    np.testing.assert_allclose(frequency.linear_interp_gain(f, 60.0, 0.0), 1.0)


def test_mean_over_alpha_is_the_numerical_average() -> None:
    f = np.array([3.5, 10.0, 20.0])
    alphas = (np.arange(200000) + 0.5) / 200000
    brute = np.array([np.mean(frequency.linear_interp_gain(fi, 60.0, alphas)) for fi in f])
    np.testing.assert_allclose(frequency.theory_linear_pct(f, 60.0), 100 * (brute - 1), atol=1e-6)
    # small-f limit θ²/12 (notes §5): at 3.5 Hz ≈ −1.11 %
    assert frequency.theory_linear_pct(np.array(3.5), 60.0) == pytest.approx(-1.11, abs=0.02)


def test_fractional_delay() -> None:
    assert frequency.fractional_delay(0.0041, 60.0) == pytest.approx(0.246)
    assert frequency.fractional_delay(-0.0041, 60.0) == pytest.approx(0.754)


def test_bad_sweep_fields_raise() -> None:
    with pytest.raises(ReportError, match="profile"):
        frequency.sweep_phase_rad({"profile": [[0, 1]]}, np.array([0.0]))
    with pytest.raises(ReportError, match="must not decrease"):
        frequency.profile_frequency_hz({"profile": [[1, 1], [0, 2]]}, np.array([0.0]))
    with pytest.raises(ReportError, match="axis"):
        frequency.sweep_samples(
            synth.make_tracks("linear").head(0), dict(synth.sweep_event(), axis=[0, 0, 0])
        )
    with pytest.raises(ReportError, match="bin_hz"):
        frequency.amplitude_by_bin(None, synth.sweep_event(), sync_method="x", bin_hz=0)


def test_linear_interpolation_of_a_continuous_sweep_matches_theory() -> None:
    """The paper's mechanism end to end: a continuous chirp sampled at 60 fps and linearly interpolated at a
    fractional delay α loses amplitude by |H(α)| (notes §5); the per-bin estimate must match it within the
    within-bin curvature of |H| plus 4 standard uncertainties of the fit."""
    fs, alpha, amp = 60.0, 0.3, 5.0
    sweep = {
        "t_start_s": 0.0,
        "t_stop_s": 50.0,
        "amplitude_mm": amp,
        "axis": [0.0, 0.0, 1.0],
        "profile": [[0.0, 0.5], [50.0, 25.5]],
    }
    t_a = np.arange(0, 50 * fs + 1) / fs  # camera A instants
    t_b = t_a + alpha / fs  # camera B samples α later; interpolating B back onto A's instants
    x_b = amp * np.sin(frequency.sweep_phase_rad(sweep, t_b))
    x_hat = np.empty_like(t_a)
    x_hat[1:] = (1 - alpha) * x_b[1:] + alpha * x_b[:-1]  # x(t) from B's samples at t − (1−α)/fs and t + α/fs
    x_hat[0] = x_b[0]
    rng = np.random.default_rng(2)
    sigma = 0.01
    tracks = synth.make_tracks("linear").head(0)
    tracks = pd.DataFrame(
        {
            "segment": "sweep",
            "time_s": t_a[1:],
            "track_id": 0,
            "x_mm": 0.0,
            "y_mm": 0.0,
            "z_mm": x_hat[1:] + rng.normal(0, sigma, len(t_a) - 1),
        }
    )
    bins = frequency.amplitude_by_bin(frequency.sweep_samples(tracks, sweep), sweep, sync_method="linear")
    assert len(bins) >= 24
    f = bins["frequency_hz"].to_numpy(float)
    # interpolating between samples t−(1−α)T and t+αT: the weights (1−α, α) sit at fractional position 1−α
    theory = frequency.theory_linear_pct(f, fs, 1 - alpha)
    h = 0.01
    curvature = (
        np.abs(
            frequency.theory_linear_pct(f + h, fs, alpha)
            - 2 * theory
            + frequency.theory_linear_pct(f - h, fs, alpha)
        )
        / h**2
    )
    tol = 0.5 * curvature * (1.0**2 / 12) + 4 * bins["u_amplitude_error_pct"].to_numpy(float) + 1e-6
    np.testing.assert_array_less(np.abs(bins["amplitude_error_pct"].to_numpy(float) - theory), tol)
    assert theory.min() < -10  # the test spans a large, quadratically growing loss


def test_a_step_in_the_profile_is_allowed_and_integrated_exactly() -> None:
    sweep = {"profile": [[0.0, 2.0], [1.0, 2.0], [1.0, 5.0], [3.0, 5.0]]}
    phi = frequency.sweep_phase_rad(sweep, np.array([0.5, 1.0, 2.0, 3.0]))
    np.testing.assert_allclose(phi / (2 * np.pi), [1.0, 2.0, 7.0, 12.0], atol=1e-12)
    with pytest.raises(ReportError, match="non-finite"):
        frequency.sweep_phase_rad({"profile": [[0.0, 1.0], [1.0, None]]}, np.array([0.5]))


def test_a_bin_names_the_same_frequencies_for_every_track() -> None:
    """A track seen only from later in the sweep (a marker lost at first) shares bin numbers with the rest."""
    sweep = synth.sweep_event()
    samples = frequency.sweep_samples(synth.make_tracks("trajectory"), sweep)
    late = samples["track"] == "sweep#1"
    t_late_s = samples.loc[late, "time_s"]
    samples = samples[~late | (t_late_s > t_late_s.quantile(0.3))]
    bins = frequency.amplitude_by_bin(samples, sweep, sync_method="trajectory")
    first = bins.groupby("track")["frequency_lo_hz"].min()
    assert first["sweep#1"] > first["sweep#0"]  # the case under test: the tracks start in different bins
    per_bin = bins.groupby("bin")[["frequency_lo_hz", "frequency_hi_hz"]].nunique()
    assert (per_bin == 1).all().all()
    np.testing.assert_array_equal(bins["bin"], np.round(bins["frequency_lo_hz"] / frequency.DEFAULT_BIN_HZ))
