"""Fuzzing the mock RC8 (b-CAP over TCP) as a separate process: crashes, hangs, bad replies, memory growth.

    .venv/bin/python benchmarks/fuzz_bcap.py --packets 100000 [--seed 0]

:func:`fuzz` starts ``python -m drivers.mock.bcap_server --port 0`` (its own world, clock at 1000× so
random Moves end quickly) and sends ``n_packets`` packets over many short connections, each a random mix of

* valid requests (every function the mock implements, plausible and hostile arguments: handles typed
  I4/UI4, command and variable names, NaN/±inf/huge numbers, arrays, nested VARIANTs), sent one at a time
  and their reply awaited (up to 2 s) — about half of them inside a real session (Service_Start, Connect,
  GetRobot, TakeArm, Motor on) so deep states are reached;
* mutated valid packets (bytes flipped, inserted, deleted; length field, argc, vt or counts rewritten;
  truncated) and random bytes, sent without waiting;
* slow packets (a valid request dribbled a few bytes at a time) and partial ones (the connection closed,
  or reset, halfway through a packet).

Every byte the server sends back is decoded by the **driver's** codec (independent of the mock's own):
any byte that is not part of a well-formed b-CAP reply, or a reply to a valid request that does not
echo its serial, counts as a bad reply. After every 2,000 packets, and at the end, a fresh connection
sends Service_Start: no valid reply within 2 s is a hang (E_MAX_CONNECT is a valid reply). A crash is the
server process gone (it is restarted). RSS growth is the server's ``VmRSS`` (``/proc/PID/status``) at the
end minus after a 2,000-packet warm-up.

Figures (keys of the returned dict): packets, crashes, hangs, bad_replies, rss_growth_mb, seconds.
Target: 0 crashes, 0 hangs, RSS growth < 5 MB per 10⁵ packets. No baseline ratio: the figures are
counts against the target, not speeds.
"""

from __future__ import annotations

import argparse
import math
import os
import random
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.denso.bcap import PacketDecoder, encode_packet  # noqa: E402
from drivers.denso.hresult import BcapProtocolError  # noqa: E402
from drivers.denso.variant import (  # noqa: E402
    VT_ARRAY,
    VT_BSTR,
    VT_I4,
    VT_R4,
    VT_R8,
    VT_UI4,
    VT_VARIANT,
    Variant,
)

REPLY_WAIT_S = 2.0
PROBE_EVERY = 2000
WARMUP = 2000
FUNCTIONS = [0, 1, 2, 3, 4, 5, 7, 8, 9, 13, 17, 62, 64, 70, 71, 72, 74, 76, 84, 88, 89, 99, 101, 102, 111,
             137]
WORDS = ["", "Arm", "Arm0", "CaoProv.DENSO.VRC", "localhost", "CurPos", "CurJnt", "HighCurJntEx", "TakeArm",
         "GiveArm", "Motor", "ExtSpeed", "ClearError", "GetCurErrorCount", "GetCurErrorInfo",
         "GetErrorDescription", "@CURRENT_POSITION", "@CURRENT_ANGLE", "@BUSY_STATUS", "@SERVO_ON",
         "@EXTSPEED", "@ERROR_CODE", "@MODE", "RobSlave", ",WDT=100", ",WDT=10", ",InvokeTimeout=100",
         "@P P(300,0,350,180,0,180,5)", "@P P(320,40,300,180,0,180)", "@P P(9e9,0,0,0,0,0)", "NEXT",
         "SPEED=50,NEXT", "SPEED=-1", "ACCEL=0", "\ud800", "x" * 300]
NUMBERS = [0, 1, -1, 2, 100, 2**31 - 1, -2**31, 0.5, 100.0, 1e308, -1e308, math.nan, math.inf, -math.inf]


# ---------------------------------------------------------------------------------------- packets
def _value(rng: random.Random, handles: list[int], depth: int = 0) -> Any:
    kind = rng.randrange(9)
    if kind == 0:
        return Variant(rng.choice((VT_I4, VT_UI4)), rng.choice(handles or [1]) if rng.random() < 0.8
                       else rng.randrange(0, 2**31))
    if kind == 1:
        return rng.choice(WORDS)
    if kind == 2:
        number = rng.choice(NUMBERS)
        if isinstance(number, float):
            return Variant(VT_R4 if rng.random() < 0.3 and not abs(number) > 3e38 else VT_R8, number)
        return Variant(VT_I4, number)
    if kind == 3:
        return Variant(VT_ARRAY | VT_I4, [rng.choice((0, 1, -1, 2)) for _ in range(rng.randrange(0, 4))])
    if kind == 4:
        return Variant(VT_ARRAY | VT_R8, [rng.choice(NUMBERS[7:]) + 0.0 for _ in range(rng.randrange(0, 8))])
    if kind == 5 and depth < 3:
        items = [_value(rng, handles, depth + 1) for _ in range(rng.randrange(4))]
        return Variant(VT_ARRAY | VT_VARIANT, items)
    if kind == 6:
        return Variant(VT_ARRAY | VT_BSTR, [rng.choice(WORDS) for _ in range(rng.randrange(3))])
    if kind == 7:
        return None
    return bytes(rng.randrange(256) for _ in range(rng.randrange(8)))


