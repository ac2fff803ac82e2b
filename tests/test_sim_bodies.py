"""Truth of the simulated bodies: the robot's trapezoidal moves and the oscillators' exact phase."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad
from scipy.spatial.transform import Rotation

from drivers.sim.bodies import OscillatorBody, RobotBody, SimCommandError

HOME = (350.0, 0.0, 300.0, 90.0, 0.0, 90.0)


def _trapezoid_distance(t: np.ndarray, dist: float, v: float, a: float) -> np.ndarray:
    """Independent textbook rest-to-rest trapezoid: distance covered at time t after the start."""
    if dist >= v * v / a:
        ta, tc = v / a, (dist - v * v / a) / v
    else:
        v = math.sqrt(dist * a)
        ta, tc = v / a, 0.0
    total = 2 * ta + tc
    out = np.empty_like(t)
    for i, x in enumerate(t):
        if x <= 0:
            out[i] = 0.0
        elif x < ta:
            out[i] = 0.5 * a * x * x
        elif x < ta + tc:
            out[i] = 0.5 * a * ta * ta + v * (x - ta)
        elif x < total:
            r = total - x
            out[i] = dist - 0.5 * a * r * r
        else:
            out[i] = dist
    return out


@pytest.mark.parametrize(("dist", "speed", "accel"), [(200.0, 100.0, 500.0), (10.0, 100.0, 500.0)])
def test_linear_move_follows_the_trapezoid(dist: float, speed: float, accel: float) -> None:
    robot = RobotBody(HOME)
    target = np.array(HOME) + np.array([dist * 0.6, -dist * 0.8, 0, 0, 0, 0])
    t_end = robot.move(2.0, target, speed, accel, linear=True)
    t = np.linspace(1.5, t_end + 0.5, 301)
    pose = robot.pose_at(t)
    travelled = np.linalg.norm(pose[:, :3] - np.array(HOME[:3]), axis=1)
    np.testing.assert_allclose(travelled, _trapezoid_distance(t - 2.0, dist, speed, accel), atol=1e-9)
    direction = (pose[-1, :3] - pose[0, :3]) / dist
    np.testing.assert_allclose(direction, [0.6, -0.8, 0.0], atol=1e-12)
    np.testing.assert_allclose(robot.pose_at(t_end + 1.0), target, atol=1e-12)
    assert robot.is_moving(2.0 + 1e-6) and not robot.is_moving(t_end) and not robot.is_moving(1.0)


def test_orientation_follows_the_same_normalised_profile() -> None:
    robot = RobotBody(HOME, rot_speed_deg_s=1e6, rot_accel_deg_s2=1e9)
    target = np.array([450.0, 0.0, 300.0, 90.0, 0.0, 120.0])  # 100 mm and 30 deg about z
    t_end = robot.move(0.0, target, 50.0, 200.0)
    t = np.linspace(0.0, t_end, 41)
    pose = robot.pose_at(t)
    fraction = (pose[:, 0] - 350.0) / 100.0
    np.testing.assert_allclose((pose[:, 5] - 90.0) / 30.0, fraction, atol=1e-9)


def test_rotation_only_move_uses_the_rotation_limits() -> None:
    robot = RobotBody(HOME, rot_speed_deg_s=30.0, rot_accel_deg_s2=60.0)
    t_end = robot.move(0.0, (350.0, 0.0, 300.0, 90.0, 0.0, 150.0), 100.0, 500.0)
    assert t_end == pytest.approx(60.0 / 30.0 + 30.0 / 60.0)


def test_halt_decelerates_and_cuts_the_move() -> None:
    robot = RobotBody(HOME)
    robot.move(0.0, (350.0, 400.0, 300.0, 90.0, 0.0, 90.0), 100.0, 200.0)
    robot.halt(1.5)  # cruising at 100 mm/s since t = 0.5 s, at y = 25 + 100 = 125 mm
    assert robot.t_end_s() == pytest.approx(2.0)
    assert robot.pose_at(5.0)[1] == pytest.approx(125.0 + 100.0**2 / (2 * 200.0))
    assert not robot.is_moving(2.0)
    with pytest.raises(SimCommandError, match="before the previous command"):
        robot.move(1.0, HOME, 100.0, 200.0)


def test_move_while_moving_and_bad_values_are_refused() -> None:
    robot = RobotBody(HOME)
    robot.move(0.0, (450.0, 0.0, 300.0, 90.0, 0.0, 90.0), 100.0, 200.0)
    with pytest.raises(SimCommandError, match="moving until"):
        robot.move(0.5, HOME, 100.0, 200.0)
    with pytest.raises(SimCommandError, match="speed_mm_s"):
        robot.move(5.0, HOME, 0.0, 200.0)
    with pytest.raises(SimCommandError, match="target_pose"):
        robot.move(5.0, (1.0, 2.0), 10.0, 200.0)


def test_transform_matches_pose() -> None:
    robot = RobotBody(HOME)
    robot.move(0.0, (300.0, 50.0, 350.0, 80.0, 10.0, 100.0), 80.0, 300.0)
    t = np.linspace(-0.5, 3.0, 17)
    pos, rot = robot.transform_at(t)
    pose = robot.pose_at(t)
    np.testing.assert_allclose(pos, pose[:, :3])
    expected = Rotation.from_euler("xyz", pose[:, 3:], degrees=True).as_matrix()
    np.testing.assert_allclose(rot, expected, atol=1e-12)


def _numeric_phase(body: OscillatorBody, t0: float, t1: float) -> float:
    breaks = [b for b, _ in body.profile_breakpoints() if t0 < b < t1]
    return 2 * math.pi * quad(body.frequency_hz, t0, t1, points=breaks or None, limit=200)[0]


def test_ramp_and_sweeps_have_exact_continuous_phase() -> None:
    body = OscillatorBody("exciter", amplitude_mm=4.0)
    body.set_frequency(0.0, 2.0)
    assert body.ramp_to(1.0, 10.0, 4.0) == pytest.approx(3.0)
    assert body.sweep(4.0, 5.0, 30.0, 10.0, "log") == pytest.approx(14.0)
    body.sweep(15.0, 30.0, 1.0, 5.0, "linear")
    for t in (0.7, 2.2, 3.5, 6.0, 13.9, 14.5, 17.0, 21.0):
        assert body.phase_rad(t) == pytest.approx(_numeric_phase(body, 0.0, t), rel=1e-9, abs=1e-9)
    assert body.frequency_hz(9.0) == pytest.approx(5.0 * 6.0 ** 0.5)  # log sweep midpoint: geometric mean
    assert body.frequency_hz(17.5) == pytest.approx(30.0 - 29.0 / 2)
    t = np.linspace(0, 25, 250_001)  # phase has no jumps: increments bounded by 2π f_max dt
    assert np.max(np.abs(np.diff(body.phase_rad(t)))) <= 2 * math.pi * 30.0 * 1e-4 * (1 + 1e-9)
    np.testing.assert_allclose(body.displacement_mm(t[:5]), 4.0 * np.sin(body.phase_rad(t[:5])))


@settings(max_examples=40, deadline=None)
@given(st.floats(0.0, 40.0), st.floats(0.0, 40.0), st.floats(0.1, 20.0), st.floats(0.01, 5.0))
def test_ramp_phase_is_the_integral_of_frequency(f0: float, f1: float, rate: float, dt: float) -> None:
    body = OscillatorBody(initial_hz=f0)
    t_end = body.ramp_to(1.0, f1, rate)
    t = 1.0 + dt
    expected = 2 * math.pi * (f0 * 1.0 + quad(body.frequency_hz, 1.0, t, points=[t_end])[0])
    assert body.phase_rad(t) == pytest.approx(expected, rel=1e-9, abs=1e-9)


def test_new_command_replaces_only_the_future() -> None:
    body = OscillatorBody()
    body.ramp_to(0.0, 20.0, 2.0)  # would reach 20 Hz at t = 10 s
    before = body.phase_rad(np.linspace(0, 4, 9))
    body.ramp_to(4.0, 0.0, 4.0)  # at 8 Hz, back to 0 by t = 6 s
    np.testing.assert_array_equal(body.phase_rad(np.linspace(0, 4, 9)), before)
    assert body.frequency_hz(5.0) == pytest.approx(4.0) and body.frequency_hz(7.0) == 0.0
    with pytest.raises(SimCommandError, match="before the previous command"):
        body.set_amplitude(3.0, 1.0)
    with pytest.raises(SimCommandError, match="spacing"):
        body.sweep(5.0, 1.0, 2.0, 1.0, "cubic")  # type: ignore[arg-type]
    with pytest.raises(SimCommandError, match="log sweep"):
        body.sweep(5.0, 0.0, 2.0, 1.0, "log")


def test_commands_from_many_threads_keep_the_body_consistent() -> None:
    body = OscillatorBody()
    lock = threading.Lock()
    clock = [0.0]
    errors: list[Exception] = []

    def worker(k: int) -> None:
        for i in range(200):
            with lock:
                clock[0] += 0.01
                t = clock[0]
            try:
                body.ramp_to(t, (k * 7 + i) % 30, 50.0)
            except SimCommandError as exc:  # a command can race past another thread's later time
                errors.append(exc)
            body.phase_rad(np.linspace(0, t, 50))

    threads = [threading.Thread(target=worker, args=(k,)) for k in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    starts = [b for b, _ in body.profile_breakpoints()]
    assert starts == sorted(starts)
    assert all("before the previous command" in str(e) for e in errors)
    t = np.linspace(0, clock[0] + 1.0, 20_001)
    assert np.max(np.abs(np.diff(body.phase_rad(t)))) <= 2 * math.pi * 30.0 * (t[1] - t[0]) * (1 + 1e-9)


def test_a_move_to_the_current_pose_ends_at_once() -> None:
    robot = RobotBody(HOME)
    assert robot.move(1.0, HOME, 100.0, 500.0) == 1.0
    assert not robot.is_moving(1.0)
    assert robot.move(1.0, (360.0, 0.0, 300.0, 90.0, 0.0, 90.0), 100.0, 500.0) > 1.0


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-200.0, 200.0), min_size=3, max_size=3), st.floats(5.0, 500.0),
       st.floats(50.0, 5000.0))
def test_moves_never_exceed_the_commanded_speed_and_end_on_time(delta: list[float], speed: float,
                                                                accel: float) -> None:
    robot = RobotBody(HOME)
    target = np.array(HOME) + np.array([*delta, 0.0, 0.0, 0.0])
    dist = float(np.linalg.norm(target[:3] - np.array(HOME[:3])))  # as represented in floats
    t_end = robot.move(0.0, target, speed, accel)
    expected = (dist / speed + speed / accel) if dist >= speed**2 / accel else 2 * math.sqrt(dist / accel)
    assert t_end == pytest.approx(expected, rel=1e-9, abs=1e-12)
    t = np.linspace(0.0, t_end, 2001)
    pos = robot.pose_at(t)[:, :3]
    step = np.linalg.norm(np.diff(pos, axis=0), axis=1) / np.diff(t) if t_end > 0 else np.zeros(1)
    assert np.all(step <= speed * (1 + 1e-9))
    np.testing.assert_allclose(robot.pose_at(t_end), target, atol=1e-9)
