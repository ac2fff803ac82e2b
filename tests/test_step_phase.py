"""Phase per steady step (reports.step_phase) against the twin's truth: a twin oscillator driven through a
staircase whose FREQ changes land at random instants inside their recorded brackets, sampled at 60 fps
with a known delay and Gaussian noise. Tolerances from the noise: each step's stated phase, amplitude and
frequency within 4 × their own stated standard uncertainty of the truth (the delay the samples were taken
with; the twin's amplitude; the step's frequency)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.sim.oscillator import OscillatorBody
from reports import frequency, step_phase
from reports.phase import ReferenceResolution

FS_HZ = 60.0
AMP_MM = 2.0


def _staircase(rng: np.random.Generator, freqs: list[float], step_s: float, bracket_s: float,
               ) -> tuple[dict, OscillatorBody]:
    """A sweep event of a generator staircase from its phase restart at t = 10 s, and the twin oscillator
    whose frequency changed at a uniform instant inside each recorded bracket."""
    body = OscillatorBody("shaker", amplitude_mm=AMP_MM, initial_hz=freqs[0], t_origin_s=10.0)
    body.set_frequency(10.0, freqs[0], phase_rad=0.0)
    profile, brackets = [[10.0, freqs[0]]], []
    for k, (f_prev, f) in enumerate(itertools.pairwise(freqs), start=1):
        sent = 10.0 + k * step_s
        done = sent + bracket_s
        body.set_frequency(sent + rng.uniform(0, bracket_s), f)
        brackets.append([sent, done])
        mid = 0.5 * (sent + done)
        profile += [[mid, f_prev], [mid, f]]
    t_end = 10.0 + len(freqs) * step_s
    profile.append([t_end, freqs[-1]])
    sweep = {"t_start_s": 10.0, "t_stop_s": t_end, "amplitude_mm": AMP_MM, "axis": [0.0, 0.0, 1.0],
             "profile": profile, "segment": "sweep", "body": "shaker", "phase_origin_s": [10.0, 10.0],
             "phase_origin": "PHASe:SYNChronize of the timing fiducial", "step_brackets_s": brackets}
    return sweep, body


def _tracks(rng: np.random.Generator, body: OscillatorBody, t_end: float, *, delay_s: float,
            sigma_mm: float, n_tracks: int = 3) -> pd.DataFrame:
    """Tracks along z sampled at 60 fps, each ``delay_s`` behind the twin, with noise ``sigma_mm``."""
    t = np.arange(10.0 + 0.5 / FS_HZ, t_end, 1.0 / FS_HZ)
    parts = []
    for k in range(n_tracks):
        z = np.asarray(body.displacement_mm(t - delay_s)) + rng.normal(0.0, sigma_mm, t.size)
        parts.append(pd.DataFrame({"segment": "sweep", "track": f"sweep#{k}", "track_id": k, "time_s": t,
                                   "x_mm": 100.0 * k, "y_mm": 0.0, "z_mm": 500.0 + z}))
    return pd.concat(parts, ignore_index=True)


@pytest.mark.parametrize("delay_s", [0.0, 0.4e-3])
def test_step_phase_against_the_twins_truth(delay_s: float) -> None:
    rng = np.random.default_rng(7)
    freqs = [4.0, 8.0, 9.5, 12.0, 15.0, 19.0, 24.0, 27.0]
    sweep, body = _staircase(rng, freqs, step_s=0.5, bracket_s=0.004)
    sigma_mm = 0.01
    tracks = _tracks(rng, body, sweep["t_stop_s"], delay_s=delay_s, sigma_mm=sigma_mm)
    u_clock_s = 2e-6
    sp = step_phase.step_phase(tracks, sweep, sweep, fs_hz=FS_HZ, u_clock_s=u_clock_s,
                               clock_source="timing fiducial: test", sync_method="trajectory")
    assert sp is not None
    b = sp.bins
    # steps with ≥ 3 cycles after the 0.1-s settle: 8 Hz and up (4 Hz: 1.6 cycles)
    assert list(np.round(b["frequency_ref_hz"], 6)) == freqs[1:]
    f = b["frequency_ref_hz"].to_numpy(float)
    truth_deg = -360.0 * f * delay_s
    # the reference's own law errs by the brackets (≤ 4 ms × Δf, accumulated): its u is stated, not zero
    assert (b["u_reference_deg"].to_numpy(float)[1:] > 0).all()
    err = b["phase_deg"].to_numpy(float) - truth_deg
    assert (np.abs(err) <= 4 * b["u_phase_deg"].to_numpy(float)).all(), b.assign(err=err)
    assert np.abs(b["delay_ms"] - 1e3 * delay_s).le(4 * b["u_delay_ms"]).all()
    assert np.abs(b["amplitude_error_pct"]).le(4 * b["u_amplitude_error_pct"]).all()
    assert np.abs(b["frequency_hz"] - f).le(4 * b["u_frequency_hz"]).all()
    # the stated fit u agrees with the noise: σ·√2/(A·√n) rad per track (n samples in the step)
    n = b["n_samples"].to_numpy(float) / b["n_tracks"].to_numpy(float)
    expected = np.rad2deg(sigma_mm * np.sqrt(2.0 / n) / AMP_MM)
    assert np.allclose(b["u_phase_fit_deg"], expected, rtol=0.35)


def test_reference_u_grows_with_every_bracketed_change() -> None:
    sweep, _ = _staircase(np.random.default_rng(1), [5.0, 10.0, 20.0], step_s=1.0, bracket_s=0.01)
    u_before = step_phase.staircase_reference_u_deg(sweep, 10.5)
    u_one = step_phase.staircase_reference_u_deg(sweep, 11.5)
    u_two = step_phase.staircase_reference_u_deg(sweep, 12.5)
    assert u_before == 0.0  # the restart dated the cameras (fiducial): its bracket cancels
    assert u_one == pytest.approx(360.0 * 5.0 * 0.01 / math.sqrt(12.0))
    assert u_two == pytest.approx(math.hypot(u_one, 360.0 * 10.0 * 0.01 / math.sqrt(12.0)))
    own = dict(sweep, phase_origin="PHASe:SYNChronize issued by the step", phase_origin_s=[10.0, 10.002])
    u_own = step_phase.staircase_reference_u_deg(own, 10.5)
    assert u_own == pytest.approx(360.0 * 5.0 * 0.002 / math.sqrt(12))


def test_polled_reference_without_a_sweep_line_states_no_phase() -> None:
    rng = np.random.default_rng(3)
    sweep, body = _staircase(rng, [8.0, 12.0], step_s=1.0, bracket_s=0.0)
    polled = dict(sweep, phase_origin_s=None, body="exciter")
    tracks = _tracks(rng, body, sweep["t_stop_s"], delay_s=0.0, sigma_mm=0.01)
    sp = step_phase.step_phase(tracks, polled, polled, fs_hz=FS_HZ, u_clock_s=1e-3, clock_source="start",
                               sync_method="trajectory", resolution=ReferenceResolution(0.01, 0.05, "polled"))
    assert sp is not None and len(sp.bins) == 2
    assert sp.bins["phase_deg"].isna().all() and "phase not stated" in " ".join(sp.notes)
    assert step_phase.measured_values(sp) == {}
    assert np.abs(sp.bins["amplitude_error_pct"]).le(4 * sp.bins["u_amplitude_error_pct"]).all()


def test_steps_above_one_cameras_nyquist_are_left_out_with_a_note() -> None:
    rng = np.random.default_rng(4)
    sweep, body = _staircase(rng, [20.0, 29.5], step_s=1.0, bracket_s=0.0)
    tracks = _tracks(rng, body, sweep["t_stop_s"], delay_s=0.0, sigma_mm=0.01)
    sp = step_phase.step_phase(tracks, sweep, sweep, fs_hz=FS_HZ, u_clock_s=1e-6,
                               clock_source="timing fiducial", sync_method="trajectory")
    assert sp is not None and list(sp.bins["frequency_ref_hz"]) == [20.0]
    assert "Nyquist" in sp.notes[0]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0.05, 3.0), st.sampled_from([2.0, 5.0, 10.0, 20.0])), min_size=1,
                max_size=8),
       st.floats(0.0, 0.3))
def test_steady_steps_are_the_flat_stretches_minus_the_settle_time(
        pieces: list[tuple[float, float]], settle_s: float) -> None:
    profile, t = [], 0.0
    for width, f in pieces:
        profile += [[t, f], [t + width, f]]
        t += width
    steps = step_phase.steady_steps(np.array(profile), (0.0, t), settle_s=settle_s)
    # expected: runs of equal neighbouring frequencies merged, each long enough for 3 cycles after settling
    runs: list[list[float]] = []
    t = 0.0
    for width, f in pieces:
        if runs and runs[-1][2] == f:
            runs[-1][1] = t + width
        else:
            runs.append([t, t + width, f])
        t += width
    expected = [(a + settle_s, b, f) for a, b, f in runs if (b - (a + settle_s)) * f >= step_phase.MIN_CYCLES]
    got = np.array([(s.t_start_s, s.t_stop_s, s.frequency_hz) for s in steps]).reshape(-1, 3)
    assert got.shape == (len(expected), 3)
    assert np.allclose(got, np.array(expected).reshape(-1, 3))


def test_each_tracks_first_bin_phase_is_amplitude_by_bins_without_fitting_the_other_bins(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The steps' phase origin (each track's phase in its first frequency bin) is the phase
    frequency.amplitude_by_bin fits in that bin, found without fitting the sweep's other bins (no
    per-bin Lomb–Scargle frequency: that costs most of a staircase's report)."""
    rng = np.random.default_rng(3)
    sweep, body = _staircase(rng, [4.0, 8.0, 12.0], step_s=1.0, bracket_s=0.004)
    tracks = _tracks(rng, body, sweep["t_stop_s"], delay_s=0.0, sigma_mm=0.01)
    samples = frequency.sweep_samples(tracks, sweep)
    bins = frequency.amplitude_by_bin(samples, sweep, sync_method="")
    first = bins.groupby("track", sort=True).first()
    expected = {}
    for track, g in samples.groupby("track", sort=True):
        t, x = g["time_s"].to_numpy(float), g["displacement_mm"].to_numpy(float)
        m = (frequency.profile_frequency_hz(sweep, t) >= first.loc[track, "frequency_lo_hz"]) & \
            (frequency.profile_frequency_hz(sweep, t) < first.loc[track, "frequency_hi_hz"])
        expected[str(track)] = frequency._fit_bin(t[m], x[m], frequency.sweep_phase_rad(sweep, t[m]))[2]
    peaks: list[tuple[object, ...]] = []

    def peak_frequency_hz(*args: object) -> float:
        peaks.append(args)
        return float("nan")

    monkeypatch.setattr(frequency, "_peak_frequency_hz", peak_frequency_hz)
    assert step_phase._first_bin_phase_rad(samples, sweep) == expected
    assert len(expected) == 3 and peaks == []
