"""Fuzzing the mock VFD's Modbus servers (TCP, and RTU over a pty) with random and mutated packets.

    .venv/bin/python benchmarks/fuzz_modbus.py [--packets N] [--seed S]

Starts ``python -m drivers.mock.vfd_server`` twice as subprocesses (``--port 0`` and ``--rtu``) and sends
half of the packets to each: valid requests (FC03/06/16), mutated ones (bit flips, truncation, extra
bytes, inserted/deleted bytes, other unit or function code), random bytes, partial requests, and slow
ones (byte by byte; on RTU with gaps longer than t3.5, so each byte is a frame fragment the slave drops).
Each RTU packet is followed by a silence (:data:`RTU_GAP_S`, > t3.5 = 1.75 ms).

Counted:

* crashes — the server process died (it is restarted);
* hangs — every :data:`CHECK_EVERY` packets and at the end, after a silence, a fresh valid request
  (TCP: on a new connection) not answered within :data:`HANG_LIMIT_S` = 2 s;
* bad replies — bytes from the server that are not a well-formed reply (CRC, length, unit, function
  code, exception code, or on TCP an MBAP transaction id never sent), and no reply to a valid request
  on an aligned TCP stream;
* RSS growth of both server processes (``VmRSS`` in /proc/PID/status, after a warm-up to the end).

:func:`fuzz` is what ``benchmarks/fuzz.py`` runs.
"""

from __future__ import annotations

import argparse
import os
import random
import re
import select
import signal
import socket
import struct
import subprocess
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from drivers.modbus import mbap_adu, rtu_adu, split_rtu  # noqa: E402

RTU_GAP_S = 0.004
CHECK_EVERY = 500
HANG_LIMIT_S = 2.0
UNIT = 1
MAPPED = [0x2000, 0x2001, 0x2002, 0x2100, 0x2101, 0x2102, 0x2103, 0x2104, 0x0109, 0x010A]
EXCEPTION_CODES = {1, 2, 3, 4, 6, 11}


@dataclass
class Tally:
    packets: int = 0
    crashes: int = 0
    hangs: int = 0
    bad_replies: int = 0
    unanswered: int = 0  # RTU: a valid request unanswered (a silence lost to scheduling is possible)
    replies: int = 0
    rss_start_mb: float = 0.0
    rss_end_mb: float = 0.0


