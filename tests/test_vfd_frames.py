"""Byte-level Modbus frames of every VFD driver command, captured by a scripted socket peer.

The RTU frames of docs/exciter.md (from the exciter notes) are the reference; frames the notes do not
list are built with an independent CRC-16/MODBUS written in the test support module.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vfd_support import ScriptedPeer, crc16_modbus, rtu, rtu_client_for

from drivers.exciter.register_map import RegisterMap
from drivers.exciter.vfd import (
    VfdCommunicationError,
    VfdDriver,
    VfdExceptionResponseError,
    VfdProtocolError,
)
from drivers.modbus_link import ModbusLink

# the notes' example frames (unit 1), with their CRC as documented
SET_10HZ = bytes.fromhex("01 06 20 01 03 E8 D3 74")
RUN_FWD = bytes.fromhex("01 06 20 00 00 12 02 07")
STOP = bytes.fromhex("01 06 20 00 00 01 43 CA")
FAULT_RESET = bytes.fromhex("01 06 20 02 00 02 A2 0B")
READ_STATUS = bytes.fromhex("01 03 21 00 00 05 8F F5")


@pytest.mark.parametrize("frame", [SET_10HZ, RUN_FWD, STOP, FAULT_RESET, READ_STATUS])
def test_independent_crc_matches_documented_frames(frame: bytes) -> None:
    assert crc16_modbus(frame[:-2]) == frame[-2:]


def _run(script: list[tuple[bytes, bytes]], action: Callable[[VfdDriver], Any], **driver_kwargs: Any) -> Any:
    """Run ``action`` on a driver whose RTU line ends in a scripted peer; check every byte it sent."""
    peer = ScriptedPeer(script)
    try:
        with rtu_client_for(peer) as client:
            result = action(VfdDriver(client, **driver_kwargs))
    finally:
        peer.close()
    assert peer.mismatch is None, f"expected {peer.mismatch[0].hex(' ')}, got {peer.mismatch[1].hex(' ')}"
    assert peer.served == len(script)
    assert bytes(peer.received) == b"".join(req for req, _ in script)
    return result


def test_set_frequency_frame() -> None:
    _run([(SET_10HZ, SET_10HZ)], lambda d: d.set_frequency_hz(10.0, verify=False))


def test_set_frequency_with_read_back() -> None:
    read_cmd = rtu("01 03 21 02 00 01")
    reply = rtu("01 03 02 03 E8")
    _run([(SET_10HZ, SET_10HZ), (read_cmd, reply)], lambda d: d.set_frequency_hz(10.0))


def test_set_frequency_rounds_to_centihertz() -> None:
    frame = rtu("01 06 20 01 0B B8")  # 30.00 Hz = 3000
    _run([(frame, frame)], lambda d: d.set_frequency_hz(29.999, verify=False))


def test_run_forward_stop_and_fault_reset_frames() -> None:
    _run([(RUN_FWD, RUN_FWD)], lambda d: d.run("forward"))
    _run([(STOP, STOP)], lambda d: d.stop())
    _run([(FAULT_RESET, FAULT_RESET)], lambda d: d.reset_fault())


def test_run_reverse_frame() -> None:
    frame = rtu("01 06 20 00 00 22")
    _run([(frame, frame)], lambda d: d.run("reverse"))


def test_ramp_time_frames() -> None:
    accel = rtu("01 06 01 09 00 32")  # 5.0 s in 0.1 s
    decel = rtu("01 06 01 0A 00 19")  # 2.5 s
    _run([(accel, accel), (decel, decel)], lambda d: d.set_ramp_times_s(5.0, 2.5))


def test_ramp_rate_converts_through_max_output_frequency() -> None:
    t = rtu("01 06 01 09 00 64")  # 50 Hz / 5 Hz/s = 10.0 s = 100
    u = rtu("01 06 01 0A 00 64")
    rate = _run([(t, t), (u, u)], lambda d: d.set_ramp_rate_hz_per_s(5.0), max_output_hz=50.0)
    assert rate == pytest.approx(5.0)


def test_read_status_frame_and_decoding() -> None:
    # fault 0, status running forward (0x0003), command 10.00 Hz, output 9.98 Hz, current 2.50 A
    reply = rtu("01 03 0A 0000 0003 03E8 03E6 00FA")
    status = _run([(READ_STATUS, reply)], lambda d: d.read_status())
    assert (status.fault_code, status.state, status.direction) == (0, "running", "forward")
    assert status.freq_cmd_hz == pytest.approx(10.0)
    assert status.freq_out_hz == pytest.approx(9.98)
    assert status.current_a == pytest.approx(2.5)


def test_status_decoding_of_intermediate_states() -> None:
    # fault 0x0105 (warning 1, fault 5), decelerating (01) while reversing (bits 4-3 = 01)
    reply = rtu("01 03 0A 0105 0009 0000 0064 0000")
    status = _run([(READ_STATUS, reply)], lambda d: d.read_status())
    assert (status.fault_code, status.warning_code) == (5, 1)
    assert (status.state, status.direction) == ("decelerating", "reversing")


def test_exception_response_raises_and_a_stop_is_sent() -> None:
    exc_reply = rtu("01 86 03")  # FC06 | 0x80, exception 03 illegal data value
    expected = r"exception 3 \(illegal data value\).*stop command sent"
    with pytest.raises(VfdExceptionResponseError, match=expected) as info:
        _run([(SET_10HZ, exc_reply), (STOP, STOP)], lambda d: d.set_frequency_hz(10.0, verify=False))
    assert info.value.exception_code == 3
    assert info.value.stop_attempted and info.value.stop_ok


def test_wrong_echo_is_not_taken_as_the_reply() -> None:
    wrong = rtu("01 06 20 01 03 E9")  # well-formed, but not the echo of this request: the link is out of step
    with pytest.raises(VfdCommunicationError, match="echoes 20 01 03 e9, sent 20 01 03 e8"):
        _run([(SET_10HZ, wrong), (STOP, STOP)], lambda d: d.set_frequency_hz(10.0, verify=False))


def test_read_back_mismatch_is_a_protocol_error() -> None:
    read_cmd = rtu("01 03 21 02 00 01")
    with pytest.raises(VfdProtocolError, match="drive reports command 999"):
        _run([(SET_10HZ, SET_10HZ), (read_cmd, rtu("01 03 02 03 E7")), (STOP, STOP)],
             lambda d: d.set_frequency_hz(10.0))


def test_setpoint_outside_drive_range_sends_nothing() -> None:
    with pytest.raises(ValueError, match="max_output_hz"):
        _run([], lambda d: d.set_frequency_hz(50.01, verify=False), max_output_hz=50.0)


def test_modbus_tcp_carries_the_same_pdu_behind_mbap() -> None:
    # MBAP after the transaction id: protocol 0, length 6, unit 1; then the FC06 PDU, no CRC
    request = bytes.fromhex("0000 0006 01 06 2001 03E8")
    peer = ScriptedPeer([(request, request)], transport="tcp")
    link = ModbusLink(f"tcp://127.0.0.1:{peer.port}", timeout_s=1.0, retries=0)
    try:
        VfdDriver(link).set_frequency_hz(10.0, verify=False)
    finally:
        link.close()
        peer.close()
    assert peer.mismatch is None and peer.served == 1


def test_single_register_reads() -> None:
    fault = _run([(rtu("01 03 21 00 00 01"), rtu("01 03 02 01 05"))], lambda d: d.read_fault_code())
    assert fault == 5  # the high byte (a warning) is masked off
    out = _run([(rtu("01 03 21 03 00 01"), rtu("01 03 02 0B B8"))], lambda d: d.read_actual_frequency_hz())
    assert out == pytest.approx(30.0)


def test_other_unit_ids_are_on_the_wire() -> None:
    frame = rtu("02 06 20 00 00 01")
    peer = ScriptedPeer([(frame, frame)])
    try:
        with rtu_client_for(peer) as client:
            VfdDriver(client, RegisterMap(unit_id=2)).stop()
    finally:
        peer.close()
    assert peer.mismatch is None and peer.served == 1


@settings(max_examples=25, deadline=None)
@given(st.floats(0.0, 60.0), st.integers(1, 247))
def test_any_setpoint_frame_matches_the_independent_encoder(f_hz: float, unit: int) -> None:
    value = round(f_hz * 100)
    frame = rtu(f"{unit:02X} 06 20 01 {value:04X}")
    peer = ScriptedPeer([(frame, frame)])
    try:
        with rtu_client_for(peer) as client:
            driver = VfdDriver(client, RegisterMap(unit_id=unit), max_output_hz=60.0)
            driver.set_frequency_hz(f_hz, verify=False)
    finally:
        peer.close()
    assert peer.mismatch is None and peer.served == 1
