"""Fuzzing the mock SCPI generator as a separate process: random and mutated lines over real sockets.

    .venv/bin/python benchmarks/fuzz_scpi.py [--packets 100000] [--seed 0]

The mock runs as ``python -m drivers.mock.generator_server --port 0`` (its own paced world). Packets are
LF-terminated program messages: valid commands (a 1 ms repeating sweep among them), mutated ones (bytes
flipped, inserted, deleted, repeated), random bytes, very long lines (beyond the mock's 4 KiB input
limit), partial lines abandoned when a connection is closed, and slow lines sent a few bytes at a time.
Every 1,000 packets (and at the end) a fresh connection asks ``*IDN?`` and ``SYST:ERR?``.

Figures: ``crashes`` (the server process died; it is restarted), ``hangs`` (a fresh ``*IDN?`` unanswered
within 2 s), ``bad_replies`` (a reply line that is not printable ASCII, or a health-check answer of the
wrong form), ``rss_growth_mb`` (VmRSS from /proc/PID/status, after the first 10 % of the packets to the
end), ``seconds``. Target: 0 crashes, 0 hangs, RSS growth < 5 MB per 10⁵ packets; the printout gives each
figure's ratio to its target. ``benchmarks/fuzz.py`` runs :func:`fuzz` of every ``fuzz_*`` module.
"""

from __future__ import annotations

import argparse
import os
import random
import re
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HEALTH_EVERY = 1000
HEALTH_TIMEOUT_S = 2.0
RECONNECT_EVERY = 2000
MAX_LINE = 4096
RSS_TARGET_MB_PER_1E5 = 5.0
VALID = ["*IDN?", "*RST", "*CLS", "*ESR?", "*ESE 36", "*ESE?", "*SRE 16", "*SRE?", "*STB?", "*OPC", "*OPC?",
         "*TST?", "*WAI", "SYST:ERR?", "SYST:ERR:COUN?", "SYST:VERS?", "SOUR1:FREQ 12.5", "FREQ?",
         "VOLT 0.5", "VOLT?", "VOLT:UNIT VRMS", "VOLT:UNIT VPP", "VOLT:UNIT DBM", "OUTP1:LOAD INF",
         "OUTP1:LOAD 50", "OUTP1 ON", "OUTP1 OFF", "SWE:STAT ON", "SWE:STAT OFF", "SWE:TIME 0.001",
         "FREQ:STAR 5;STOP 30", "SWE:SPAC LOG", "SWE:SPAC LIN", "FUNC SQU", "FUNC SIN", "VOLT:OFFS 1",
         ":SOUR1:FREQ:STAR?;STOP?;:OUTP1?", "VOLT MAX", "FREQ MIN", "TRIG1:SOUR IMM"]
_PRINTABLE = re.compile(rb"^[\x20-\x7e]*$")
_ERROR_ENTRY = re.compile(rb'^[+-]?\d+,".*"$')