class MockProcess:
    """``python -m drivers.mock.vfd_server ARGS`` as a subprocess; :attr:`url` is the address it prints."""

    def __init__(self, *args: str) -> None:
        self.args = args
        self.start()

    def start(self) -> None:
        env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
        self.proc = subprocess.Popen([sys.executable, "-m", "drivers.mock.vfd_server", *self.args], cwd=ROOT,
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        match = re.search(r"at (tcp://127\.0\.0\.1:\d+|/dev/\S+)", line)
        if match is None:
            raise RuntimeError(f"mock VFD did not start: {line!r}")
        self.url = match.group(1)

    def alive(self) -> bool:
        return self.proc.poll() is None

    def rss_mb(self) -> float:
        text = Path(f"/proc/{self.proc.pid}/status").read_text()
        return int(re.search(r"VmRSS:\s+(\d+) kB", text).group(1)) / 1024.0  # type: ignore[union-attr]

    def stop(self) -> None:
        if self.alive():
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


# packets -----------------------------------------------------------------------------------------------
class PacketSource:
    """Random packets: (bytes, kind) with kind valid | mutated | random | partial | slow."""

    def __init__(self, rng: random.Random) -> None:
        self.rng = rng

    def valid_pdu(self) -> bytes:
        rng = self.rng
        address = rng.choice(MAPPED) if rng.random() < 0.8 else rng.randrange(0x10000)
        kind = rng.random()
        if kind < 0.5:
            count = rng.randint(1, 5) if rng.random() < 0.9 else rng.randint(0, 130)
            return struct.pack(">BHH", 3, address, count)
        if kind < 0.85:
            return struct.pack(">BHH", 6, address, rng.randrange(0x10000) if rng.random() < 0.5 else 1)
        values = [rng.randrange(0x10000) for _ in range(rng.randint(1, 4))]
        return struct.pack(f">BHHB{len(values)}H", 16, address, len(values), 2 * len(values), *values)

    def mutate(self, data: bytes) -> bytes:
        rng, out = self.rng, bytearray(data)
        for _ in range(rng.randint(1, 3)):
            op = rng.randrange(6)
            if op == 0 and out:
                i = rng.randrange(len(out))
                out[i] ^= 1 << rng.randrange(8)
            elif op == 1 and out:
                del out[rng.randrange(len(out)):]
            elif op == 2:
                out += bytes(rng.randrange(256) for _ in range(rng.randint(1, 20)))
            elif op == 3:
                out.insert(rng.randrange(len(out) + 1), rng.randrange(256))
            elif op == 4 and out:
                del out[rng.randrange(len(out))]
            elif op == 5 and len(out) > 1:
                out[rng.randrange(2)] = rng.randrange(256)
        return bytes(out)

    def packet(self, frame: Callable[[bytes], bytes]) -> tuple[bytes, str]:
        """``frame(pdu) -> bytes`` wraps a PDU for the link."""
        r = self.rng.random()
        valid = frame(self.valid_pdu())
        if r < 0.3:
            return valid, "valid"
        if r < 0.65:
            return self.mutate(valid), "mutated"
        if r < 0.85:
            return bytes(self.rng.randrange(256) for _ in range(self.rng.randint(0, 300))), "random"
        if r < 0.95:
            return valid[:self.rng.randint(1, max(1, len(valid) - 1))], "partial"
        return valid, "slow"


# reply checking ----------------------------------------------------------------------------------------
def _pdu_ok(pdu: bytes) -> bool:
    if not pdu:
        return False
    fc = pdu[0]
    if fc & 0x80:
        return len(pdu) == 2 and pdu[1] in EXCEPTION_CODES
    if fc == 3:
        return len(pdu) >= 2 and len(pdu) == 2 + pdu[1] and pdu[1] % 2 == 0
    return fc in (6, 16) and len(pdu) == 5


class RtuReplies:
    """Splits the RTU reply stream into frames and counts the malformed ones."""

    def __init__(self) -> None:
        self.buffer = bytearray()
        self.frames = 0
        self.bad = 0

    def feed(self, data: bytes) -> None:
        self.buffer += data
        while len(self.buffer) >= 3:
            fc = self.buffer[1]
            length = 5 if fc & 0x80 else 5 + self.buffer[2] if fc == 3 else 8 if fc in (6, 16) else None
            if self.buffer[0] != UNIT or length is None:
                self.bad += 1
                self.buffer.clear()
                return
            if len(self.buffer) < length:
                return
            frame = bytes(self.buffer[:length])
            del self.buffer[:length]
            parts = split_rtu(frame)
            if parts is None or not _pdu_ok(parts[1]):
                self.bad += 1
                self.buffer.clear()
                return
            self.frames += 1

    def flush(self) -> None:
        """At a silence: a partial frame left over is a truncated reply."""
        if self.buffer:
            self.bad += 1
            self.buffer.clear()


@dataclass
class TcpReplies:
    """Splits an MBAP reply stream into frames; checks them and their transaction ids."""

    buffer: bytearray = field(default_factory=bytearray)
    sent_tids: deque[int] = field(default_factory=lambda: deque(maxlen=2000))
    frames: int = 0
    bad: int = 0

    def feed(self, data: bytes) -> None:
        self.buffer += data
        while len(self.buffer) >= 7:
            tid, protocol, length, _unit = struct.unpack(">HHHB", self.buffer[:7])
            if protocol != 0 or not 2 <= length <= 254:
                self.bad += 1
                self.buffer.clear()
                return
            if len(self.buffer) < 6 + length:
                return
            pdu = bytes(self.buffer[7:6 + length])
            del self.buffer[:6 + length]
            if tid not in self.sent_tids or not _pdu_ok(pdu):
                self.bad += 1
            self.frames += 1


def _mbap_tids(data: bytes) -> tuple[list[int], bool]:
    """Transaction ids of the complete Modbus frames at the start of ``data``, and whether ``data`` is a
    whole number of MBAP frames (else the server's view of the stream is no longer aligned with ours)."""
    tids, i = [], 0
    while i < len(data):
        if len(data) - i < 7:
            return tids, False
        tid, protocol, length, _ = struct.unpack(">HHHB", data[i:i + 7])
        if not 2 <= length <= 254 or i + 6 + length > len(data):
            return tids, False
        if protocol == 0:
            tids.append(tid)
        i += 6 + length
    return tids, True


def _wait_frames(read: Callable[[float], None], replies: RtuReplies | TcpReplies, before: int,
                 limit_s: float) -> bool:
    end = time.monotonic() + limit_s
    while replies.frames <= before and time.monotonic() < end:
        read(min(0.05, max(end - time.monotonic(), 0.0)))
    return replies.frames > before


class TcpFuzzer:
    """One client connection to the TCP mock, reconnected whenever the stream is no longer aligned."""

    def __init__(self, server: MockProcess, tally: Tally) -> None:
        self.server, self.tally = server, tally
        self.sock: socket.socket | None = None
        self.replies = TcpReplies()

    def _connect(self) -> socket.socket:
        host, port = self.server.url.removeprefix("tcp://").split(":")
        sock = socket.create_connection((host, int(port)), timeout=5.0)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))  # no TIME_WAIT pile-up
        return sock

    def _close(self) -> None:
        self.read(0.0)  # replies already there (this may find the connection closed by the server)
        if self.sock is not None:
            self.sock.close()
            self.sock = None
        self.replies.buffer.clear()

    def read(self, wait_s: float) -> None:
        if self.sock is None:
            return
        while select.select([self.sock], [], [], wait_s)[0]:
            try:
                data = self.sock.recv(65536)
            except OSError:
                data = b""
            if not data:
                self.sock.close()
                self.sock = None
                return
            self.replies.feed(data)
            wait_s = 0.0

    def send(self, data: bytes, kind: str) -> None:
        if self.sock is None:
            self.sock = self._connect()
        tids, aligned = _mbap_tids(data)
        self.replies.sent_tids.extend(tids)
        before = self.replies.frames
        try:
            for chunk in ([data[i:i + 1] for i in range(len(data))] if kind == "slow" else [data]):
                self.sock.sendall(chunk)
                if kind == "slow":
                    time.sleep(0.0005)
        except OSError:
            self._close()
            return
        if kind in ("valid", "slow") and not _wait_frames(self.read, self.replies, before, HANG_LIMIT_S):
            self.tally.bad_replies += 1  # a valid request on an aligned stream got no reply
        self.read(0.0)
        if not aligned:
            self._close()

    def check(self, rng: random.Random) -> bool:
        """A fresh valid request on a new connection answered within HANG_LIMIT_S."""
        self.tally.bad_replies += self.replies.bad
        self.replies.bad = 0
        replies = TcpReplies()
        tid = rng.randrange(0x10000)
        replies.sent_tids.append(tid)
        try:
            with self._connect() as sock:
                sock.sendall(mbap_adu(tid, UNIT, struct.pack(">BHH", 3, 0x2100, 1)))
                def read(wait_s: float) -> None:
                    if select.select([sock], [], [], wait_s)[0]:
                        replies.feed(sock.recv(65536) or b"")
                ok = _wait_frames(read, replies, 0, HANG_LIMIT_S)
        except OSError:
            ok = False
        self.tally.bad_replies += replies.bad
        return ok

    def restart(self) -> None:
        self._close()


