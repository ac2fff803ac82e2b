"""The dashboard state's plots beyond the raw device streams: the rotor's phase from its drive's polled speed
(the sync step's truth), and the arm's position error per move."""

from __future__ import annotations

import pytest

from rig.dashboard.state import DashboardState


def _event(t_s: float, stream: str, data: dict) -> dict:
    return {"type": "event", "time_s": t_s, "stream": stream, "data": data}


def _phases(state: DashboardState) -> list[list[float]]:
    return state.patch({})[0]["plots"]["rotor_phase"]["rows"]


def test_rotor_phase_integrates_the_polled_frequency_in_turns() -> None:
    state = DashboardState("sync")
    # spin-up 0 → 1 Hz in 0.5 s (polled every 0.5 s), then 1 → 2 Hz, then 2 Hz polled every 0.2 s
    polls = [(0.0, 0.0), (0.5, 1.0), (1.0, 2.0), (1.2, 2.0), (1.4, 2.0)]
    for t_s, f_hz in polls:
        state.on_document(_event(t_s, "rotor", {"frequency_hz": f_hz, "setpoint_hz": 2.0}))
    # turns: 0.25 (trapezoid 0 → 1 Hz over 0.5 s), + 0.75 (1 → 2 Hz), + 0.4, + 0.4
    turns = [0.25, 1.0, 1.4, 1.8]
    rows = _phases(state)
    assert [r[0] for r in rows] == [0.5, 1.0, 1.2, 1.4]  # the rotor at rest before the spin: no point
    assert [r[1] for r in rows] == pytest.approx(turns)  # unwrapped: a wrapped phase would alias


def test_rotor_phase_starts_again_at_the_next_spin() -> None:
    state = DashboardState("sync")
    for t_s, f_hz in [(0.0, 1.0), (1.0, 1.0), (1.1, 0.0), (5.0, 0.0), (5.5, 2.0), (5.75, 2.0)]:
        state.on_document(_event(t_s, "rotor", {"frequency_hz": f_hz, "setpoint_hz": f_hz}))
    rows = _phases(state)
    assert [r[0] for r in rows] == [0.0, 1.0, 1.1, 5.5, 5.75]
    # from rest at 5.0 s: half a turn by 5.5 s (0 → 2 Hz), half a turn more by 5.75 s
    assert rows[-2][1] == pytest.approx(0.5) and rows[-1][1] == pytest.approx(1.0)


def test_the_arm_position_error_is_plotted_per_move() -> None:
    state = DashboardState("calibrate")
    state.on_document(_event(3.0, "arm", {"commanded_pose": [400.0, 0.0, 300.0, 90.0, 0.0, 90.0],
                                          "reported_pose": [400.01, 0.0, 300.0, 90.0, 0.0, 90.0],
                                          "position_error_mm": 0.01}))
    arm = state.patch({})[0]["plots"]["arm"]
    assert arm["columns"] == ["t_s", "x_mm", "y_mm", "z_mm", "position_error_mm"]
    assert arm["rows"] == [[3.0, 400.0, 0.0, 300.0, 0.01]]


def test_the_commanded_line_follows_a_stop_not_the_drives_reference_register() -> None:
    """A stop command leaves the drive's frequency reference at the last value written (10 Hz) while the
    output ramps to 0: the commanded line drops to 0 with the stop, and the lag is polled − 0."""
    state = DashboardState("sync")
    polls = [(0.0, 10.0, "running"), (1.0, 7.5, "decelerating"), (2.0, 2.5, "decelerating"),
             (2.5, 0.0, "stopped"), (3.0, 0.0, "standby"), (3.5, 4.0, "running"), (4.0, 3.0, "fault 7")]
    for t_s, f_hz, status in polls:
        state.on_document(_event(t_s, "rotor", {"frequency_hz": f_hz, "setpoint_hz": 10.0, "status": status}))
    rows = state.patch({})[0]["plots"]["rotor"]["rows"]
    assert [r[1] for r in rows] == [10.0, 0.0, 0.0, 0.0, 10.0, 10.0, 0.0]
    assert [r[3] for r in rows] == [0.0, 7.5, 2.5, 0.0, -10.0, -6.0, 3.0]


def test_a_stop_through_the_real_drive_and_its_mock_drops_the_commanded_line() -> None:
    from rig.config.rig_config import default_config
    from rig.run.clock import make_clock
    from rig.run.station import open_station

    state = DashboardState("sync")
    with open_station(default_config(), make_clock(True)) as st:
        rotor = st.devices["rotor"]
        state.on_document(_event(0.0, "rotor", rotor.set_frequency(2.0).as_event()))
        rotor.stop(wait=False)
        ramping = rotor.read_sample()
        state.on_document(_event(1.0, "rotor", ramping.as_event()))
    assert ramping.setpoint_hz == 2.0 and ramping.frequency_hz > 0.0  # the register keeps 2 Hz
    rows = state.patch({})[0]["plots"]["rotor"]["rows"]
    assert [r[1] for r in rows] == [2.0, 0.0]
