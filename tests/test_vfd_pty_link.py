"""The software null-modem cable used by the serial mocks (drivers/mock/pty_link.py)."""

from __future__ import annotations

import serial

from drivers.mock.pty_link import PtyLink


def _open(port: str) -> serial.Serial:
    return serial.serial_for_url(port, timeout=0.5, write_timeout=0.5)


def test_bytes_cross_both_ways_unchanged() -> None:
    with PtyLink() as link:
        dev, cli = _open(link.device_port), _open(link.client_port)
        try:
            payload = bytes(range(256))  # every byte value, including \n, \r, XON/XOFF
            cli.write(payload)
            assert dev.read(256) == payload
            dev.write(b"\x01\x06\x20\x01\x03\xe8\xd3\x74")
            assert cli.read(8) == b"\x01\x06\x20\x01\x03\xe8\xd3\x74"
        finally:
            dev.close()
            cli.close()


def test_peer_can_reopen_its_port() -> None:
    with PtyLink() as link:
        dev = _open(link.device_port)
        cli = _open(link.client_port)
        cli.close()
        cli = _open(link.client_port)
        try:
            dev.write(b"again\n")
            assert cli.readline() == b"again\n"
        finally:
            dev.close()
            cli.close()


def test_unplugged_cable_loses_bytes_and_filter_applies() -> None:
    with PtyLink() as link:
        dev, cli = _open(link.device_port), _open(link.client_port)
        try:
            link.unplug()
            dev.write(b"lost\n")
            assert cli.readline() == b""
            link.plug()
            link.filter_to_client = lambda data: data.upper()
            dev.write(b"ok\n")
            assert cli.readline() == b"OK\n"
        finally:
            dev.close()
            cli.close()
