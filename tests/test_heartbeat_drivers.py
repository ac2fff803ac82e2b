"""Device heartbeats against the protocol mocks (b-CAP over TCP, Modbus RTU over a pty and Modbus TCP,
SCPI over TCP), on the simulated station with a paced clock: healthy devices keep beating through a long
move and a sweep without a request beside a call in flight; a mock that stops answering or closes the
connection is reported lost, naming the device, the age of the last contact and the limit."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import pytest
from heartbeat_support import HEARTBEAT_TIMEOUT_S, BeatWatcher, sim_station, wait_until

from drivers.denso import bcap
from drivers.denso.motion import WaitSettings
from drivers.exciter.sweep import LinearSweep
from drivers.heartbeat import ContactRecord, DeviceLostError, Heartbeat, HeartbeatError

LIMIT = HEARTBEAT_TIMEOUT_S
MOVE_TARGET = [420.0, 0.0, 300.0, 90.0, 0.0, 90.0]  # 70 mm from home


def test_arm_keeps_beating_through_a_long_paced_move_and_probes_only_when_idle() -> None:
    with sim_station(rate=2.0) as (st, servers):
        arm, server = st.devices["robot"], servers["robot"]
        arm.wait = WaitSettings(wait_mode="blocking")  # this test is about a blocking Move's keep-alives
        monitor = arm.heartbeat_monitor
        with BeatWatcher(arm) as watcher:
            probes_before = monitor.probes_sent
            keepalives_before = arm.client.link.keepalives_seen
            t0 = time.monotonic()
            arm.move_to(MOVE_TARGET, speed_mm_s=17.5)  # 4 s virtual = 2 s wall at rate 2
            move_wall_s = time.monotonic() - t0
            probes_during_move = monitor.probes_sent - probes_before
            assert wait_until(lambda: monitor.probes_sent >= probes_before + 2, 3.0)  # idle → CurPos probes
        assert watcher.error is None and watcher.beats > 10
        assert move_wall_s > LIMIT  # longer than the limit: only the keep-alives kept it alive
        assert arm.client.link.keepalives_seen - keepalives_before >= 3
        assert probes_during_move == 0  # never a request beside the blocking Move (it would get E_BUSY_PROC)
        assert monitor.probe_errors == []
        curpos = [a for a in server.requests if a[2] == bcap.ROBOT_EXECUTE]
        assert len(curpos) >= 3  # the move's own CurPos and the idle probes, all answered


def test_arm_that_stops_answering_is_lost_after_the_limit() -> None:
    with sim_station() as (st, servers):
        arm = st.devices["robot"]
        servers["robot"].faults.drop_replies = 10**6  # executes requests, never replies
        with BeatWatcher(arm) as watcher:
            err = watcher.wait_for_error(60.0)  # returns as soon as it is reported
        assert isinstance(err, DeviceLostError), err
        assert err.device == "robot" and err.limit_s == LIMIT and err.age_s > LIMIT and err.cause is None
        assert err.unanswered_s is not None and err.unanswered_s > LIMIT
        assert (f"robot: lost: no reply for {err.unanswered_s:.2f} s; last contact {err.age_s:.2f} s ago "
                f"(limit {LIMIT:g} s)") in str(err)
        assert "BcapTimeoutError" in str(err)  # the last probe's error is named
        assert watcher.error_after_s is not None and watcher.error_after_s > LIMIT  # not before the limit


def test_arm_whose_connection_closes_mid_move_is_lost_at_once() -> None:
    with sim_station() as (st, servers):
        arm = st.devices["robot"]
        servers["robot"].faults.close_mid_move = True
        with BeatWatcher(arm) as watcher:
            with pytest.raises(Exception, match="link closed"):
                arm.move_to(MOVE_TARGET, speed_mm_s=17.5)
            err = watcher.wait_for_error(30.0)  # the latched failure: at the next check
        assert isinstance(err, DeviceLostError) and err.device == "robot"
        assert "link failed (b-CAP link closed during Robot_Move" in str(err)
        assert err.age_s < LIMIT  # reported from the latched failure, not from the age


# Limits for the VFD case, wide enough for a loaded machine (make test-load): a Modbus reply may take a
# second there, so the healthy part must not be decided by scheduling; the loss is still seen, later.
VFD_LIMIT_S, VFD_TIMEOUT_S = 5.0, 1.0


@pytest.mark.parametrize("name", ["exciter", "rotor"])  # Modbus RTU over a pty / Modbus TCP
def test_vfd_keeps_beating_through_a_sweep_and_is_lost_when_it_stops_answering(name: str) -> None:
    settings = {"station.heartbeat_timeout_s": VFD_LIMIT_S, f"devices.{name}.timeout_s": VFD_TIMEOUT_S}
    with sim_station(rate=4.0, **settings) as (st, servers):
        axis = st.devices[name]  # left running after the sweep
        with BeatWatcher(axis) as watcher:
            result = axis.sweep(LinearSweep(2.0, 4.0, 12.0), update_interval_s=0.5)  # 3 s wall, unloaded
            assert len(result.samples) > 10
            idle_probes = axis.heartbeat_monitor.probes_sent
            # the idle link is probed (STATUS read) after a quarter of the limit; bound generously
            assert wait_until(lambda: axis.heartbeat_monitor.probes_sent > idle_probes, 60.0)
            assert watcher.error is None and watcher.beats > 20
            servers[name].inject("no_reply", count=None)
            err = watcher.wait_for_error(120.0)  # returns as soon as it is reported
        assert isinstance(err, DeviceLostError), err
        assert err.device == name and err.age_s > VFD_LIMIT_S
        assert f"{name}: lost: no reply for " in str(err) and f"(limit {VFD_LIMIT_S:g} s)" in str(err)
        servers[name].clear_faults()


def test_vfd_probe_reports_a_drive_fault() -> None:
    with sim_station(rate=4.0) as (st, servers):
        rotor = st.devices["rotor"]
        rotor.set_rotation_hz(1.0)
        servers["rotor"].drive.trip(0x05)  # overload
        with BeatWatcher(rotor) as watcher:
            err = watcher.wait_for_error(60.0)  # returns as soon as it is reported
        assert isinstance(err, HeartbeatError) and not isinstance(err, DeviceLostError)
        assert str(err) == "rotor: drive reports fault code 5 (oL: drive overload)"


def test_generator_keeps_beating_through_a_sweep_and_is_lost_when_disconnected() -> None:
    # limits a loaded machine cannot cross while healthy (its probes wait up to half the limit): a probe
    # error here is a probe beside the sweep's own calls, not a slow reply
    settings = {"station.heartbeat_timeout_s": VFD_LIMIT_S, "devices.generator.timeout_s": VFD_TIMEOUT_S}
    with sim_station(rate=4.0, **settings) as (st, servers):
        shaker = st.devices["generator"]
        with BeatWatcher(shaker) as watcher:
            probes_before = shaker.heartbeat_monitor.probes_sent
            shaker.sweep(5.0, 10.0, 8.0, amplitude_mm=0.5)  # the driver sleeps 2 s wall while it sweeps
            # *OPC? once the link was idle for a quarter of the limit; bound generously
            assert wait_until(lambda: shaker.heartbeat_monitor.probes_sent > probes_before, 60.0)
            assert shaker.heartbeat_monitor.probe_errors == []
            assert watcher.error is None
            servers["generator"].inject("disconnect")
            err = watcher.wait_for_error(60.0)  # returns as soon as it is reported
        assert isinstance(err, DeviceLostError) and err.device == "generator"
        assert "link failed (SCPI link closed" in str(err)


def test_generator_that_stops_answering_is_lost_after_the_limit() -> None:
    with sim_station(rate=4.0) as (st, servers):
        shaker = st.devices["generator"]
        servers["generator"].inject("no_reply")
        with BeatWatcher(shaker) as watcher:
            err = watcher.wait_for_error(60.0)  # returns as soon as it is reported
        assert isinstance(err, DeviceLostError) and err.device == "generator" and err.age_s > LIMIT
        assert "LinkError: *OPC? (heartbeat): no reply" in str(err)


def test_probe_is_never_sent_while_the_link_is_held() -> None:
    record = ContactRecord()
    sent: list[float] = []
    beat = Heartbeat("dev", record, lambda: sent.append(time.monotonic()), timeout_s=0.4)
    release = threading.Event()

    def procedure_call() -> None:
        with record.exchange():
            release.wait(5.0)
            record.touch()

    caller = threading.Thread(target=procedure_call)
    caller.start()
    assert wait_until(lambda: record.busy, 2.0)
    time.sleep(0.15)  # idle longer than the probe interval (0.1 s), but a call is in flight
    assert beat.check() is True
    time.sleep(0.05)
    assert sent == [] and beat.probes_sent == 0
    release.set()
    caller.join()
    time.sleep(0.15)
    assert beat.check() is True and wait_until(lambda: len(sent) == 1, 2.0)  # idle and free: one probe


def test_idle_link_is_probed_not_lost_silent_calls_are_not_counted_and_bad_timing_is_refused() -> None:
    record = ContactRecord()
    beat = Heartbeat("robot", record, lambda: None, timeout_s=0.1)
    time.sleep(0.15)  # nobody asked for longer than the limit: not lost, a probe is due
    assert beat.check() is True and wait_until(lambda: beat.probes_sent == 1, 2.0)
    record.silent_calls = True  # b-CAP without WDT: a blocking call sends nothing until it ends
    with record.exchange():
        time.sleep(0.15)
        assert beat.check() is True
    record.silent_calls = False
    with pytest.raises(ZeroDivisionError), record.exchange():
        1 / 0  # noqa: B018 — a request that got no answer
    with pytest.raises(DeviceLostError, match=r"robot: lost: no reply for 0\.\d\d s; last contact "
                                              r"\d+\.\d\d s ago \(limit 0\.1 s\)"):  # the age: wall time
        for _ in range(1000):  # checked regularly (as the watchdog does), well within the probe interval
            beat.check()
            time.sleep(0.005)
    record.touch()
    assert beat.check() is True
    record.fail("closed by the peer")
    with pytest.raises(DeviceLostError, match=r"link failed \(closed by the peer\)"):
        beat.check()
    with pytest.raises(ValueError, match="heartbeat timeout_s=0: must be"):
        Heartbeat("x", record, lambda: None, timeout_s=0)
    with pytest.raises(ValueError, match=r"heartbeat interval_s=2\.0: must be > 0 s and below timeout_s=1"):
        Heartbeat("x", record, lambda: None, timeout_s=1.0, interval_s=2.0)


class FakeWall:
    """A wall clock the test moves."""

    def __init__(self) -> None:
        self.t_s = 100.0

    def __call__(self) -> float:
        return self.t_s


def _unanswered(record: ContactRecord) -> None:
    with pytest.raises(TimeoutError), record.exchange():
        raise TimeoutError("no reply")  # a request that got no answer: pending until the next reply


def test_silence_counts_on_the_checks_own_cadence_so_a_starved_checker_declares_nothing() -> None:
    """A device asked and silent is lost after ``timeout_s`` of regular checks (the watchdog's period ≤
    the probe interval: the count is the wall time); a gap between two checks longer than the probe
    interval — this process was not running, so an in-process mock was starved alike and a real reply
    may sit unread — counts as one interval only."""
    wall = FakeWall()
    record = ContactRecord(wall_s=wall)
    beat = Heartbeat("exciter", record, lambda: None, timeout_s=2.0)  # probe interval 0.5 s
    assert beat.check() is True
    _unanswered(record)
    wall.t_s += 0.25
    for _ in range(8):  # up to 2.0 s of checks every 0.25 s: not yet
        assert beat.check() is True
        wall.t_s += 0.25
    with pytest.raises(DeviceLostError, match=r"exciter: lost: no reply for 2\.25 s; last contact 2\.25 s"):
        beat.check()  # past the limit at the first check after it: a silent device is lost on time

    record.touch()
    assert beat.check() is True
    _unanswered(record)
    wall.t_s += 30.0  # the checker itself starved for 30 s (the wall says 30 s unanswered)
    assert beat.check() is True  # counted: one interval (0.5 s)
    for _ in range(6):  # then checked regularly: 0.5 + 6 × 0.25 = 2.0 s
        wall.t_s += 0.25
        assert beat.check() is True
    wall.t_s += 0.25
    with pytest.raises(DeviceLostError, match=r"no reply for 2\.25 s; last contact 31\.75 s ago"):
        beat.check()
    record.touch()  # it answered: the count starts again
    assert beat.check() is True


def test_a_reply_on_a_fresh_link_clears_a_latched_failure() -> None:
    record = ContactRecord(wall_s=FakeWall())
    beat = Heartbeat("robot", record, lambda: None, timeout_s=2.0)
    record.fail("b-CAP link closed during Robot_Move")
    with pytest.raises(DeviceLostError, match=r"link failed \(b-CAP link closed during Robot_Move\)"):
        beat.check()
    record.touch()  # a reply, over the reconnected link
    assert beat.check() is True and record.failure is None
    assert record.recovered_from == "b-CAP link closed during Robot_Move"


def test_wait_probes_now_for_rig_check() -> None:
    with sim_station(rate=8.0) as (st, servers):
        for name in ("robot", "exciter", "rotor", "generator"):
            assert st.devices[name].heartbeat(wait=True) is True
        servers["rotor"].inject("no_reply", count=None)
        with pytest.raises(DeviceLostError, match=r"rotor: lost: no reply; last contact .* \(limit 1 s\) "
                                                  r"\(probe failed: VfdCommunicationError: heartbeat"):
            st.devices["rotor"].heartbeat(wait=True)
        servers["rotor"].clear_faults()


def test_aggressive_probing_interleaves_safely_with_the_procedures_own_calls() -> None:
    """Probes every 5 ms of idle line, from another thread, while the procedure talks to every device:
    the link locks keep each request/reply exchange whole (no mixed-up Modbus transactions, no SCPI
    reply read by the wrong caller, no b-CAP request beside a call in flight). Reply time-outs and the loss
    limit are long (their subject is elsewhere): any probe error here is a mix-up, not a slow machine."""
    patient = {f"devices.{n}.timeout_s": 3.0 for n in ("robot", "exciter", "rotor", "generator")}
    with sim_station(rate=10.0, **patient) as (st, _servers):
        devices = st.devices
        for name in ("robot", "exciter", "rotor", "generator"):
            dev = devices[name]
            old = dev.heartbeat_monitor
            dev.heartbeat_monitor = Heartbeat(name, old.record, old.probe, timeout_s=30.0, interval_s=0.005)
        names = ("robot", "exciter", "rotor", "generator")
        watchers = [BeatWatcher(devices[n], period_s=0.002) for n in names]
        for w in watchers:
            w.__enter__()
        try:
            for x_mm in (380.0, 400.0, 360.0):
                devices["robot"].move_to([x_mm, 0.0, 300.0, 90.0, 0.0, 90.0], speed_mm_s=200.0)
            devices["exciter"].set_frequency(3.0)
            devices["rotor"].set_rotation_hz(2.0)
            devices["generator"].start(10.0, 0.5)
            devices["generator"].stop()
            devices["exciter"].stop()
        finally:
            for w in watchers:
                w.__exit__()
        for w in watchers:
            assert w.error is None, w.error
            monitor = w.device.heartbeat_monitor
            assert monitor.probes_sent > 0 and monitor.probe_errors == [], monitor.probe_errors


def _hammer(calls: list[Callable[[], object]], n: int) -> list[BaseException]:
    """Run each call ``n`` times in its own thread, all at once; return the errors."""
    errors: list[BaseException] = []
    start = threading.Barrier(len(calls))

    def loop(call: Callable[[], object]) -> None:
        start.wait()
        try:
            for _ in range(n):
                call()
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=loop, args=(c,)) for c in calls]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60.0)
    return errors


def test_probe_and_procedure_calls_from_two_threads_never_mix_replies() -> None:
    with sim_station(rate=8.0) as (st, _servers):
        shaker, arm = st.devices["generator"], st.devices["robot"]
        shaker.generator.set_frequency_hz(12.5)
        pose = arm.position()

        def read_frequency() -> None:
            assert shaker.generator.frequency_hz() == 12.5

        def read_pose() -> None:
            assert (arm.position() == pose).all()

        errors = _hammer([read_frequency, shaker.heartbeat_monitor.probe, read_pose,
                          arm.heartbeat_monitor.probe], 150)
        assert errors == []
