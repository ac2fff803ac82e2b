"""Every injected fault ends in a clear exception within the timeout, and a stop command is attempted.

Driver ↔ mock over Modbus TCP and over RTU on a pty. The client timeout is 0.25 s (no retries where one
fault must make one failure), so a lost reply costs 0.25 s; the stop after it is repeated on fresh links
for at most the driver's stop deadline (2 s here); the wall-time bound below is that worst case plus a
generous allowance for a loaded machine — a liveness check, not a speed test.
"""

from __future__ import annotations

import re
import time

import pytest
from vfd_support import HEALTHY_TIMEOUT_S, vfd_rig

from drivers.exciter.sweep import LinearSweep
from drivers.exciter.vfd import (
    VfdCommunicationError,
    VfdError,
    VfdExceptionResponseError,
    VfdFaultError,
)
from drivers.mock.vfd_drive import FAULT_OVERLOAD, FAULT_WATCHDOG
from drivers.modbus_link import ModbusLinkError

TIMEOUT_S = 0.25  # the reply time-out while a fault is injected (HEALTHY_TIMEOUT_S around it)
STOP_DEADLINE_S = 2.0
WORST_CASE_S = 2 * TIMEOUT_S + STOP_DEADLINE_S + 30.0  # a liveness bound (a loaded machine), not a speed test

MODES = ["tcp", "rtu"]


def _timed(fn):
    t0 = time.monotonic()
    try:
        fn()
    except VfdError as exc:
        return exc, time.monotonic() - t0
    raise AssertionError("no exception raised")


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize(("fault", "error", "pattern"), [
    ("no_reply", VfdCommunicationError, "no valid reply after 1 attempt.*TransportTimeout"),
    ("bad_crc", VfdCommunicationError, "no valid reply after 1 attempt.*(CRC error|malformed MBAP)"),
    ("exception", VfdExceptionResponseError, r"exception 6 \(device busy\)"),
])
def test_single_fault_raises_and_the_stop_goes_through(mode: str, fault: str, error: type,
                                                        pattern: str) -> None:
    with vfd_rig(mode, timeout_s=HEALTHY_TIMEOUT_S) as rig:
        rig.exciter.set_frequency(5.0)
        assert rig.drive.running
        rig.client.retries, rig.client.timeout_s = 0, TIMEOUT_S  # one fault, one failure
        rig.server.inject(fault, count=1)
        exc, elapsed = _timed(rig.exciter.read_sample)
        assert isinstance(exc, error)
        assert elapsed < WORST_CASE_S
        assert exc.stop_attempted and exc.stop_ok, str(exc)
        assert "stop command sent and acknowledged" in str(exc)
        assert re.search(pattern, str(exc)), str(exc)
        assert not rig.drive.running  # the stop really arrived at the drive


@pytest.mark.parametrize("mode", MODES)
def test_persistent_silence_fails_the_stop_too_and_says_so(mode: str) -> None:
    with vfd_rig(mode, timeout_s=HEALTHY_TIMEOUT_S) as rig:
        rig.exciter.set_frequency(5.0)
        rig.client.timeout_s = TIMEOUT_S
        rig.server.inject("no_reply", count=None)
        exc, elapsed = _timed(lambda: rig.exciter.set_frequency(6.0))
        assert isinstance(exc, VfdCommunicationError)
        assert elapsed < WORST_CASE_S
        assert exc.stop_attempted and exc.stop_ok is False
        assert "stop command attempted but failed" in str(exc)
        rig.server.clear_faults()
        rig.client.timeout_s = HEALTHY_TIMEOUT_S
        rig.exciter.stop()
        assert not rig.drive.running


@pytest.mark.parametrize("mode", MODES)
def test_disconnect_raises_and_a_stop_is_attempted(mode: str) -> None:
    with vfd_rig(mode, timeout_s=HEALTHY_TIMEOUT_S) as rig:
        rig.exciter.set_frequency(5.0)
        rig.client.retries, rig.client.timeout_s = 0, TIMEOUT_S
        rig.server.inject("disconnect", count=1)
        exc, elapsed = _timed(rig.exciter.read_sample)
        assert isinstance(exc, VfdCommunicationError), exc
        assert elapsed < WORST_CASE_S
        assert exc.stop_attempted
        if mode == "rtu":  # a pulled cable stays pulled: the stop cannot arrive
            assert exc.stop_ok is False
            assert rig.drive.running
            rig.server.clear_faults()
            rig.client.timeout_s = HEALTHY_TIMEOUT_S
            rig.exciter.stop()
        assert not rig.drive.running


@pytest.mark.parametrize("mode", MODES)
def test_drive_overload_during_a_sweep_raises_a_fault_and_stops(mode: str) -> None:
    # gear 1.5, max 60 Hz; I = 0.8 + 3.2·(f/60)²; 2.4 A ↔ f_drive = 60·sqrt(0.5) = 42.4 Hz ↔ 28.3 Hz vibration
    with vfd_rig(mode, timeout_s=HEALTHY_TIMEOUT_S, overload_current_a=2.4) as rig:
        with pytest.raises(VfdFaultError, match="fault code 5") as info:
            rig.exciter.sweep(LinearSweep(5.0, 30.0, 15.0))
        assert info.value.fault_code == FAULT_OVERLOAD
        assert info.value.stop_attempted and info.value.stop_ok
        t = rig.clock.now_s()
        f_trip = 60 * 0.5**0.5 / 1.5
        assert rig.drive.fault_time_s is not None
        assert rig.world.exciter.frequency_hz(rig.drive.fault_time_s) == pytest.approx(f_trip, rel=1e-9)
        peak = max(rig.world.exciter.frequency_hz(t - k * 0.01) for k in range(int(t / 0.01)))
        assert peak <= f_trip * (1 + 1e-9)  # the twin never went past the trip point


@pytest.mark.parametrize("mode", ["tcp"])
def test_watchdog_trip_is_reported_on_the_next_poll(mode: str) -> None:
    with vfd_rig(mode, timeout_s=HEALTHY_TIMEOUT_S, watchdog_s=0.5) as rig:
        rig.exciter.set_frequency(5.0)  # polls every 0.25 s: the watchdog stays fed
        rig.clock.sleep_s(2.0)  # the procedure goes silent
        with pytest.raises(VfdFaultError, match="CE10") as info:
            rig.exciter.read_sample()
        assert info.value.fault_code == FAULT_WATCHDOG
        assert info.value.stop_attempted


def test_rtu_drive_stays_silent_for_another_unit_id() -> None:
    with vfd_rig("rtu", timeout_s=HEALTHY_TIMEOUT_S) as rig:
        assert rig.client.read_holding_registers(1, 0x2100, 1) == [0]
        rig.client.timeout_s = TIMEOUT_S  # no reply is the expected outcome: waited for that long
        with pytest.raises(ModbusLinkError, match="TransportTimeout"):
            rig.client.read_holding_registers(7, 0x2100, 1)
