"""Clocks: the wall clock, and the virtual clock in instant and paced modes."""

from __future__ import annotations

import threading
import time

import pytest

from drivers.clock import Clock, ClockError, WallClock
from drivers.sim.clock import VirtualClock


def test_both_clocks_satisfy_the_protocol() -> None:
    assert isinstance(WallClock(), Clock)
    assert isinstance(VirtualClock(), Clock)
    assert WallClock().is_virtual is False
    assert VirtualClock().is_virtual is True


def test_instant_sleep_advances_at_once() -> None:
    clock = VirtualClock(start_s=5.0)
    t0 = time.monotonic()
    clock.sleep_s(1000.0)
    assert time.monotonic() - t0 < 100.0  # a liveness bound far below the 1000 s slept, not a speed test
    assert clock.now_s() == pytest.approx(1005.0)
    clock.advance_to(2000.0)
    clock.advance_to(10.0)  # never backwards
    assert clock.now_s() == 2000.0


def test_paced_clock_runs_at_its_rate() -> None:
    clock = VirtualClock(start_s=100.0, rate=50.0)
    w0, v0 = time.monotonic(), clock.now_s()
    clock.sleep_s(2.5)  # 0.05 s of wall time
    w1, v1 = time.monotonic(), clock.now_s()
    assert v1 - v0 >= 2.5
    assert (v1 - v0) == pytest.approx(50.0 * (w1 - w0), rel=0.05, abs=0.05)
    with pytest.raises(ClockError, match="instant mode"):
        clock.advance_to(1e6)


@pytest.mark.parametrize("bad", [-1.0, float("nan"), float("inf")])
def test_bad_durations_are_refused(bad: float) -> None:
    with pytest.raises(ClockError, match="duration_s"):
        VirtualClock().sleep_s(bad)
    with pytest.raises(ClockError, match="duration_s"):
        WallClock().sleep_s(bad)


def test_bad_rate_is_refused() -> None:
    with pytest.raises(ClockError, match="rate"):
        VirtualClock(rate=0.0)


def test_concurrent_sleepers_end_at_the_latest_wake_up_not_the_sum() -> None:
    clock = VirtualClock()
    barrier = threading.Barrier(8)

    def sleeper() -> None:
        barrier.wait()
        clock.sleep_s(1.0)

    threads = [threading.Thread(target=sleeper) for _ in range(8)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    # each sleeper moved the clock to (its call time + 1); calls happen at times in [0, 7]
    assert 1.0 <= clock.now_s() <= 8.0


def test_wait_until_wakes_when_another_thread_advances() -> None:
    clock = VirtualClock()
    woke: list[bool] = []
    th = threading.Thread(target=lambda: woke.append(clock.wait_until(3.0, timeout_s=5.0)))
    th.start()
    time.sleep(0.02)
    assert not woke
    clock.advance_to(3.0)
    th.join(timeout=5.0)
    assert woke == [True]
    assert clock.wait_until(10.0, timeout_s=0.01) is False
