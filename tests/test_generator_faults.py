"""Faults of a real link, injected in the mock generator, and the driver's recovery from them: replies
late, twice, truncated, swallowed; a busy instrument; a connection closed after N messages; an error in
the queue. Also the mock's bounded input and its reaped connection threads. Everything over real
loopback sockets or a pty; waits are bounded by events or generous timeouts, never asserted."""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_generator_mock import Line

from drivers.exciter.generator import SAFE_OFF_PAUSE_S, GeneratorError, LinkError, ScpiError, ScpiGenerator
from drivers.mock.generator_instrument import GeneratorInstrument
from drivers.mock.generator_server import MAX_LINE, Fault, GeneratorServer, LineAssembler, main, parse_fault
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World
from drivers.transport import Transport, open_transport

TIMEOUT_S = 0.3


@contextlib.contextmanager
def served(mode: str = "tcp", faults: list[Fault] | None = None) -> Iterator[GeneratorServer]:
    world = World(VirtualClock(), seed=8)
    with GeneratorServer(GeneratorInstrument(world.shaker, world.clock), mode=mode, faults=faults) as server:
        yield server


@contextlib.contextmanager
def driver(server: GeneratorServer, *, reopen: bool = True, timeout_s: float = TIMEOUT_S
           ) -> Iterator[ScpiGenerator]:
    url = server.url

    def fresh() -> Transport:
        return open_transport(url, timeout_s=timeout_s)

    generator = ScpiGenerator(fresh(), timeout_s=timeout_s, reopen=fresh if reopen else None)
    try:
        yield generator
    finally:
        generator.close()


# ------------------------------------------------------------------------------------ fault parsing


def test_fault_specs_parse_with_defaults_and_refuse_nonsense() -> None:
    assert parse_fault("late:1.5") == Fault("late", 1.5)
    assert parse_fault("no-reply") == Fault("no_reply", None)
    assert parse_fault("disconnect") == Fault("disconnect", 0.0)
    assert parse_fault("error:-222") == Fault("error", -222.0, count=1)
    for bad, message in [("slow:1", "KIND must be one of"), ("late:x", "PARAM must be a number"),
                         ("twice:2", "takes no parameter"), ("busy:-1", "must be >= 0")]:
        with pytest.raises(ValueError, match=message):
            parse_fault(bad)


def test_command_line_refuses_a_bad_fault(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["--port", "0", "--fault", "melt"], prog="rig mock generator")
    assert info.value.code == 4  # bad input (rig's exit code; argparse's own is 2)
    assert "rig mock generator: error: argument --fault: --fault 'melt': KIND must be one of" in \
        capsys.readouterr().err


# ---------------------------------------------------------------------------------- the mock's side


def test_late_reply_arrives_after_the_next_line_was_executed() -> None:
    with served() as server:
        server.inject("late", 0.5, count=1)
        line = Line(server)
        try:
            line.send("FREQ 20")
            line.send("FREQ?")  # its reply is held back 0.5 s ...
            line.send("FREQ 30")  # ... while this executes
            assert float(line.ask("FREQ?")) == 20.0  # the late reply arrives first, in order
            assert float(line.file.readline()) == 30.0
        finally:
            line.close()


def test_twice_drop_no_reply_and_error_faults() -> None:
    with served() as server:
        line = Line(server)
        try:
            server.inject("twice", count=1)
            assert line.ask("*OPC?") == "1" and line.file.readline() == b"1\n"
            server.inject("drop", 3, count=1)  # "1.0" → the last 3 bytes, LF included, are lost
            line.send("*OPC?;*OPC?")
            assert line.ask("*OPC?") == "11"  # "1;" + the next reply "1"
            server.inject("no_reply", count=1)
            line.send("*IDN?")
            assert line.ask("*OPC?") == "1"
            server.inject("error", -310, count=1)
            line.send("*CLS")
            assert line.ask("SYST:ERR?") == '-310,"System error"'
        finally:
            line.close()


def test_disconnect_after_n_messages_and_busy() -> None:
    with served(faults=[Fault("disconnect", 3)]) as server:
        sock = socket.create_connection(("127.0.0.1", server.port), timeout=5.0)
        with sock:
            sock.sendall(b"*OPC?\n*OPC?\n*OPC?\n*OPC?\n")
            received = b""
            while chunk := sock.recv(100):
                received += chunk
            assert received == b"1\n1\n1\n"  # the fourth message was never executed
        server.clear_faults()
        server.inject("busy", 0.2, count=2)
        line = Line(server)
        try:
            assert line.ask("*OPC?") == "1"  # slow, but answered in order
            assert line.ask("*OPC?") == "1"
        finally:
            line.close()


