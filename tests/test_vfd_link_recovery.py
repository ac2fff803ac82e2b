"""Link recovery: the driver stays in step with a drive that answers late, twice, with the previous
request's reply or with bytes missing, and a stop is repeated on fresh links until its deadline.

Driver ↔ mock over the real pty (RTU) and TCP links. Where a deadline matters the link gets a step clock
(every reading advances it by 1 s), so the number of attempts is exact and no wall-clock window is
asserted.
"""

from __future__ import annotations

import pytest
from vfd_support import vfd_rig

from drivers.exciter.vfd import VfdCommunicationError, VfdError, VfdExceptionResponseError
from drivers.mock.vfd_server import VfdServer

MODES = ["rtu", "tcp"]
TIMEOUT_S = 0.25  # from the first injected fault on; the set-up's exchanges wait HEALTHY_TIMEOUT_S


class StepClock:
    """A link clock that advances 1 s at every reading (and by the pause at every sleep)."""

    def __init__(self) -> None:
        self.t = 0.0

    def monotonic(self) -> float:
        self.t += 1.0
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += seconds


def _expect_in_step(rig: object) -> None:
    """Several reads and writes in a row all get their own reply."""
    for hz in (4.0, 4.5):
        rig.vfd.set_frequency_hz(hz, verify=True)  # type: ignore[attr-defined]
        assert rig.vfd.read_status().freq_cmd_hz == pytest.approx(hz)  # type: ignore[attr-defined]


@pytest.mark.parametrize("mode", MODES)
def test_a_late_reply_is_not_taken_for_the_next_one_and_the_stop_goes_through(mode: str) -> None:
    """The issue's defect: a read times out, its reply comes late, and the stop after it must succeed."""
    with vfd_rig(mode) as rig:
        rig.exciter.set_frequency(5.0)
        rig.client.timeout_s = TIMEOUT_S  # set up; now the faults
        rig.client.retries = 0  # the read fails at its first time-out
        rig.server.inject("late", 2 * TIMEOUT_S, count=1)
        with pytest.raises(VfdCommunicationError) as info:
            rig.exciter.read_sample()
        exc = info.value
        assert exc.stop_attempted and exc.stop_ok, str(exc)
        assert "stop command sent and acknowledged" in str(exc)
        assert not rig.drive.running
        _expect_in_step(rig)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize(("fault", "value"), [("twice", None), ("previous", None), ("drop", 2),
                                              ("late", 1.5)])
def test_commands_survive_an_out_of_step_reply(mode: str, fault: str, value: float | None) -> None:
    """Every kind of stray reply costs a repeated request, not a failure. (A reply 1.5 time-outs late
    lands in the middle of the repeated request's wait; a third attempt leaves room for a loaded machine.)"""
    with vfd_rig(mode, timeout_s=1.0, retries=2) as rig:
        rig.vfd.read_status()
        before = rig.client.requests_sent
        rig.server.inject(fault, value, count=1)
        rig.vfd.set_frequency_hz(7.0, verify=True)  # a write then a read, both must get their own reply
        rig.vfd.run("forward")
        _expect_in_step(rig)
        assert rig.drive.running and rig.drive.regs[0x2001] == 450  # the last setpoint, 4.50 Hz
        sent = rig.client.requests_sent - before
        if fault != "twice":  # a duplicate that arrived before the next request is just drained
            assert sent > 6, f"{fault}: no request was repeated ({sent} sent)"
        assert rig.client.stale_replies + rig.client.discarded_bytes + rig.client.reconnects > 0


@pytest.mark.parametrize("mode", MODES)
def test_stop_repeats_on_fresh_links_until_acknowledged(mode: str) -> None:
    with vfd_rig(mode, stop_deadline_s=10.0) as rig:
        rig.exciter.set_frequency(5.0)
        rig.client.timeout_s = TIMEOUT_S  # set up; now the faults
        rig.client.clock = StepClock()
        reconnects = rig.client.reconnects
        rig.server.inject("no_reply", count=3)
        rig.vfd.stop()
        assert rig.vfd.stop_attempts == 4
        assert rig.client.reconnects - reconnects == 3  # a fresh link before every repetition
        assert not rig.drive.running


@pytest.mark.parametrize("mode", MODES)
def test_stop_gives_up_at_its_deadline_and_says_how_often_it_tried(mode: str) -> None:
    with vfd_rig(mode, stop_deadline_s=5.0) as rig:
        rig.exciter.set_frequency(5.0)
        rig.client.timeout_s = TIMEOUT_S  # set up; now the faults
        rig.client.clock = StepClock()  # start reading 1, end 6; readings 2..6 after attempts 1..5
        rig.server.inject("no_reply", count=None)
        with pytest.raises(VfdCommunicationError, match=r"not acknowledged after 5 attempt\(s\) within 5 s"):
            rig.vfd.stop()
        assert rig.vfd.stop_attempts == 5
        # "no_reply" executes the request and loses the reply: the drive did stop, but the driver cannot
        # know it and says so; once replies come back the stop is acknowledged at once
        rig.server.clear_faults()
        rig.client.timeout_s = 30.0  # its reply may take long on a loaded machine; it is not lost
        rig.vfd.stop()
        assert rig.vfd.stop_attempts == 1 and not rig.drive.running


def test_stop_waits_out_a_busy_drive_but_not_a_refusal() -> None:
    with vfd_rig("rtu", stop_deadline_s=10.0) as rig:
        rig.exciter.set_frequency(5.0)
        rig.client.timeout_s = TIMEOUT_S  # set up; now the faults
        rig.client.clock = StepClock()
        rig.server.inject("busy", count=2)
        rig.vfd.stop()
        assert rig.vfd.stop_attempts == 3 and not rig.drive.running
        rig.server.inject("exception", count=None, exception_code=4)  # device failure: not retried
        with pytest.raises(VfdExceptionResponseError, match="exception 4"):
            rig.vfd.stop()


def test_after_a_failure_the_stop_survives_a_cable_pulled_for_a_moment() -> None:
    with vfd_rig("rtu", stop_deadline_s=30.0) as rig:
        rig.exciter.set_frequency(5.0)
        rig.client.timeout_s = TIMEOUT_S  # set up; now the faults
        server: VfdServer = rig.server
        rig.client.retries = 0
        server.inject("disconnect", 0.3, count=1)  # the cable is pulled for 0.3 s, then plugged back
        with pytest.raises(VfdError) as info:
            rig.exciter.read_sample()
        assert info.value.stop_ok, str(info.value)
        assert not rig.drive.running


@pytest.mark.parametrize("mode", MODES)
def test_stop_on_a_link_its_owner_closed_fails_at_once_without_spinning(mode: str) -> None:
    """A closed link opens no fresh one: the stop reports it after one attempt (it used to retry in a
    busy loop until its deadline on the injected clock — thousands of attempts on an instant clock)."""
    with vfd_rig(mode, stop_deadline_s=5.0) as rig:
        rig.exciter.set_frequency(5.0)
        rig.client.timeout_s = TIMEOUT_S  # set up; now the faults
        rig.client.close()
        with pytest.raises(VfdCommunicationError, match=r"the link was closed after 1 attempt\(s\)"):
            rig.vfd.stop()
        assert rig.vfd.stop_attempts == 1
