"""Transports over real loopback sockets, pyserial's loop:// and a pty pair."""

from __future__ import annotations

import os
import pty
import socket
import threading
import time
import tty

import pytest
import serial

from drivers.transport import (
    SerialTransport,
    TcpTransport,
    Transport,
    TransportClosed,
    TransportError,
    TransportTimeout,
    open_transport,
)


@pytest.fixture
def tcp_peer():
    """A listening socket on 127.0.0.1; yields (port, accept) where accept() returns the server side."""
    listener = socket.create_server(("127.0.0.1", 0))
    accepted: list[socket.socket] = []

    def accept() -> socket.socket:
        listener.settimeout(2.0)
        conn, _ = listener.accept()
        accepted.append(conn)
        return conn

    yield listener.getsockname()[1], accept
    for conn in accepted:
        conn.close()
    listener.close()


def test_tcp_exact_reads_reassemble_fragments(tcp_peer) -> None:
    port, accept = tcp_peer
    with TcpTransport("127.0.0.1", port, timeout_s=2.0) as link:
        assert isinstance(link, Transport)
        peer = accept()
        link.write(b"ping")
        assert peer.recv(4) == b"ping"

        def dribble() -> None:
            for byte in b"abcdef":
                peer.sendall(bytes([byte]))
                time.sleep(0.01)

        threading.Thread(target=dribble).start()
        assert link.read_exact(4) == b"abcd"
        assert link.read_exact(2, timeout_s=1.0) == b"ef"


def test_tcp_timeout_keeps_partial_bytes(tcp_peer) -> None:
    port, accept = tcp_peer
    with TcpTransport("127.0.0.1", port, timeout_s=1.0) as link:
        peer = accept()
        peer.sendall(b"xyz")
        with pytest.raises(TransportTimeout, match="3 of 5 bytes"):
            link.read_exact(5, timeout_s=0.1)
        peer.sendall(b"12")
        assert link.read_exact(5) == b"xyz12"


def test_tcp_peer_close_raises_closed(tcp_peer) -> None:
    port, accept = tcp_peer
    link = TcpTransport("127.0.0.1", port, timeout_s=1.0)
    peer = accept()
    peer.close()
    with pytest.raises(TransportClosed):
        link.read_exact(1)
    link.close()
    with pytest.raises(TransportClosed, match="closed"):
        link.write(b"x")


def test_tcp_connect_refused_is_transport_error() -> None:
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    sock.close()  # nothing listens there now
    with pytest.raises(TransportError, match="cannot connect"):
        TcpTransport("127.0.0.1", port, timeout_s=0.5)


def test_read_until_and_max_bytes(tcp_peer) -> None:
    port, accept = tcp_peer
    with TcpTransport("127.0.0.1", port, timeout_s=1.0) as link:
        peer = accept()
        peer.sendall(b"*IDN?\nrest")
        assert link.read_until(b"\n") == b"*IDN?\n"
        with pytest.raises(TransportTimeout, match="terminator"):
            link.read_until(b"\n", timeout_s=0.1)
        with pytest.raises(TransportError, match="4 bytes without terminator"):
            link.read_until(b"\n", timeout_s=0.5, max_bytes=4)
        time.sleep(0.05)
        assert link.read_available() == b"rest"
        assert link.read_available() == b""


def test_loop_url_through_open_transport() -> None:
    with open_transport("loop://", timeout_s=0.5) as link:
        assert isinstance(link, SerialTransport)
        link.write(b"\x01\x02\x03hello\r\n")
        assert link.read_exact(3) == b"\x01\x02\x03"
        assert link.read_until(b"\r\n") == b"hello\r\n"
        with pytest.raises(TransportTimeout):
            link.read_exact(1, timeout_s=0.05)


def test_pty_slave_by_device_name() -> None:
    master_fd, slave_fd = pty.openpty()
    tty.setraw(slave_fd)
    name = os.ttyname(slave_fd)
    try:
        url = f"serial://{name}?baud=115200&parity=N&stopbits=1&bytesize=8"
        with open_transport(url, timeout_s=1.0) as link:
            assert link.baudrate == 115200
            link.write(b"\x01abc\x04")
            got = b""
            while len(got) < 5:
                got += os.read(master_fd, 5 - len(got))
            assert got == b"\x01abc\x04"
            os.write(master_fd, b"\x00\xff\x04")
            assert link.read_exact(3) == b"\x00\xff\x04"
    finally:
        os.close(slave_fd)
        os.close(master_fd)


def test_socket_url_is_pyserial_socket(tcp_peer) -> None:
    port, accept = tcp_peer
    with open_transport(f"socket://127.0.0.1:{port}", timeout_s=1.0) as link:
        peer = accept()
        peer.sendall(b"abc")
        assert link.read_exact(3) == b"abc"


@pytest.mark.parametrize("url, message", [
    ("http://example.org", "unsupported address"),
    ("tcp://127.0.0.1", "tcp://HOST:PORT"),
    ("serial:///dev/null?baud=fast", "baud='fast'"),
    ("serial:///dev/null?flow=rtscts", "unknown option 'flow'"),
    ("serial:///dev/null?parity=X", "parity='X'"),
])
def test_bad_addresses_name_the_field(url: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        open_transport(url)


def test_missing_serial_device_is_transport_error() -> None:
    with pytest.raises(TransportError, match="cannot open serial line"):
        open_transport("serial:///dev/does-not-exist-rig?baud=9600")


def test_timeout_must_be_positive() -> None:
    with pytest.raises(ValueError, match="timeout_s"):
        open_transport("loop://", timeout_s=0)
    assert issubclass(serial.SerialException, OSError)  # pyserial errors are wrapped, not leaked


def test_udp_datagrams_read_as_a_stream() -> None:
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind(("127.0.0.1", 0))
    peer.settimeout(1.0)
    try:
        with open_transport(f"udp://127.0.0.1:{peer.getsockname()[1]}", timeout_s=0.5) as link:
            link.write(b"\x01request\x04")
            data, address = peer.recvfrom(100)
            assert data == b"\x01request\x04"
            peer.sendto(b"ab", address)
            peer.sendto(b"cd", address)
            assert link.read_exact(3) == b"abc"
            assert link.read_exact(1) == b"d"
            with pytest.raises(TransportTimeout):
                link.read_exact(1, timeout_s=0.05)
    finally:
        peer.close()
