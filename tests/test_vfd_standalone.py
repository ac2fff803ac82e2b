"""Both mocks run on their own (`python -m ...`) and answer a plain client on the address they print."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from pymodbus.client import ModbusTcpClient

from drivers.transport import open_transport

ROOT = Path(__file__).resolve().parents[1]


@contextmanager
def standalone(module: str, *args: str) -> Iterator[str]:
    """Start ``python -m module args``; yield the first line it prints; stop it (by its own pid)."""
    proc = subprocess.Popen([sys.executable, "-m", module, *args], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line, f"{module} printed nothing (exit code {proc.poll()})"
        yield line
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def test_vfd_mock_runs_standalone_on_tcp() -> None:
    with standalone("drivers.mock.vfd_server", "--port", "0") as line:
        port = int(re.search(r"tcp://127\.0\.0\.1:(\d+)", line).group(1))  # type: ignore[union-attr]
        client = ModbusTcpClient("127.0.0.1", port=port, timeout=2.0, retries=0)
        try:
            assert client.connect()
            assert not client.write_register(0x2001, 1000, device_id=1).isError()
            assert client.read_holding_registers(0x2102, count=1, device_id=1).registers == [1000]
        finally:
            client.close()


def test_generator_mock_runs_standalone_on_a_pty() -> None:
    with standalone("drivers.mock.generator_server", "--pty") as line:
        device = re.search(r"(/dev/\S+)", line).group(1)  # type: ignore[union-attr]
        with open_transport(device, timeout_s=30.0) as transport:  # a bound: a starved mock answers late
            transport.write(b"*IDN?\n")
            assert transport.read_until(b"\n").startswith(b"Keysight Technologies,33521B,")
