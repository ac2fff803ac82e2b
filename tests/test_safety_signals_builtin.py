"""Stop signals on the built-in simulated rig, in the phases of a real procedure (``rig run sweep``):
acquisition (the sync step films the spinning rotor), the sweep, and the report (its checkpoints: before
each analysis and before the certificate). Each ends exit 2 with the stop document naming the signal, and
the drives' own read-back (over Modbus, by the runner, before the in-process mocks end with the process) at
0 Hz. The stand-alone mock variant, read
back by a stock Modbus client afterwards, is ``test_safety_standalone.py``."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.certify_support import write_config

ROOT = Path(__file__).resolve().parents[1]
WAIT_S = 300.0  # generous bound on a loaded machine; each wait ends as soon as the phase is reached
# the test's own bound: the phase, then the safe stop (WAIT_S each), above the suite's 300 s default
TEST_TIMEOUT_S = 2 * WAIT_S + 60.0
# each phase's step begins: the signal comes while that step runs (the sweep step films, then reduces its
# frames for ≈ 20 s wall with checkpoints; its ``sweep`` event is written only after all of it)
PHASES = {"acquisition": '"name":"sync","status":"begin"', "sweep": '"name":"sweep","status":"begin"',
          "report": '"name":"report","status":"begin"'}
# the report phase comes after the whole sweep is filmed: a 3 s sweep to 4 Hz reaches it (the default,
# 24 s to 30 Hz and the ramp back down, is most of these tests' CPU); the other phases begin before it
SWEEP_SETTINGS = {"report": ("duration_s=3", "max_hz=4", "shape=linear")}


def _documents(run_dir: Path) -> list[dict]:
    return [json.loads(line) for line in (run_dir / "record.jsonl").read_text().splitlines() if line.strip()]


def _run_until(tmp_path: Path, needle: str,
               settings: tuple[str, ...] = ()) -> tuple[subprocess.Popen[str], Path]:
    # the built-in rig, its report the certificate only (certify_support.write_config: [report] no comparison,
    # no figure — the report phase is about the stop, not about what the report draws)
    argv = [sys.executable, "-m", "rig.cli", "run", "sweep", "--config", str(write_config(tmp_path)),
            "--runs-dir", str(tmp_path / "runs"), "--set", "hold_s=0"]
    for setting in settings:
        argv += ["--set", setting]
    with open(tmp_path / "rig.stderr", "w") as err:  # a file the test watches while the run goes on
        proc = subprocess.Popen(argv, cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT)},
                                stdout=subprocess.PIPE, stderr=err, text=True)
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        records = list((tmp_path / "runs").glob("*/record.jsonl")) if (tmp_path / "runs").is_dir() else []
        if records and needle in records[0].read_text():
            return proc, records[0].parent
        assert proc.poll() is None, (proc.communicate(), (tmp_path / "rig.stderr").read_text())
        time.sleep(0.05)
    proc.kill()
    raise AssertionError(f"{needle} never appeared")


def _acknowledged(proc: subprocess.Popen[str], stderr: Path) -> None:
    """Wait until rig has handled the first stop signal (its line on stderr) or has ended (a checkpoint came
    first): two signals sent before its handler ran are one pending signal (POSIX does not queue them)."""
    deadline = time.monotonic() + WAIT_S
    while "abort requested; stopping at the next" not in stderr.read_text() and proc.poll() is None:
        assert time.monotonic() < deadline, stderr.read_text()
        time.sleep(0.05)


@pytest.mark.slow
@pytest.mark.timeout(TEST_TIMEOUT_S)
@pytest.mark.parametrize(("phase", "signals"), [
    ("acquisition", [signal.SIGTERM]),
    ("sweep", [signal.SIGHUP]),
    ("sweep", [signal.SIGINT, signal.SIGINT]),
    ("report", [signal.SIGINT]),
    ("report", [signal.SIGQUIT, signal.SIGQUIT]),
], ids=["acquisition-SIGTERM", "sweep-SIGHUP", "sweep-SIGINTx2", "report-SIGINT", "report-SIGQUITx2"])
def test_stop_signal_in_each_phase_is_a_safe_abort(tmp_path: Path, phase: str,
                                                   signals: list[signal.Signals]) -> None:
    proc, run_dir = _run_until(tmp_path, PHASES[phase], SWEEP_SETTINGS.get(phase, ()))
    for i, sig in enumerate(signals):
        if i:
            _acknowledged(proc, tmp_path / "rig.stderr")
        proc.send_signal(sig)
    out, _ = proc.communicate(timeout=WAIT_S)
    err = (tmp_path / "rig.stderr").read_text()
    assert proc.returncode == 2, (out, err)  # a Ctrl-C during the report used to end "pass", exit 0
    docs = _documents(run_dir)
    (stop,) = [d for d in docs if d["type"] == "stop"]
    assert stop["exit_status"] == "abort" and stop["outcome"] == "aborted"
    assert stop["signal"] == signals[0].name
    assert stop["safe_state_failures"] == []
    for axis in ("exciter", "rotor"):
        state = stop["safe_state"][axis]
        assert state["setpoint_hz"] == 0.0 and abs(state["frequency_hz"]) <= 0.02, state
    assert stop["safe_state"]["robot"]["moved_mm"] == 0.0
    if phase == "sweep":  # the abort came in the sweep step, which never completed
        assert "sweep" not in {d["name"] for d in docs if d["type"] == "step" and d["status"] == "done"}
    if phase == "report":
        # the abort takes effect at the report step's checkpoint before the certificate is issued: no
        # certificate saying the run was finishing normally stands beside a stop document saying abort
        assert "report" not in {d["name"] for d in docs if d["type"] == "step" and d["status"] == "done"}
        assert not (run_dir / "certificate.json").exists()
