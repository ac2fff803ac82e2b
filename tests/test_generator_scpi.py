"""SCPI strings of every generator command, captured byte for byte on a serial line (pty) peer, and the
driver-side codec (number formatting, reply parsing)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st
from vfd_support import ScriptedPeer

from drivers.exciter.generator import GeneratorError, ScpiError, ScpiGenerator
from drivers.exciter.scpi import (
    ScpiReplyError,
    format_command,
    format_number,
    parse_bool,
    parse_error,
    parse_identity,
    parse_number,
)
from drivers.transport import open_transport

OK = (b"SYST:ERR?\n", b'+0,"No error"\n')


def cmd(text: str) -> list[tuple[bytes, bytes]]:
    """A command the driver must send, followed by its error check."""
    return [(text.encode() + b"\n", b""), OK]


def run(script: list[tuple[bytes, bytes]], action: Callable[[ScpiGenerator], Any], channel: int = 1) -> Any:
    peer = ScriptedPeer(script)
    transport = open_transport(peer.client_port, timeout_s=1.0)
    try:
        result = action(ScpiGenerator(transport, channel=channel, timeout_s=0.5))
    finally:
        transport.close()
        peer.close()
    assert peer.mismatch is None, f"expected {peer.mismatch[0]!r}, got {peer.mismatch[1]!r}"
    assert bytes(peer.received) == b"".join(req for req, _ in script)
    return result


def test_identify() -> None:
    idn = run([(b"*IDN?\n", b"Keysight Technologies,33522B,MY12345678,4.03-1.19-2.00-52-00\n"), OK],
              lambda g: g.identify())
    assert (idn.manufacturer, idn.model, idn.serial) == ("Keysight Technologies", "33522B", "MY12345678")


@pytest.mark.parametrize(("action", "text"), [
    (lambda g: g.set_sine(), "SOUR1:FUNC SIN"),
    (lambda g: g.set_frequency_hz(10.0), "SOUR1:FREQ 10"),
    (lambda g: g.set_frequency_hz(12.5), "SOUR1:FREQ 12.5"),
    (lambda g: g.set_frequency_hz(1e-6), "SOUR1:FREQ 1E-06"),
    (lambda g: g.set_amplitude_vpp(0.5), "SOUR1:VOLT 0.5"),
    (lambda g: g.set_output(True), "OUTP1 ON"),
    (lambda g: g.set_output(False), "OUTP1 OFF"),
    (lambda g: g.set_load_high_z(), "OUTP1:LOAD INF"),
    (lambda g: g.set_sweep(True), "SOUR1:SWE:STAT ON"),
    (lambda g: g.set_sweep(False), "SOUR1:SWE:STAT OFF"),
])
def test_single_commands(action: Callable[[ScpiGenerator], Any], text: str) -> None:
    run(cmd(text), action)


def test_units_and_offset() -> None:
    run(cmd("SOUR1:VOLT:UNIT VPP") + cmd("SOUR1:VOLT:OFFS 0"), lambda g: g.configure_units())


@pytest.mark.parametrize(("spacing", "code"), [("linear", "LIN"), ("log", "LOG")])
def test_sweep_configuration(spacing: str, code: str) -> None:
    script = (cmd("SOUR1:FREQ:STAR 5") + cmd("SOUR1:FREQ:STOP 30") + cmd(f"SOUR1:SWE:SPAC {code}")
              + cmd("SOUR1:SWE:TIME 60") + cmd("TRIG1:SOUR IMM"))
    run(script, lambda g: g.configure_sweep(5.0, 30.0, 60.0, spacing))


def test_channel_two_headers() -> None:
    run(cmd("SOUR2:FREQ 10") + cmd("OUTP2 ON"), lambda g: (g.set_frequency_hz(10), g.set_output(True)),
        channel=2)


def test_queries_parse_their_replies() -> None:
    script = [(b"SOUR1:FREQ?\n", b"+1.00000000000000E+01\n"), OK, (b"OUTP1?\n", b"1\n"), OK,
              (b"SOUR1:VOLT?\n", b"+5.0000E-01\n"), OK, (b"*OPC?\n", b"1\n"), OK]
    freq, out, volt, _ = run(script, lambda g: (g.frequency_hz(), g.output(), g.amplitude_vpp(),
                                                g.wait_complete()))
    assert (freq, out, volt) == (10.0, True, 0.5)


def test_remote_mode() -> None:
    run(cmd("SYST:REM"), lambda g: g.set_remote())


def test_clear_status() -> None:
    run([(b"*CLS\n", b""), OK], lambda g: g.clear_status())


def test_queued_errors_are_drained_and_raised_with_the_command() -> None:
    script = [(b"SOUR1:FREQ 1000000000\n", b""),
              (b"SYST:ERR?\n", b'-222,"Data out of range"\n'),
              (b"SYST:ERR?\n", b'-221,"Settings conflict"\n'),
              (b"SYST:ERR?\n", b'+0,"No error"\n')]
    with pytest.raises(ScpiError) as info:
        run(script, lambda g: g.set_frequency_hz(1e9))
    assert info.value.errors == [(-222, "Data out of range"), (-221, "Settings conflict")]
    assert info.value.code == -222 and info.value.command == "SOUR1:FREQ 1000000000"


def test_missing_query_reply_reports_the_queued_error() -> None:
    script = [(b"SOUR1:FREQ?\n", b""), (b"SYST:ERR?\n", b'-113,"Undefined header"\n'), OK]
    with pytest.raises(ScpiError, match="Undefined header"):
        run(script, lambda g: g.frequency_hz())


def test_silent_instrument_raises_a_timeout_error() -> None:
    with pytest.raises(GeneratorError, match=r"no reply within 0.5 s"):
        run([(b"SOUR1:FUNC SIN\n", b"")], lambda g: g.set_sine())


# ----------------------------------------------------------------------------------- codec


@given(st.floats(-1e12, 1e12, allow_nan=False, allow_infinity=False))
def test_number_format_round_trips(value: float) -> None:
    assert parse_number(format_number(value)) == value


@pytest.mark.parametrize(("reply", "value"), [("+1.00000000000000E+01", 10.0), ("1.000000E+02", 100.0),
                                              ("10HZ", 10.0), (" 0.5 ", 0.5), ("-3", -3.0)])
def test_number_replies_of_several_makers(reply: str, value: float) -> None:
    assert parse_number(reply) == value


def test_scpi_infinity() -> None:
    assert math.isinf(parse_number("9.9E+37"))


def test_bad_replies_raise() -> None:
    for bad in ("", "ten", "1,2"):
        with pytest.raises(ScpiReplyError):
            parse_number(bad)
    with pytest.raises(ScpiReplyError):
        parse_bool("2")
    with pytest.raises(ScpiReplyError):
        parse_error("No error")


def test_error_and_bool_parsing() -> None:
    assert parse_error('+0,"No error"') == (0, "No error")
    assert parse_error('-350,"Queue overflow"') == (-350, "Queue overflow")
    assert parse_bool("ON") and not parse_bool("0")


def test_rigol_identity_with_padding_and_empty_field() -> None:
    idn = parse_identity("RIGOL TECHNOLOGIES,DG1022 ,DG1D123456789,,00.02.00.06.00.02")
    assert (idn.model, idn.serial) == ("DG1022", "DG1D123456789")


def test_command_formatting_rejects_bad_input() -> None:
    assert format_command("SOUR1:FREQ", 10) == "SOUR1:FREQ 10"
    with pytest.raises(ValueError, match="not a SCPI command header"):
        format_command("SOUR1 FREQ")
    with pytest.raises(ValueError, match="must be a finite number"):
        format_command("SOUR1:FREQ", float("nan"))
    with pytest.raises(ValueError, match="without ; , or newline"):
        format_command("SOUR1:FUNC", "SIN;*RST")


def test_phase_restart_is_bracketed_by_one_round_trip() -> None:
    """``PHAS:SYNC;*OPC?`` goes as one message; the bracket's end is read as its reply arrives, before the
    error queue is read."""
    reads: list[str] = []
    ticks = iter([1.0, 2.0])

    def now_s() -> float:
        reads.append("clock")
        return next(ticks)

    bracket = run([(b"SOUR2:PHAS:SYNC;*OPC?\n", b"1\n"), OK],
                  lambda g: g.synchronize_phase_bracketed(now_s), channel=2)
    assert bracket == (1.0, 2.0) and reads == ["clock", "clock"]