class RtuFuzzer:
    """The client end of the RTU mock's pty."""

    def __init__(self, server: MockProcess, tally: Tally) -> None:
        import serial

        self.server, self.tally = server, tally
        self.port = serial.serial_for_url(server.url, baudrate=115200, timeout=0, write_timeout=5.0)
        self.replies = RtuReplies()

    def read(self, wait_s: float) -> None:
        if select.select([self.port.fileno()], [], [], wait_s)[0]:
            self.replies.feed(self.port.read(self.port.in_waiting or 1))

    def send(self, data: bytes, kind: str) -> None:
        before = self.replies.frames
        for chunk in ([data[i:i + 1] for i in range(len(data))] if kind == "slow" else [data]):
            self.port.write(chunk)
            time.sleep(RTU_GAP_S)  # the silence that ends the frame (or fragment)
        self.read(0.0)
        if kind == "valid" and not _wait_frames(self.read, self.replies, before, HANG_LIMIT_S):
            self.tally.unanswered += 1

    def check(self, rng: random.Random) -> bool:
        time.sleep(3 * RTU_GAP_S)
        self.read(0.0)
        self.replies.flush()
        self.tally.bad_replies += self.replies.bad
        self.replies.bad = 0
        before = self.replies.frames
        self.port.write(rtu_adu(UNIT, struct.pack(">BHH", 3, 0x2100, 1)))
        ok = _wait_frames(self.read, self.replies, before, HANG_LIMIT_S)
        self.tally.bad_replies += self.replies.bad
        self.replies.bad = 0
        return ok

    def restart(self) -> None:
        self.port.close()
        self.__init__(self.server, self.tally)  # type: ignore[misc]