def _request(rng: random.Random, serial: int, handles: list[int]) -> bytes:
    function = rng.choice(FUNCTIONS)
    args = [_value(rng, handles) for _ in range(rng.choice((0, 1, 2, 3, 3, 4, 4, 5)))]
    return encode_packet(serial, 0, function, args)


def _mutate(rng: random.Random, data: bytes) -> bytes:
    raw = bytearray(data)
    for _ in range(rng.randrange(1, 4)):
        kind, at = rng.randrange(7), rng.randrange(len(raw)) if raw else 0
        if kind == 0 and raw:
            raw[at] ^= 1 << rng.randrange(8)
        elif kind == 1:
            raw[at:at] = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 6)))
        elif kind == 2 and raw:
            del raw[at:at + rng.randrange(1, 6)]
        elif kind == 3 and len(raw) >= 5:
            length = rng.choice((0, 15, 16, len(raw) + 1, len(raw) * 2, 2**24, 2**32 - 1))
            raw[1:5] = struct.pack("<I", length)
        elif kind == 4 and len(raw) >= 15:
            raw[13:15] = struct.pack("<H", rng.randrange(65536))
        elif kind == 5 and len(raw) >= 21:
            raw[19:21] = struct.pack("<H", rng.choice((0x2000, 0x200C, 0x0D, 0xFFFF, 0x2008, 9)))
        else:
            del raw[rng.randrange(len(raw) + 1):]
    return bytes(raw)


# --------------------------------------------------------------------------------------- server
class Server:
    """The mock as a child process; ``port`` from the first line it prints."""

    def __init__(self) -> None:
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "drivers.mock.bcap_server", "--port", "0", "--rate", "1000"],
            cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        line = self.proc.stdout.readline() if self.proc.stdout else ""
        if "tcp://" not in line:
            raise RuntimeError(f"the mock did not start: {line!r}")
        self.port = int(line.strip().rsplit(":", 1)[1])

    def alive(self) -> bool:
        return self.proc.poll() is None

    def rss_mb(self) -> float:
        for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
        return math.nan

    def stop(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.proc.kill()


class Connection:
    """One fuzz connection: sends, and decodes every byte that comes back with the driver's codec."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=REPLY_WAIT_S)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.decoder = PacketDecoder()
        self.bad = 0
        self.closed = False

    def send(self, data: bytes, *, slow: bool = False) -> None:
        try:
            if slow:
                for i in range(0, len(data), 3):
                    self.sock.sendall(data[i:i + 3])
                    time.sleep(0.001)
            else:
                self.sock.sendall(data)
        except OSError:
            self.closed = True

    def _take(self, wait_s: float) -> None:
        self.sock.settimeout(wait_s)
        try:
            chunk = self.sock.recv(65536)
        except (TimeoutError, BlockingIOError):
            return
        except OSError:
            self.closed = True
            return
        if not chunk:
            self.closed = True
        self.decoder.feed(chunk)

    def packets(self) -> list[Any]:
        found = []
        while True:
            skipped = self.decoder.skipped_bytes
            try:
                packet = self.decoder.next_packet()
            except BcapProtocolError:
                self.bad += 1
                continue
            if self.decoder.skipped_bytes != skipped:
                self.bad += 1
            if packet is None:
                return found
            found.append(packet)

    def ask(self, data: bytes, serial: int, *, slow: bool = False) -> Any:
        """Send a valid request and wait for its final reply; None when none came within 2 s."""
        self.send(data, slow=slow)
        deadline = time.monotonic() + REPLY_WAIT_S
        while not self.closed and time.monotonic() < deadline:
            self._take(max(0.001, deadline - time.monotonic()))
            for packet in self.packets():
                if packet.serial == serial and not packet.is_keepalive:
                    return packet
                if packet.serial != serial:
                    self.bad += 1  # a reply to nothing this client asked
        return None

    def close(self, *, reset: bool = False) -> int:
        self._take(0.0)
        self.packets()
        if reset:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        self.sock.close()
        return self.bad


def _probe(port: int) -> bool:
    """A fresh connection's Service_Start gets a valid reply within 2 s (E_MAX_CONNECT counts)."""
    try:
        conn = Connection(port)
    except OSError:
        return False
    reply = conn.ask(encode_packet(1, 0, 1, [""]), 1)
    conn.close(reset=True)
    return reply is not None


# ----------------------------------------------------------------------------------------- fuzz
def _session(conn: Connection, rng: random.Random) -> tuple[list[int], int]:
    """Service_Start … Motor on; returns the handles the mock gave and the next serial."""
    handles: list[int] = []
    steps = [(1, [""]), (3, ["", "CaoProv.DENSO.VRC", "localhost", ""]), (7, None), (64, "TakeArm"),
             (64, "Motor")]
    serial = 1
    for function, fixed in steps:
        args = fixed
        if function == 7:
            args = [Variant(VT_UI4, handles[0] if handles else 1), "Arm", ""]
        elif function == 64:
            param = [1, 0] if fixed == "Motor" else [0, 1]
            args = [Variant(VT_I4, handles[-1] if handles else 2), fixed, param]
        reply = conn.ask(encode_packet(serial, 0, function, args), serial)
        serial += 1
        if reply is not None and reply.args and isinstance(reply.args[0].value, int):
            handles.append(reply.args[0].value)
    return handles, serial


def _one_connection(server: Server, rng: random.Random, budget: int) -> tuple[int, int, int]:
    """One connection: valid requests (each answered before the next), then perhaps one mutated, random or
    partial packet (after which the stream may be out of frame, so the connection ends); returns
    (packets sent, bad replies, valid requests left unanswered on a connection still open)."""
    conn = Connection(server.port)
    handles, serial = _session(conn, rng) if rng.random() < 0.3 else ([], 1)
    sent, unanswered = len(handles), 0
    for _ in range(min(budget, rng.randrange(0, 12))):
        if conn.closed:
            break
        if conn.ask(_request(rng, serial, handles), serial, slow=rng.random() < 0.002) is None \
                and not conn.closed:
            unanswered += 1
        serial = serial % 0xFFFF + 1
        sent += 1
    kind = rng.random()
    if not conn.closed and kind < 0.9:
        data = _request(rng, serial, handles)
        if kind < 0.7:
            data = _mutate(rng, data)
        elif kind < 0.8:
            data = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 64)))
        else:
            data = data[:rng.randrange(1, len(data))]  # a partial packet
        conn.send(data)
        sent += 1
    return sent, conn.close(reset=rng.random() < 0.5), unanswered


