"""The procedures' safety on the simulated rig, through the real ``rig`` command:

- Ctrl-C (SIGINT) in the middle of the certification's sweep: exit 2, the run's stop is ``abort``, the
  exciter stopped and the arm halted by the runner, the record readable;
- a plan beyond a limit (a sweep above the exciter's frequency limit, a plate slide outside the arm's
  envelope): exit 4 before any device is connected (no run folder), the parameter and the limit named.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rig.record.writer import load_run
from tests.certify_support import write_config

ROOT = Path(__file__).resolve().parents[1]


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT)}


def _rig(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    config = write_config(tmp_path)
    return subprocess.run([sys.executable, "-m", "rig.cli", *args, "--config", str(config)], cwd=tmp_path,
                          env=_env(), capture_output=True, text=True, timeout=240, check=False)


def _documents(run_dir: Path) -> list[dict]:
    return [json.loads(line) for line in (run_dir / "record.jsonl").read_text().splitlines() if line.strip()]


def test_sweep_above_the_frequency_limit_is_refused_before_connecting(tmp_path: Path) -> None:
    # certify checks the plan of all its steps: the sweep (its last motion) is refused before calibrate runs
    proc = _rig(tmp_path, "certify", "--set", 'preset="fast"', "--set", "sweep_max_hz=40")
    assert proc.returncode == 4, proc.stderr
    assert "certify.sweep_max_hz = 40 Hz: frequency 40 Hz" in proc.stderr, proc.stderr
    assert "exceeds the exciter's limit 32 Hz (limits.exciter.max_frequency_hz)" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "runs").exists()  # no run folder, no station: nothing was connected


def test_plate_slide_outside_the_envelope_is_refused_before_connecting(tmp_path: Path) -> None:
    proc = _rig(tmp_path, "run", "calibrate", "--set", "slide_positions_mm=[0.0, 300.0]")
    assert proc.returncode == 4, proc.stderr
    assert "calibrate.slide_positions_mm = [0.0, 300.0] mm" in proc.stderr, proc.stderr
    assert "pose x = 720 mm" in proc.stderr and "[150, 650] mm (limits.robot.envelope_x_mm)" in proc.stderr
    assert not (tmp_path / "runs").exists()


def test_ctrl_c_mid_sweep_aborts_with_exciter_stopped_and_arm_halted(tmp_path: Path) -> None:
    config = write_config(tmp_path)
    proc = subprocess.Popen([sys.executable, "-m", "rig.cli", "certify", "--config", str(config),
                             "--set", 'preset="fast"', "--set", "sweep_duration_s=120",
                             "--set", "accuracy_grid_points=0", "--set", "accuracy_cycles=0",
                             "--set", "figures=false"],
                            cwd=tmp_path, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        deadline = time.monotonic() + 180
        record = None
        while time.monotonic() < deadline:
            runs = list((tmp_path / "runs").glob("*")) if (tmp_path / "runs").is_dir() else []
            if runs:
                record = runs[0] / "record.jsonl"
                text = record.read_text() if record.is_file() else ""
                sweeping = [ln for ln in text.splitlines()
                            if '"stream":"exciter"' in ln and '"step":"sweep"' in ln]
                if len(sweeping) >= 20:
                    break
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.05)
        else:
            raise AssertionError("the sweep did not start in time")
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 2, err
    run = load_run(record.parent)
    assert run.stop["exit_status"] == "abort" and run.stop["outcome"] == "aborted"
    assert run.stop["safe_state_failures"] == []
    steps = run.documents
    assert not any(d["type"] == "step" and d["name"] == "sweep" and d["status"] == "done" for d in steps)
    logs = [d["message"] for d in steps if d["type"] == "log"]
    assert any(m.startswith("exciter:") and "done" in m for m in logs), logs
    assert any(m.startswith("robot:") and "done" in m for m in logs), logs
    # the exciter was running when interrupted (its last polled frequency was not zero)
    polled = [d["data"]["frequency_hz"] for d in steps if d["type"] == "event" and d["stream"] == "exciter"]
    assert polled[-1] > 0
    # ... and after the runner made it safe, the devices themselves say so (read back over their protocols
    # after the safe-state actions): the drives commanded to 0 Hz with their output at rest (within the
    # driver's 0.02 Hz "reached" tolerance: the crank drive may still report its last 0.01 Hz of
    # deceleration), the arm still, the generator's output off
    state = run.stop["safe_state"]
    for axis in ("exciter", "rotor"):
        assert state[axis]["setpoint_hz"] == 0.0 and abs(state[axis]["frequency_hz"]) <= 0.02, state
        assert state[axis]["status"] in ("stopped", "decelerating"), state
    assert state["robot"]["moved_mm"] == 0.0 and state["robot"]["settle_s"] > 0, state
    assert state["generator"] == {"output_on": False}, state


@pytest.mark.slow
def test_certify_killed_mid_accuracy_resumes_without_repeating_done_steps(tmp_path: Path) -> None:
    config = write_config(tmp_path)
    # the resumed run goes on through the sweep: 2 → 4 Hz in 2 s (not the preset's 2 → 12 Hz in 8 s) is
    # enough for what is checked here, which steps run again (the sweep's measurement is test_certify_e2e's)
    args = [sys.executable, "-m", "rig.cli", "certify", "--config", str(config), "--set", 'preset="fast"',
            "--set", "figures=false", "--set", "sweep_max_hz=4", "--set", "sweep_duration_s=2"]
    proc = subprocess.Popen(args, cwd=tmp_path, env=_env(), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline:
            records = list((tmp_path / "runs").glob("*/record.jsonl")) if (tmp_path / "runs").is_dir() else []
            if records and '"name":"accuracy_iso9283","status":"begin"' in records[0].read_text():
                break
            assert proc.poll() is None
            time.sleep(0.05)
        proc.kill()  # SIGKILL: no cleanup, no stop document
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    run_dir = records[0].parent
    assert not any(d["type"] == "stop" for d in _documents(run_dir))
    resumed = subprocess.run([sys.executable, "-m", "rig.cli", "run", "--resume", str(run_dir), "--config",
                              str(config)], cwd=tmp_path, env=_env(), capture_output=True, text=True,
                             timeout=300, check=False)
    assert resumed.returncode in (0, 1), resumed.stderr
    docs = _documents(run_dir)
    begins = [d["name"] for d in docs if d["type"] == "step" and d["status"] == "begin"]
    assert begins.count("calibrate") == 1 and begins.count("sync") == 1 and begins.count("accuracy_grid") == 1
    assert begins.count("accuracy_iso9283") == 2  # cut short, then redone
    assert (run_dir / "certificate.json").is_file() and docs[-1]["type"] == "stop"
    assert docs[-1]["exit_status"] == "success"