def fuzz_server(mode: str, n_packets: int, rng: random.Random) -> Tally:
    """Fuzz one server (``mode`` "tcp" or "rtu") with ``n_packets`` packets."""
    tally = Tally()
    server = MockProcess("--port", "0") if mode == "tcp" else MockProcess("--rtu")
    fuzzer: TcpFuzzer | RtuFuzzer = TcpFuzzer(server, tally) if mode == "tcp" else RtuFuzzer(server, tally)
    source = PacketSource(rng)
    tid = 0

    def frame(pdu: bytes) -> bytes:
        nonlocal tid
        tid = (tid + 1) & 0xFFFF
        return mbap_adu(tid, UNIT, pdu) if mode == "tcp" else rtu_adu(UNIT, pdu)

    def check() -> None:
        if not server.alive():
            tally.crashes += 1
            server.start()
            fuzzer.restart()
            return
        if not fuzzer.check(rng):
            tally.hangs += 1

    try:
        for i in range(n_packets):
            data, kind = source.packet(frame)
            fuzzer.send(data, kind)
            tally.packets += 1
            if (i + 1) % CHECK_EVERY == 0:
                check()
                if i + 1 == CHECK_EVERY:
                    tally.rss_start_mb = server.rss_mb()  # after a warm-up
        check()
        tally.rss_end_mb = server.rss_mb() if server.alive() else tally.rss_start_mb
        if not tally.rss_start_mb:
            tally.rss_start_mb = tally.rss_end_mb
    finally:
        server.stop()
    return tally


def fuzz(n_packets: int, seed: int) -> dict[str, float]:
    """Half the packets to the TCP mock, half to the RTU mock; the summed counts and RSS growth (MB)."""
    t0 = time.perf_counter()
    rng = random.Random(seed)
    tallies = [fuzz_server("tcp", n_packets // 2, rng), fuzz_server("rtu", n_packets - n_packets // 2, rng)]
    for mode, t in zip(("tcp", "rtu"), tallies, strict=True):
        print(f"  modbus {mode}: {t.packets} packets, {t.crashes} crashes, {t.hangs} hangs, "
              f"{t.bad_replies} bad replies, {t.unanswered} valid requests unanswered, "
              f"RSS {t.rss_start_mb:.1f} → {t.rss_end_mb:.1f} MB", file=sys.stderr)
    return {"packets": float(sum(t.packets for t in tallies)),
            "crashes": float(sum(t.crashes for t in tallies)),
            "hangs": float(sum(t.hangs for t in tallies)),
            "bad_replies": float(sum(t.bad_replies for t in tallies)),
            "rss_growth_mb": sum(t.rss_end_mb - t.rss_start_mb for t in tallies),
            "seconds": time.perf_counter() - t0}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--packets", type=int, default=100_000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    result = fuzz(args.packets, args.seed)
    print("  ".join(f"{k} {v:.3g}" if k in ("rss_growth_mb", "seconds") else f"{k} {v:.0f}"
                    for k, v in result.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
