"""The sweep's phase reference against the twin's crank: the polled actual frequency, not the commanded
profile, so the report's "track delay" carries no lead of the drive.

A real sweep through the exciter driver and the mock drive over Modbus TCP moves the twin's crank. The
reference phase of :func:`reports.frequency.reference_sweep` is compared with the crank's exact phase; its
equivalent delay (the report's estimator: least-squares slope of the phase difference against frequency,
÷ −2π) must stay within the floor derived from the drive's 0.01 Hz resolution: every poll is within
Q = 0.005 Hz / gear of the crank (tests/test_exciter_sweep.py), so the phase error grows by at most 2π·Q
per second, plus 2π·Q·dt for each restored setpoint arrival (its level within Q over a poll interval dt);
a phase error bounded by e(f) gives a least-squares slope of at most max|e|·Σ|f − f̄|/Σ(f − f̄)² … taken
here with the exact weights of the frequency grid.
The commanded profile leads by ≈ ½·update·margin/(1 + margin) (≈ 4.9 ms): outside that floor.
"""

from __future__ import annotations

import numpy as np
import pytest
from vfd_support import vfd_rig

from drivers.exciter.sweep import LinearSweep
from reports.frequency import ramp_knots, reference_sweep, sweep_phase_rad

GEAR = 5.0
Q_HZ = 0.005 / GEAR
UPDATE_S = 0.5
POLL_S = 0.05


def _equivalent_delay_s(dphi: np.ndarray, f: np.ndarray) -> float:
    df = f - f.mean()
    return float(-(df @ (dphi - dphi.mean())) / (df @ df) / (2 * np.pi))


def _delay_floor_s(f: np.ndarray, t: np.ndarray, n_corners: int) -> float:
    """Largest equivalent delay a phase error ≤ 2π·Q·((t − t0) + n_corners·dt) can produce."""
    e = 2 * np.pi * Q_HZ * ((t[-1] - t[0]) + n_corners * POLL_S)
    df = f - f.mean()
    return float(e * np.sum(np.abs(df)) / (df @ df) / (2 * np.pi))


@pytest.fixture(scope="module")
def swept():
    with vfd_rig("tcp", gear_ratio=GEAR, poll_interval_s=POLL_S) as rig:
        rig.exciter.set_frequency(2.0)
        profile = LinearSweep(2.0, 8.0, 4.5)  # 1.33 Hz/s: below the 2 Hz/s cap, the margin applies
        result = rig.exciter.sweep(profile, update_interval_s=UPDATE_S)
        sweep = {"t_start_s": result.t_start_s, "t_stop_s": result.t_stop_s, "amplitude_mm": 4.0,
                 "axis": [0.0, 0.0, 1.0], "profile": [list(p) for p in result.profile]}
        polled = [s.as_event() for s in result.samples]
        t = np.linspace(result.t_start_s, result.t_stop_s, 4001)
        return sweep, polled, t, np.asarray(rig.world.exciter.phase_rad(t)), \
            np.asarray(rig.world.exciter.frequency_hz(t)), len(profile.segments(UPDATE_S))


def test_polled_reference_follows_the_crank_within_the_resolution_floor(swept) -> None:
    sweep, polled, t, phi_true, f_true, n_segments = swept
    reference, source = reference_sweep(sweep, polled)
    assert source.startswith("polled actual frequency")
    floor = _delay_floor_s(f_true, t, n_segments)
    delay = _equivalent_delay_s(sweep_phase_rad(reference, t) - phi_true, f_true)
    assert abs(delay) <= floor, (delay, floor)
    # the commanded profile leads the crank by the drive's ramp margin: a delay well outside the floor
    commanded = _equivalent_delay_s(sweep_phase_rad(sweep, t) - phi_true, f_true)
    lead = 0.5 * UPDATE_S * 0.02 / 1.02  # run_sweep's default margin 2 %
    assert commanded > max(0.9 * lead, floor), (commanded, lead, floor)


def test_restored_arrivals_remove_the_corner_cutting_lag(swept) -> None:
    """Joining the polls with straight lines cuts each arrival corner: a lag the restored knots remove."""
    sweep, polled, t, phi_true, f_true, _ = swept
    inside = [p for p in polled if sweep["t_start_s"] <= p["t_s"] <= sweep["t_stop_s"]]
    plain = dict(sweep, profile=[[p["t_s"], p["frequency_hz"]] for p in inside])
    restored, _ = reference_sweep(sweep, polled)
    assert len(restored["profile"]) > len(plain["profile"])
    d_plain = _equivalent_delay_s(sweep_phase_rad(plain, t) - phi_true, f_true)
    d_restored = _equivalent_delay_s(sweep_phase_rad(restored, t) - phi_true, f_true)
    assert abs(d_restored) < abs(d_plain)


def test_sparse_polls_keep_the_commanded_profile_and_say_so(swept) -> None:
    sweep, polled, *_ = swept
    reference, source = reference_sweep(sweep, polled[::20])  # one poll per second: coarser than the profile
    assert reference["profile"] == sweep["profile"]
    assert source.startswith("commanded profile")


def test_ramp_knots_puts_the_arrival_on_the_ramp_line() -> None:
    # ramp at 2 Hz/s from 5.0 Hz (setpoint 5.3) polled every 0.05 s: arrives at t = 0.15, between polls
    t = np.array([0.0, 0.05, 0.1, 0.2, 0.25])
    f = np.array([5.0, 5.1, 5.2, 5.3, 5.3])
    sp = np.array([5.0, 5.3, 5.3, 5.3, 5.3])
    tk, fk = ramp_knots(t, f, sp)
    assert tk.tolist() == pytest.approx([0.0, 0.05, 0.1, 0.15, 0.2, 0.25])
    assert fk.tolist() == pytest.approx([5.0, 5.1, 5.2, 5.3, 5.3, 5.3])


def test_a_shaker_sweep_keeps_its_exact_commanded_law_without_a_ramp_note() -> None:
    from reports.frequency import reference_sweep

    sweep = {"t_start_s": 0.0, "t_stop_s": 10.0, "profile": [[0.0, 2.0], [10.0, 12.0]], "body": "shaker",
             "profile_source": "commanded generator sweep"}
    ref, source = reference_sweep(sweep, [])
    assert ref["profile"] == sweep["profile"]
    assert "shaker" in source and "ramp margin" not in source