def fuzz(n_packets: int, seed: int) -> dict[str, float]:
    """Send ``n_packets`` random and mutated packets to a mock RC8 process; return the figures."""
    rng = random.Random(seed)
    server = Server()
    started = time.perf_counter()
    packets = crashes = hangs = bad = 0
    rss_start: float | None = None
    next_probe = PROBE_EVERY
    try:
        while packets < n_packets:
            try:
                sent, bad_here, unanswered = _one_connection(server, rng, n_packets - packets)
            except OSError:
                sent, bad_here, unanswered = 1, 0, 0
            packets += sent
            bad += bad_here
            if unanswered or packets >= next_probe or not server.alive():
                if not server.alive():
                    crashes += 1
                    server = Server()
                elif not _probe(server.port):
                    hangs += 1
                next_probe = packets + PROBE_EVERY
            if rss_start is None and packets >= min(WARMUP, n_packets // 10):
                rss_start = server.rss_mb()
        if not _probe(server.port):
            hangs += 1
        rss_end = server.rss_mb()
        crashes += 0 if server.alive() else 1
    finally:
        server.stop()
    return {"packets": float(packets), "crashes": float(crashes), "hangs": float(hangs),
            "bad_replies": float(bad), "rss_growth_mb": rss_end - (rss_start or rss_end),
            "seconds": time.perf_counter() - started}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--packets", type=int, default=10_000, help="packets to send (default 10,000)")
    parser.add_argument("--seed", type=int, default=0)
    options = parser.parse_args(argv)
    figures = fuzz(options.packets, options.seed)
    for key, value in figures.items():
        print(f"{key:>14}: {value:g}")
    per_1e5 = figures["rss_growth_mb"] * 1e5 / max(figures["packets"], 1.0)
    target = figures["crashes"] == 0 and figures["hangs"] == 0 and per_1e5 < 5.0
    print(f"{'rss per 1e5':>14}: {per_1e5:.2f} MB  (target: 0 crashes, 0 hangs, < 5 MB per 1e5 packets: "
          f"{'met' if target else 'NOT met'})")
    return 0 if target else 1


if __name__ == "__main__":
    raise SystemExit(main())
