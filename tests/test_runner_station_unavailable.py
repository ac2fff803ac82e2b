"""A station that cannot be built (a device unreachable): the run folder exists with its start document
(configuration, parameters, versions; no device snapshot) and a stop ``fail`` saying why; the console
shows one line (the reason and the run folder) and the traceback is only in the run's ``rig.log``."""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from drivers.sim.clock import VirtualClock
from rig.config.rig_config import load_config
from rig.record.catalogue import run_folders
from rig.record.writer import load_run
from rig.run.station import StationError, open_station
from tests.certify_support import write_config

ROOT = Path(__file__).resolve().parents[1]


def _unreachable_robot(tmp_path: Path) -> Path:
    config = write_config(tmp_path)
    text = config.read_text()
    robot = text.index("[devices.robot]")
    line = re.compile(r"^address = .*$", re.M).search(text, robot)
    assert line is not None
    config.write_text(text[:line.start()] + 'address = "tcp://127.0.0.1:1"' + text[line.end():])
    return config


def _rig(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "rig.cli", *args], cwd=tmp_path,
                          env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True,
                          timeout=120, check=False)


def test_run_with_an_unreachable_robot_records_why_in_the_run_folder(tmp_path: Path) -> None:
    config = _unreachable_robot(tmp_path)
    proc = _rig(tmp_path, "run", "plate", "--config", str(config), "--set", "record_s=1.5", "--no-dashboard")
    assert proc.returncode == 3, proc.stderr
    (run_dir,) = run_folders(tmp_path / "runs")

    # the console: one line with the reason and the run folder, no traceback
    assert proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "could not build the station" in lines[0] and "tcp://127.0.0.1:1" in lines[0]
    assert lines[0].endswith(str(run_dir)) and "Traceback" not in proc.stderr

    run = load_run(run_dir)
    assert [d["type"] for d in run.documents] == ["start", "stop"]
    start, stop = run.start, run.stop
    assert start["procedure"] == "plate" and start["parameters"]["record_s"] == 1.5
    assert start["rig"]["devices"]["robot"]["address"] == "tcp://127.0.0.1:1"  # the configuration snapshot
    assert start["versions"]["python"] and start["devices"] == {"connected": False}
    assert stop["exit_status"] == "fail" and stop["exit_code"] == 3 and stop["outcome"] == "fault"
    assert stop["reason"].startswith("could not build the station: StationError: robot at tcp://127.0.0.1:1")
    assert "refused" in stop["reason"].lower()

    log_text = (run_dir / "rig.log").read_text()
    assert "Traceback (most recent call last)" in log_text and "ConnectionRefusedError" in log_text


def test_certify_with_an_unreachable_robot_also_leaves_a_run_folder(tmp_path: Path) -> None:
    config = _unreachable_robot(tmp_path)
    proc = _rig(tmp_path, "certify", "--config", str(config), "--set", 'preset="fast"')
    assert proc.returncode == 3 and "Traceback" not in proc.stderr, proc.stderr
    (run_dir,) = run_folders(tmp_path / "runs")
    run = load_run(run_dir)
    assert run.start["procedure"] == "certify" and run.stop["exit_status"] == "fail"
    assert "robot at tcp://127.0.0.1:1" in run.stop["reason"]


def test_cameras_are_built_before_any_device_is_connected(tmp_path: Path) -> None:
    """A network camera can take seconds to connect and settle on a loaded host; a device connected before
    it would be silent that long before the runner's heartbeats start (the lab's arm ended the session: its
    b-CAP watchdog saw 10 s of silence). So the cameras come first, and one that fails is refused before any
    device hears a byte."""
    with socket.create_server(("127.0.0.1", 0)) as robot:
        robot.settimeout(0.0)
        config = write_config(tmp_path)
        text = config.read_text()
        text = re.sub(r'^(\[devices\.robot\]\n(?:.*\n)*?)address = .*$',
                      rf'\1address = "tcp://127.0.0.1:{robot.getsockname()[1]}"', text, count=1, flags=re.M)
        missing = (tmp_path / "missing.avi").as_posix()
        text = text.replace('[cameras.left]\ndriver = "sim"',
                            f'[cameras.left]\ndriver = "file"\nsource = "{missing}"')
        config.write_text(text)
        with pytest.raises(StationError, match=r"cameras\.left\.source"), \
                open_station(load_config(config), VirtualClock()):
            pass
        with pytest.raises(BlockingIOError):
            robot.accept()  # no connection was ever attempted
