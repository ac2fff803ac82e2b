"""`kill -9` of `rig run` on the simulated rig mid-run leaves a readable record; `--resume` completes it."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import pytest

from rig.cli import main
from rig.record.catalogue import run_folders
from rig.record.writer import TruncatedRecordWarning, load_run

ROOT = Path(__file__).resolve().parents[1]

PROCEDURE = textwrap.dedent('''
    """Moves the arm, then vibrates while the file HOLD exists in the working directory."""
    import time
    from dataclasses import dataclass
    from pathlib import Path

    NAME = "holder"

    @dataclass(frozen=True)
    class Parameters:
        pass

    def run(ctx, params):
        with ctx.step("move") as step:
            if not step.skipped:
                result = ctx.device("robot").move_to([400.0, 0.0, 320.0, 90.0, 0.0, 90.0])
                ctx.event("arm", {"commanded_pose": result.commanded_pose, "t_end_s": result.t_end_s})
        with ctx.step("vibrate") as step:
            ctx.device("exciter").set_frequency(4.0)
            i = 0
            while Path("HOLD").exists():
                ctx.event("tick", {"i": i})
                if i == 10:
                    print("HOLDING", flush=True)
                ctx.checkpoint()
                time.sleep(0.01)
                i += 1
        return {"passed": True, "summary": "held"}
''')


def test_kill_9_then_resume_on_the_simulated_rig(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    proc_file = tmp_path / "holder.py"
    proc_file.write_text(PROCEDURE)
    (tmp_path / "HOLD").write_text("")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    argv = [sys.executable, "-m", "rig.cli", "run", str(proc_file), "--runs-dir", str(tmp_path / "runs")]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            cwd=tmp_path)
    assert proc.stdout.readline().strip() == "HOLDING", proc.stderr.read() if proc.poll() else ""
    proc.kill()
    proc.communicate(timeout=30)
    (run_dir,) = run_folders(tmp_path / "runs")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TruncatedRecordWarning)
        crashed = load_run(run_dir)
    assert crashed.stop is None and list(crashed.steps_completed) == ["move"]
    assert len(crashed.events["tick"]) >= 10

    (tmp_path / "HOLD").unlink()
    monkeypatch.chdir(tmp_path)
    assert main(["run", str(proc_file), "--resume", str(run_dir)]) == 0
    run = load_run(run_dir)
    assert run.exit_status == "success" and list(run.steps_completed) == ["move", "vibrate"]
    assert len(run.starts) == 2 and run.starts[1]["resume"] is True
    assert len(run.events["arm"]) == 1  # the move was not repeated
    assert "tick" not in run.events  # the interrupted attempt at "vibrate" was superseded
    assert (tmp_path / "runs").exists() and len(run_folders(tmp_path / "runs")) == 1