def test_long_lines_are_discarded_whole_and_queued_once() -> None:
    errors: list[int] = []
    lines = LineAssembler(lambda: errors.append(-223), max_line=16)
    assert lines.feed(b"FREQ 1") == []
    assert lines.feed(b"0" * 20) == []  # over the limit: dropped, discarding until the LF
    assert lines.feed(b"0" * 5000 + b"\nFREQ?\r\n") == ["FREQ?"]
    assert errors == [-223]
    assert lines.feed(b"A" * 17 + b"\n*IDN?\n") == ["*IDN?"]
    assert errors == [-223, -223]
    with served() as server:
        line = Line(server)
        try:
            line.send("FREQ " + "1" * (3 * MAX_LINE))
            assert line.ask("SYST:ERR?") == '-223,"Too much data"'
            assert line.ask("SYST:ERR?") == '+0,"No error"'
        finally:
            line.close()


def test_finished_connection_threads_are_reaped() -> None:
    with served() as server:
        for _ in range(40):  # more than MAX_CONNECTIONS, one after the other
            line = Line(server)
            assert line.ask("*OPC?") == "1"
            line.close()
        deadline = time.monotonic() + 10.0
        while server.connection_threads and time.monotonic() < deadline:
            time.sleep(0.02)
        assert server.connection_threads == 0
        line = Line(server)  # still serving
        try:
            assert line.ask("*OPC?") == "1"
        finally:
            line.close()


# ------------------------------------------------------------------------------- the driver's side


@pytest.mark.parametrize("mode", ["tcp", "pty"])
def test_driver_recovers_from_a_late_reply(mode: str) -> None:
    # 1 s: only the injected fault makes an exchange late (with 0.3 s a loaded machine sent on-time
    # exchanges through the recovery paths too)
    timeout_s = 1.0
    with served(mode) as server, driver(server, timeout_s=timeout_s) as g:
        g.set_frequency_hz(12.0)
        server.inject("late", 2 * timeout_s, count=1)
        assert g.frequency_hz() == 12.0  # timed out, resynchronised, asked again
        assert g.resyncs >= 1
        g.set_frequency_hz(13.0)  # in step afterwards: every reply belongs to its request
        assert g.frequency_hz() == 13.0 and g.output() is False


def test_driver_recovers_from_duplicated_replies() -> None:
    with served() as server, driver(server) as g:
        server.inject("twice", count=1)
        assert g.frequency_hz() == 1000.0  # the copy was read as the SYST:ERR? reply: out of step
        assert g.resyncs == 1
        g.set_load_high_z()
        g.set_amplitude_vpp(1.5)
        assert g.amplitude_vpp() == 1.5


def test_driver_recovers_from_dropped_bytes() -> None:
    with served() as server, driver(server) as g:
        server.inject("drop", 1, count=1)  # the reply's LF is lost: it runs into the next line
        assert g.frequency_hz() == 1000.0
        assert g.resyncs >= 1
        assert g.sweep_enabled() is False


def test_stale_bytes_before_a_request_trigger_a_resynchronisation() -> None:
    with served() as server, driver(server) as g:
        g.transport.write(b"*IDN?\n")  # a reply nobody waits for: stale before the next request, or
        g.set_frequency_hz(15.0)  # read by its SYST:ERR? (out of step): resynchronised either way
        assert g.resyncs == 1 and g.frequency_hz() == 15.0
        assert server.instrument.status.ese == 0  # the marker leaves the enable mask as it was
        g.transport.write(b"*IDN?\n")
        # the heartbeat probe finds the stale reply (and resynchronises) or reads it as its own answer
        # (and says so); either way the next exchange is in step
        with contextlib.suppress(LinkError):
            g.probe()
        assert g.frequency_hz() == 15.0 and g.output() is False


def test_instrument_errors_are_not_retried() -> None:
    with served() as server, driver(server) as g:
        with pytest.raises(ScpiError, match="-222"):
            g.set_frequency_hz(1e9)
        assert g.resyncs == 0 and server.instrument.lines_received == 3  # command, SYST:ERR? ×2


