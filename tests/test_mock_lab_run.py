"""``rig mock lab`` end to end, as a new user runs it: the lab in one process (every device and both cameras
on one simulated world), ``rig run calibrate`` in another with the ``rig.toml`` the lab wrote, the cameras
read as IP cameras (``driver = "opencv"``, MJPEG over HTTP) with host time stamps.

The lab streams at 30 fps (``--fps 30``): two 60 fps cameras cost more CPU than a loaded 2-core CI host
gives next to ``rig``, and a camera that drops more than half its frames fails the calibration's still
frames (it needs half of ``frames_per_position`` per position). Waits are bounded generously; nothing is
timed.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from pymodbus.client import ModbusTcpClient

ROOT = Path(__file__).resolve().parents[1]
WAIT_S = 900.0  # a calibrate on a loaded host; the run ends as soon as it is done
FREQ_OUT = 0x2103  # the drives' output frequency register (docs/exciter.md; 0.01 Hz)
UNIT = {"exciter": 1, "rotor": 2}  # the built-in rig's unit ids


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT)}


@dataclass
class RunningLab:
    proc: subprocess.Popen[str]
    config: Path
    endpoints: dict[str, str]


@pytest.fixture
def lab(tmp_path: Path) -> Iterator[RunningLab]:
    config = tmp_path / "rig.toml"
    with open(tmp_path / "lab.log", "w") as log:
        proc = subprocess.Popen([sys.executable, "-m", "rig.cli", "mock", "lab", "--fps", "30",
                                 "--write-config", str(config)], cwd=tmp_path, env=_env(),
                                stdout=subprocess.PIPE, stderr=log, text=True)
    endpoints: dict[str, str] = {}
    try:
        assert proc.stdout is not None
        for line in proc.stdout:  # until "lab ready" (or the lab's exit: EOF)
            found = re.match(r"lab (\S+): (\S+://\S+)", line)
            if found:
                endpoints[found.group(1)] = found.group(2)
            if line.startswith("lab ready"):
                break
        assert proc.poll() is None, (tmp_path / "lab.log").read_text()
        yield RunningLab(proc, config, endpoints)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=60)
        print(out)  # the lab's closing figures (frames sent and skipped, render CPU)


@pytest.mark.slow
def test_rig_calibrates_against_the_lab(lab: RunningLab, tmp_path: Path) -> None:
    assert set(lab.endpoints) == {"robot", "exciter", "rotor", "generator", "cameras.left", "cameras.right",
                                  "control"}
    assert all("127.0.0.1" in url for url in lab.endpoints.values())
    text = lab.config.read_text()
    assert 'driver = "opencv"' in text and lab.endpoints["cameras.left"] in text
    runs = tmp_path / "runs"
    result = subprocess.run([sys.executable, "-m", "rig.cli", "run", "calibrate", "--config", str(lab.config),
                             "--runs-dir", str(runs), "--no-dashboard"], check=False, cwd=tmp_path,
                            env=_env(),
                            capture_output=True, text=True, timeout=WAIT_S)
    print(result.stdout[-3000:], result.stderr[-3000:])
    (path,) = runs.glob("*/calibration.json")
    calibration = json.loads(path.read_text())
    rms = {name: cam["residuals_rms_px"] for name, cam in calibration["cameras"].items()}
    print("calibration residuals (px rms):", rms)
    assert result.returncode == 0, (result.stdout[-2000:], result.stderr[-2000:])
    assert set(rms) == {"left", "right"}
    # the lab's camera served the plate the arm moved: the fit is the criterion's (calibration_rms_px)
    assert all(value <= 0.5 for value in rms.values()), rms


def _output_hz(url: str, device: str) -> float:
    """The drive's output frequency read with a stock pymodbus client (not our driver)."""
    host, port = url.removeprefix("tcp://").split(":")
    client = ModbusTcpClient(host, port=int(port), timeout=10.0, retries=1)
    assert client.connect()
    try:
        reply = client.read_holding_registers(FREQ_OUT, count=1, device_id=UNIT[device])
        assert not reply.isError(), reply
        return int(reply.registers[0]) / 100.0
    finally:
        client.close()


SPIN = ROOT / "tests" / "spin_procedure.py"  # spins both drives and holds (the safety tests' procedure)


@pytest.mark.slow
@pytest.mark.parametrize(("procedure", "spinning"),
                         [("sweep", ("rotor",)), (str(SPIN), ("exciter", "rotor"))],
                         ids=["sweep-sync-step", "spin-both-drives"])
def test_sigterm_while_drives_spin_leaves_both_drives_of_the_lab_at_rest(lab: RunningLab, tmp_path: Path,
                                                                         procedure: str,
                                                                         spinning: tuple[str, ...]) -> None:
    """``rig run sweep`` calibrates, then spins the rotor to sync the cameras; the spin procedure runs both
    drives. A SIGTERM while they turn (read from the lab by a stock Modbus client) stops both drives, exit 2,
    and the stop document names the signal."""
    runs = tmp_path / "runs"
    with open(tmp_path / "rig.stderr", "w") as err:
        proc = subprocess.Popen([sys.executable, "-m", "rig.cli", "run", procedure, "--config",
                                 str(lab.config), "--runs-dir", str(runs), "--no-dashboard"], cwd=tmp_path,
                                env=_env(), stdout=subprocess.PIPE, stderr=err, text=True)
    try:
        deadline = time.monotonic() + WAIT_S
        while min(_output_hz(lab.endpoints[d], d) for d in spinning) < 1.0:
            assert proc.poll() is None, (tmp_path / "rig.stderr").read_text()[-3000:]
            assert time.monotonic() < deadline, f"{spinning} never turned"
            time.sleep(0.2)
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=WAIT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 2, (tmp_path / "rig.stderr").read_text()[-3000:]
    (record,) = runs.glob("*/record.jsonl")
    stops = [d for line in record.read_text().splitlines() if line.strip()
             for d in [json.loads(line)] if d["type"] == "stop"]
    assert len(stops) == 1 and stops[0]["signal"] == "SIGTERM" and stops[0]["safe_state_failures"] == []
    for device in ("exciter", "rotor"):
        assert _output_hz(lab.endpoints[device], device) == 0.0, device
