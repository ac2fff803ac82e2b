"""`rig check` reaches every device of the simulated rig; `rig mock` serves a device on 127.0.0.1 that the
real driver can use, and stops on Ctrl-C."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from rig.cli import main

ROOT = Path(__file__).resolve().parents[1]


def test_check_reaches_every_simulated_device(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check"]) == 0
    out = capsys.readouterr().out
    assert "configuration builtin:sim: valid" in out
    for name in ("robot", "exciter", "rotor", "generator"):
        assert re.search(rf"^  {name}\s+reachable$", out, re.MULTILINE), out


def test_mock_exciter_serves_modbus_to_the_real_driver() -> None:
    from drivers.exciter.vfd import VfdDriver
    from drivers.modbus_link import ModbusLink

    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "rig.cli", "mock", "exciter", "--port", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        line = proc.stdout.readline()
        match = re.search(r"tcp://127\.0\.0\.1:(\d+)", line)
        assert match, (line, proc.stderr.read() if proc.poll() is not None else "")
        client = ModbusLink(f"tcp://127.0.0.1:{match.group(1)}", timeout_s=2.0, retries=0)
        try:
            vfd = VfdDriver(client)
            vfd.set_frequency_hz(12.5)
            assert vfd.read_status().freq_cmd_hz == pytest.approx(12.5)
        finally:
            client.close()
    finally:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=20)
    assert proc.returncode == 0