def test_silent_link_fails_with_a_link_error_after_the_retry() -> None:
    with served() as server, driver(server, reopen=False) as g:
        server.inject("no_reply")
        with pytest.raises(LinkError, match=r"no reply within 0.3 s.*recovery failed"):
            g.frequency_hz()


def test_output_off_goes_on_a_fresh_link_after_a_disconnect() -> None:
    with served() as server, driver(server) as g:
        g.set_output(True)
        server.inject("disconnect", 0.0)  # drops the connection and refuses new ones
        old = g.transport
        with pytest.raises(GeneratorError):
            g.frequency_hz()
        server.clear_faults()  # the instrument is back: the next fresh link works
        outcome = g.output_off(min_amplitude_vpp=0.01, deadline_s=10.0)
        assert outcome.output_off and outcome.reconnects >= 1, outcome.describe()
        assert g.transport is not old
        assert server.instrument.output is False and server.instrument.emf_vpp == pytest.approx(0.02)


def test_output_off_reports_failure_at_its_deadline() -> None:
    with served() as server, driver(server) as g:
        server.inject("no_reply")
        outcome = g.output_off(deadline_s=1.0)
        assert not outcome.output_off and outcome.attempts >= 2 and outcome.reconnects >= 1
        assert "NOT confirmed" in outcome.describe() and "no reply" in outcome.describe()
        assert server.instrument.output is False  # OFF was executed; only the read-back was lost


def test_rig_mock_generator_passes_faults_to_the_mock() -> None:
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.Popen([sys.executable, "-m", "rig.cli", "mock", "generator", "--port", "0",
                             "--fault", "twice", "--fault", "error:-222"], cwd=root, stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1", "PYTHONPATH": str(root)})
    try:
        assert proc.stdout is not None
        banner = [proc.stdout.readline() for _ in range(3)]
        port = int(banner[0].split("tcp://127.0.0.1:")[1].split()[0])
        assert banner[1:] == ["fault injected: twice\n", "fault injected: error:-222\n"]
        with socket.create_connection(("127.0.0.1", port), timeout=10.0) as sock:
            stream = sock.makefile("rb")
            sock.sendall(b"*OPC?\n")
            assert [stream.readline(), stream.readline()] == [b"1\n", b"1\n"]
            sock.sendall(b"SYST:ERR?\n")
            assert stream.readline() == b'-222,"Data out of range"\n'
            stream.readline()  # its copy
            sock.sendall(b"SYST:ERR?\n")
            assert stream.readline() == b'+0,"No error"\n'  # pushed once, not after every message
    finally:
        proc.terminate()
        proc.wait(10.0)


def test_a_connection_that_cannot_be_served_does_not_stop_the_server_accepting() -> None:
    """accept_loop (shared by the mocks) carries on after a connection whose handler raises."""
    import socket
    import threading

    from drivers.mock._serve import accept_loop

    listener = socket.create_server(("127.0.0.1", 0))
    stopped = threading.Event()
    served: list[int] = []

    def on_connection(conn: socket.socket) -> None:
        served.append(1)
        if len(served) == 1:
            raise ConnectionResetError("reset before it was served")
        conn.close()

    thread = threading.Thread(target=accept_loop, args=(listener, stopped, on_connection), daemon=True)
    thread.start()
    try:
        for _ in range(2):
            socket.create_connection(listener.getsockname(), timeout=30).close()
        deadline = threading.Event()
        for _ in range(600):  # bounded: up to 60 s on a loaded machine
            if len(served) == 2:
                break
            deadline.wait(0.1)
        assert len(served) == 2 and thread.is_alive()
    finally:
        stopped.set()
        listener.close()
        thread.join(timeout=30)


def test_output_off_against_an_instrument_that_drops_every_connection_paces_its_rounds() -> None:
    """Each fresh link is accepted and closed at once: the make-safe keeps trying until its deadline, a
    pause apart (it reconnected in a busy loop: 990 rounds in 1 s, 10341 in 3 s on the twin)."""
    with served() as server, driver(server) as g:
        server.inject("disconnect", 0.0)  # closes the connection, and every new one at once
        outcome = g.output_off(deadline_s=1.0)
        assert not outcome.output_off
        assert 2 <= outcome.attempts <= 1.0 / SAFE_OFF_PAUSE_S + 1, outcome.describe()
