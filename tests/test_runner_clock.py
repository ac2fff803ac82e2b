"""rig.run.clock: one interface over wall and virtual time."""

from __future__ import annotations

import time

import pytest

from rig.run.clock import Clock, ClockError, VirtualClock, WallClock, make_clock


def test_virtual_instant_clock_advances_without_waiting() -> None:
    clock = make_clock(True, start_s=10.0)
    assert isinstance(clock, VirtualClock) and isinstance(clock, Clock) and clock.is_virtual
    wall0 = time.monotonic()
    clock.sleep_s(3600.0)
    assert clock.now_s() == 3610.0
    assert time.monotonic() - wall0 < 60.0  # an hour of virtual time did not take an hour


def test_wall_clock() -> None:
    clock = make_clock(False)
    assert isinstance(clock, WallClock) and not clock.is_virtual
    t0 = clock.now_s()
    clock.sleep_s(0.01)
    assert clock.now_s() >= t0 + 0.01
    with pytest.raises(ClockError, match="a wall clock takes no rate"):
        make_clock(False, rate=2.0)
    with pytest.raises(ClockError):
        clock.sleep_s(-1.0)
