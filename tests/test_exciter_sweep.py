"""Exciter and rotor ↔ mock drive over Modbus TCP and RTU on a pty: set a frequency, sweep to 30 Hz,
read the actual frequency back; the twin's body agrees with what the drive reports.

Tolerances are derived, not tuned:
* the drive reports frequency in 0.01 Hz, so a reported vibration frequency is within
  Q = 0.005 Hz / gear_ratio of the body's (instant clock: the poll's time stamp is exact);
* the drive ramps at (1 + margin) × the segment slope (the ramp time rounded down to 0.1 s makes it a
  little faster still) and holds at each segment end, so it leads the profile by at most
  slope × update interval × (1 − 1/(rate/slope)) plus the setpoint's rounding Q;
* the twin's phase is the exact integral of its frequency; the trapezoid integral of the polls differs
  by Q per second from quantization plus rate × dt² / 8 for every kink (two per segment) in a poll interval.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from vfd_support import EXCITER_LIMITS, connect_client, vfd_rig

from drivers.exciter.exciter import Exciter
from drivers.exciter.limits import MotionLimits
from drivers.exciter.register_map import DELTA_MAP, RegisterMap
from drivers.exciter.rotor import Rotor
from drivers.exciter.sweep import FrequencySample, LinearSweep, LogSweep, PointsSweep, SweepProfile
from drivers.exciter.vfd import VfdDriver
from drivers.heartbeat import HeartbeatError
from drivers.mock.vfd_drive import DriveModel
from drivers.mock.vfd_server import VfdServer
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World

GEAR = 1.5
Q_HZ = 0.005 / GEAR
UPDATE_S = 0.5
MARGIN = 0.02  # run_sweep's default ramp margin


def _check_sweep(rig, profile: SweepProfile, result) -> None:
    body = rig.world.exciter
    samples = result.samples
    assert samples[-1].frequency_hz == pytest.approx(profile.stop_hz, abs=Q_HZ)
    # frequency: drive report vs twin at the same instants
    t = np.array([s.t_s for s in samples])
    f_rep = np.array([s.frequency_hz for s in samples])
    f_body = np.asarray(body.frequency_hz(t))
    assert np.max(np.abs(f_rep - f_body)) <= Q_HZ + 1e-9
    # the twin follows the commanded profile
    slope = profile.max_slope_hz_per_s()
    lead = slope * UPDATE_S * (1 - 1 / (1 + MARGIN)) * 1.01 + Q_HZ  # 1 % for the ramp-time rounding
    f_profile = np.array([profile.frequency_hz(x - result.t_start_s) for x in t])
    assert np.max(np.abs(f_body - f_profile)) <= lead + 1e-9
    # phase: twin's exact integral vs trapezoid of the reported samples
    dt = float(np.max(np.diff(t)))
    n_kinks = 2 * len(profile.segments(UPDATE_S))
    rate = slope * (1 + MARGIN) * 1.01
    bound = 2 * math.pi * (Q_HZ * (t[-1] - t[0]) + n_kinks * rate * dt * dt / 8)
    trapezoid = 2 * math.pi * float(np.sum(0.5 * (f_rep[1:] + f_rep[:-1]) * np.diff(t)))
    exact = float(body.phase_rad(t[-1]) - body.phase_rad(t[0]))
    assert abs(trapezoid - exact) <= bound
    # the record's profile is the commanded one in absolute time
    assert result.profile[0] == (pytest.approx(result.t_start_s), pytest.approx(profile.start_hz))
    assert result.profile[-1][1] == pytest.approx(profile.stop_hz)


@pytest.mark.parametrize("mode", ["tcp", "rtu"])
def test_set_frequency_then_linear_sweep_to_30_hz(mode: str) -> None:
    with vfd_rig(mode, gear_ratio=GEAR) as rig:
        reached = rig.exciter.set_frequency(10.0)
        assert reached is not None and reached.frequency_hz == pytest.approx(10.0, abs=Q_HZ)
        assert rig.world.exciter.frequency_hz(rig.clock.now_s()) == pytest.approx(10.0, abs=Q_HZ)
        seen: list[FrequencySample] = []
        profile = LinearSweep(10.0, 30.0, 20.0)
        result = rig.exciter.sweep(profile, update_interval_s=UPDATE_S, on_sample=seen.append)
        assert seen == result.samples and len(seen) > 20
        _check_sweep(rig, profile, result)
        assert rig.exciter.vibration_hz() == pytest.approx(30.0, abs=Q_HZ)
        rest = rig.exciter.stop()
        assert rest is not None and rest.frequency_hz == 0.0 and rest.status == "stopped"
        assert rig.world.exciter.frequency_hz(rig.clock.now_s()) == 0.0


def test_log_sweep_over_rtu() -> None:
    with vfd_rig("rtu", gear_ratio=GEAR, poll_interval_s=0.5) as rig:
        profile = LogSweep(3.0, 30.0, 40.0)  # steepest: 30·ln(10)/40 = 1.73 Hz/s
        result = rig.exciter.sweep(profile, update_interval_s=UPDATE_S)
        _check_sweep(rig, profile, result)


def test_fig17_like_points_profile_over_tcp() -> None:
    # monotone rise to 30 Hz with changing slopes, like the paper's Fig. 17
    profile = PointsSweep([(0.0, 2.0), (5.0, 5.0), (10.0, 12.0), (15.0, 20.0), (20.0, 26.0), (25.0, 30.0)])
    with vfd_rig("tcp", gear_ratio=GEAR) as rig:
        result = rig.exciter.sweep(profile, update_interval_s=UPDATE_S)
        _check_sweep(rig, profile, result)
        frame = result.to_dataframe()
        assert list(frame.columns) == ["t_s", "frequency_hz", "setpoint_hz", "status"]
        assert frame["frequency_hz"].is_monotonic_increasing


def test_exciter_displacement_amplitude_is_the_crank_radius() -> None:
    with vfd_rig("tcp", gear_ratio=GEAR) as rig:
        rig.exciter.set_frequency(8.0)
        t = rig.clock.now_s() + np.linspace(0, 1.0, 2001)
        x = np.asarray(rig.world.exciter.displacement_mm(t))
        assert np.max(np.abs(x)) == pytest.approx(rig.exciter.crank_radius_mm, rel=1e-4)


def test_rotor_at_10_hz_on_unit_2() -> None:
    world = World(VirtualClock(), seed=2)
    unit2 = RegisterMap(model="delta", unit_id=2)
    drive = DriveModel(world.rotor, world.clock, register_map=unit2, max_output_hz=50.0)
    limits = MotionLimits(max_frequency_hz=12.0, max_displacement_mm=100.0, max_acceleration_m_s2=400.0,
                          max_ramp_rate_hz_per_s=5.0)
    with VfdServer(drive) as server:
        client = connect_client(server)
        try:
            rotor = Rotor(VfdDriver(client, unit2, max_output_hz=50.0), clock=world.clock, limits=limits,
                          marker_radius_mm=50.0, ramp_rate_hz_per_s=5.0, poll_interval_s=0.1)
            rotor.set_rotation_hz(10.0)
            assert rotor.rotation_hz() == pytest.approx(10.0, abs=0.005)
            t0 = world.clock.now_s()
            world.clock.sleep_s(1.0)
            assert rotor.rotation_hz() == pytest.approx(10.0, abs=0.005)
            turned = world.rotor.angle_deg(t0 + 1.0) - world.rotor.angle_deg(t0)
            assert turned == pytest.approx(3600.0, abs=1e-6)
            rotor.stop()
        finally:
            client.close()
    # the default unit (1) would not be answered by this drive: the map's unit id is on the wire
    assert DELTA_MAP.unit_id == 1


def test_sweep_rejects_a_profile_steeper_than_a_fixed_ramp_drive() -> None:
    no_ramp = RegisterMap(accel_time=None, decel_time=None)
    with vfd_rig("tcp", gear_ratio=GEAR) as rig:
        exciter = Exciter(VfdDriver(rig.client, no_ramp, max_output_hz=60.0), clock=rig.clock,
                          limits=EXCITER_LIMITS, crank_radius_mm=4.0, gear_ratio=GEAR,
                          fixed_drive_ramp_rate_hz_per_s=1.5)  # 1 Hz/s of vibration
        before = rig.drive.request_count
        with pytest.raises(ValueError, match="fixed ramp rate"):
            exciter.sweep(LinearSweep(0.0, 30.0, 15.0))  # 2 Hz/s
        assert rig.drive.request_count == before  # checked before anything was sent


@pytest.mark.parametrize("mode", ["tcp", "rtu"])
def test_safe_state_brings_the_twin_to_rest_and_heartbeat_reports_faults(mode: str) -> None:
    with vfd_rig(mode, gear_ratio=GEAR, overspeed_hz=30.0) as rig:
        rig.exciter.set_frequency(12.0)
        assert rig.exciter.heartbeat() is True
        rig.exciter.safe_state()
        t = rig.clock.now_s()
        assert rig.world.exciter.frequency_hz(t) == 0.0
        assert rig.drive.regs[DELTA_MAP.freq_set] == 0 and not rig.drive.running
        rig.exciter.set_frequency(12.0)
        rig.drive.trip(0x41)  # the drive trips on its own (overspeed sensor)
        # the heartbeat's idle probe (STATUS + FAULT) finds it; the watchdog then sees HeartbeatError
        with pytest.raises(HeartbeatError, match=r"exciter: drive reports fault code 65"):
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline:
                rig.exciter.heartbeat()
                time.sleep(0.05)


def test_exciter_and_rotor_share_one_rs485_line() -> None:
    world = World(VirtualClock(), seed=8)
    exciter_map, rotor_map = RegisterMap(unit_id=1), RegisterMap(unit_id=2)
    drives = [DriveModel(world.exciter, world.clock, register_map=exciter_map, max_output_hz=60.0),
              DriveModel(world.rotor, world.clock, register_map=rotor_map, max_output_hz=60.0)]
    with VfdServer(drives, mode="rtu") as server:
        client = connect_client(server)
        try:
            exciter = Exciter(VfdDriver(client, exciter_map, max_output_hz=60.0), clock=world.clock,
                              limits=EXCITER_LIMITS, crank_radius_mm=4.0, ramp_rate_hz_per_s=2.0,
                              poll_interval_s=0.25)
            rotor = Rotor(VfdDriver(client, rotor_map, max_output_hz=60.0), clock=world.clock,
                          limits=EXCITER_LIMITS, marker_radius_mm=5.0, ramp_rate_hz_per_s=2.0,
                          poll_interval_s=0.25)
            exciter.set_frequency(8.0)
            rotor.set_rotation_hz(3.0)
            t = world.clock.now_s()
            assert world.exciter.frequency_hz(t) == pytest.approx(8.0, abs=0.005)
            assert world.rotor.frequency_hz(t) == pytest.approx(3.0, abs=0.005)
            assert rotor.rotation_hz() == pytest.approx(3.0, abs=0.005)
            assert exciter.vibration_hz() == pytest.approx(8.0, abs=0.005)
        finally:
            client.close()


def test_stop_after_a_trip_waits_for_rest_instead_of_failing() -> None:
    with vfd_rig("tcp", gear_ratio=GEAR) as rig:
        rig.exciter.set_frequency(12.0)
        rig.drive.trip(0x41)
        rest = rig.exciter.stop()
        assert rest is not None and rest.frequency_hz == 0.0 and rest.status == "fault 65"
        assert rig.world.exciter.frequency_hz(rig.clock.now_s()) == 0.0
