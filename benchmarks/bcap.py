"""b-CAP driver throughput: codec and request/reply round trips over loopback TCP and a pty.

    .venv/bin/python benchmarks/bcap.py [--calls N]

Figures: packets/s encoded and decoded (a CurPos reply, 7 × R8), and CurPos calls/s through the whole
driver stack (BcapClient → transport → mock RC8 → twin → reply) over TCP and over a pty with CRC.
Baselines measured in the same run: ``struct.pack``/``struct.unpack`` of the same bytes (codec), and a
bare socket / pty echo of the same request and reply sizes with no b-CAP logic (round trips).
A real RC8 answers in milliseconds (network and controller), so the driver needs only ≫ 100 calls/s.
"""

from __future__ import annotations

import argparse
import os
import pty
import socket
import struct
import threading
import time
import tty

from drivers.denso.bcap import decode_packet, encode_packet
from drivers.denso.client import BcapClient
from drivers.denso.variant import VT_ARRAY, VT_R8, Variant
from drivers.mock.bcap_server import BcapMockServer
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World
from drivers.transport import open_transport

POSE = [300.0, 12.5, 350.0, 180.0, 0.0, 180.0, 5.0]


def rate(fn, n: int) -> float:
    start = time.perf_counter()
    for _ in range(n):
        fn()
    return n / (time.perf_counter() - start)


def codec(n: int) -> None:
    args = [Variant(VT_ARRAY | VT_R8, POSE)]
    data = encode_packet(9, 0, 0, args)
    enc = rate(lambda: encode_packet(9, 0, 0, args), n)
    dec = rate(lambda: decode_packet(data), n)
    fmt = "<BIHHiHIHI7dB"
    raw = (1, len(data), 9, 0, 0, 1, 62, 0x2005, 7, *POSE, 4)
    assert struct.pack(fmt, *raw) == data  # the baseline produces the very same bytes
    base_enc = rate(lambda: struct.pack(fmt, *raw), n)
    base_dec = rate(lambda: struct.unpack(fmt, data), n)
    print(f"encode CurPos reply: {enc:10.0f} packets/s   baseline struct.pack   {base_enc:10.0f}/s  "
          f"ratio {enc / base_enc:.3f}")
    print(f"decode CurPos reply: {dec:10.0f} packets/s   baseline struct.unpack {base_dec:10.0f}/s  "
          f"ratio {dec / base_dec:.3f}")


def _echo_baseline_tcp(n: int, request: bytes, reply: bytes) -> float:
    server = socket.create_server(("127.0.0.1", 0))

    def serve() -> None:
        conn, _ = server.accept()
        with conn:
            for _ in range(n):
                got = b""
                while len(got) < len(request):
                    got += conn.recv(4096)
                conn.sendall(reply)

    threading.Thread(target=serve, daemon=True).start()
    with socket.create_connection(server.getsockname()) as sock:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

        def call() -> None:
            sock.sendall(request)
            got = b""
            while len(got) < len(reply):
                got += sock.recv(4096)

        result = rate(call, n)
    server.close()
    return result


def _echo_baseline_pty(n: int, request: bytes, reply: bytes) -> float:
    master, slave = pty.openpty()
    tty.setraw(slave)

    def serve() -> None:
        for _ in range(n):
            got = b""
            while len(got) < len(request):
                got += os.read(master, 4096)
            os.write(master, reply)

    threading.Thread(target=serve, daemon=True).start()

    def call() -> None:
        os.write(slave, request)
        got = b""
        while len(got) < len(reply):
            got += os.read(slave, 4096)

    result = rate(call, n)
    os.close(master)
    os.close(slave)
    return result


def round_trips(n: int) -> None:
    world = World(VirtualClock())
    with BcapMockServer(world.robot, world.clock) as server:
        for kind in ("tcp", "pty"):
            serial_line = kind == "pty"
            url = (f"tcp://127.0.0.1:{server.serve_tcp()}" if kind == "tcp"
                   else f"serial://{server.serve_pty()}?baud=115200")
            link = open_transport(url, 2.0)
            with link, BcapClient(link, serial_line=serial_line, timeout_s=2.0) as c:
                c.open_robot()
                calls = rate(c.cur_pos, n)
                request = encode_packet(1, 0, 64, [c.h_robot, "CurPos", None], serial_line=serial_line)
                reply = encode_packet(1, 0, 0, [Variant(VT_ARRAY | VT_R8, POSE)], serial_line=serial_line)
            baseline = (_echo_baseline_pty if serial_line else _echo_baseline_tcp)(n, request, reply)
            print(f"CurPos over {kind}: {calls:8.0f} calls/s   baseline bare echo {baseline:8.0f}/s  "
                  f"ratio {calls / baseline:.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=2000)
    options = parser.parse_args()
    codec(options.calls * 10)
    round_trips(options.calls)


if __name__ == "__main__":
    main()