class MockProcess:
    """The mock generator in a subprocess on an ephemeral port."""

    def __init__(self) -> None:
        env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        self.proc = subprocess.Popen([sys.executable, "-m", "drivers.mock.generator_server", "--port", "0"],
                                     cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                     text=True)
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        m = re.search(r"tcp://127\.0\.0\.1:(\d+)", line)
        if not m:
            self.stop()
            raise RuntimeError(f"the mock did not report its port: {line!r}")
        self.port = int(m.group(1))

    @property
    def alive(self) -> bool:
        return self.proc.poll() is None

    def rss_mb(self) -> float:
        status = Path(f"/proc/{self.proc.pid}/status").read_text()
        m = re.search(r"^VmRSS:\s+(\d+) kB", status, re.MULTILINE)
        return int(m.group(1)) / 1024.0 if m else float("nan")

    def stop(self) -> None:
        if self.alive:
            self.proc.terminate()
            try:
                self.proc.wait(5.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


class Client:
    """A fuzzing connection; a reader thread consumes and checks every reply line."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5.0)
        self.bad_replies = 0
        self._buffer = b""
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        while True:
            try:
                data = self.sock.recv(65536)
            except OSError:
                return
            if not data:
                return
            self._buffer += data
            *lines, self._buffer = self._buffer.split(b"\n")
            self.bad_replies += sum(1 for r in lines if not _PRINTABLE.match(r) or len(r) > MAX_LINE)

    def send(self, data: bytes, slow: bool = False) -> bool:
        try:
            if slow:
                for i in range(0, len(data), 3):
                    self.sock.sendall(data[i:i + 3])
                    time.sleep(0.001)
            else:
                self.sock.sendall(data)
        except OSError:
            return False
        return True

    def close(self) -> None:
        try:
            self.sock.close()
        finally:
            self._reader.join(timeout=2.0)


def _mutate(rng: random.Random, line: bytes) -> bytes:
    data = bytearray(line)
    for _ in range(rng.randint(1, 4)):
        op = rng.randrange(5)
        i = rng.randrange(len(data) + 1)
        if op == 0 and data:  # flip bits of a byte
            data[min(i, len(data) - 1)] ^= 1 << rng.randrange(8)
        elif op == 1:  # insert a byte (separators and quotes are the interesting ones)
            special = rng.choice(b";:,\"' *?#\t\r\x00\xff")
            data.insert(i, special if rng.random() < 0.6 else rng.randrange(256))
        elif op == 2 and data:  # delete a byte
            del data[min(i, len(data) - 1)]
        elif op == 3:  # repeat a slice
            j = rng.randrange(i, len(data) + 1)
            data[i:i] = data[i:j] * rng.randint(1, 20)
        else:  # splice another command in
            data[i:i] = rng.choice(VALID).encode()
    return bytes(data).replace(b"\n", b" ")


def _packet(rng: random.Random) -> tuple[bytes, bool, bool]:
    """(bytes with their LF, sent slowly, left unterminated)."""
    kind = rng.random()
    if kind < 0.40:
        data = ";".join(rng.choice(VALID) for _ in range(rng.randint(1, 3))).encode()
    elif kind < 0.80:
        data = _mutate(rng, rng.choice(VALID).encode())
    elif kind < 0.97:
        data = bytes(rng.randrange(256) for _ in range(rng.randint(0, 64))).replace(b"\n", b"")
    else:
        data = rng.choice(VALID).encode() * rng.randint(100, 1000)  # very long: up to 3 × the limit
    return data + b"\n", rng.random() < 0.002, rng.random() < 0.001


def _health(port: int, timeout_s: float = HEALTH_TIMEOUT_S) -> tuple[bool, bool]:
    """(answered in time, answers well formed): ``*IDN?`` and ``SYST:ERR?`` on a fresh connection."""
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=timeout_s) as sock:
            sock.settimeout(timeout_s)
            stream = sock.makefile("rb")
            sock.sendall(b"*IDN?\n")
            idn = stream.readline()
            sock.sendall(b"SYST:ERR?\n")
            err = stream.readline()
    except OSError:
        return False, True
    if not idn.endswith(b"\n") or not err.endswith(b"\n"):
        return False, True
    well_formed = idn.startswith(b"Keysight Technologies,33521B,") and _ERROR_ENTRY.match(err.rstrip(b"\n"))
    return True, bool(well_formed)


def fuzz(n_packets: int, seed: int) -> dict[str, float]:
    """Send ``n_packets`` random and mutated lines to a mock generator subprocess; see the module doc."""
    rng = random.Random(seed)
    start = time.perf_counter()
    mock = MockProcess()
    crashes = hangs = bad = 0
    client = Client(mock.port)
    rss_start = rss_end = float("nan")
    try:
        for i in range(1, n_packets + 1):
            data, slow, partial = _packet(rng)
            if partial:  # abandon an unterminated line with its connection
                client.send(data[: max(len(data) // 2, 1)])
                bad += client.bad_replies
                client.close()
                client = Client(mock.port)
                continue
            if not client.send(data, slow):
                bad += client.bad_replies
                client.close()
                if not mock.alive:
                    crashes += 1
                    mock = MockProcess()
                client = Client(mock.port)
            if i % RECONNECT_EVERY == 0:
                bad += client.bad_replies
                client.close()
                client = Client(mock.port)
            if i % HEALTH_EVERY == 0 or i == n_packets:
                if not mock.alive:
                    crashes += 1
                    mock = MockProcess()
                    client.close()
                    client = Client(mock.port)
                    continue
                answered, well_formed = _health(mock.port)
                hangs += not answered
                bad += not well_formed
            if i == max(n_packets // 10, 1):
                rss_start = mock.rss_mb()
        _health(mock.port)  # everything sent has been read and executed
        rss_end = mock.rss_mb() if mock.alive else float("nan")
    finally:
        bad += client.bad_replies
        client.close()
        mock.stop()
    return {"packets": float(n_packets), "crashes": float(crashes), "hangs": float(hangs),
            "bad_replies": float(bad), "rss_growth_mb": rss_end - rss_start,
            "seconds": time.perf_counter() - start}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--packets", type=int, default=100_000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    result = fuzz(args.packets, args.seed)
    rss_target = RSS_TARGET_MB_PER_1E5 * args.packets / 1e5
    for key, value in result.items():
        print(f"{key:14s} {value:12.3f}")
    print(f"RSS growth {result['rss_growth_mb']:.2f} MB = {result['rss_growth_mb'] / rss_target:.2f} × the "
          f"target ({rss_target:.2f} MB for {args.packets} packets); "
          f"{result['packets'] / result['seconds']:.0f} packets/s")
    ok = result["crashes"] == 0 and result["hangs"] == 0 and result["rss_growth_mb"] < rss_target
    print("target met" if ok else "TARGET MISSED")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
