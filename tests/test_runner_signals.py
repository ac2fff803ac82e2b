"""The runner as a real process: Ctrl-C once and twice, ``kill -9`` and ``--resume``."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest

from rig.record.writer import TruncatedRecordWarning, load_run

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def _start(tmp_path: Path, mode: str, *extra: str) -> tuple[subprocess.Popen[str], Path, Path]:
    calls = tmp_path / "calls.txt"
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{HERE}"}
    argv = [sys.executable, str(HERE / "runner_dummy.py"), str(tmp_path / "runs"), str(calls), mode, *extra]
    with open(tmp_path / "stderr.txt", "w") as err:  # a file the tests can watch while the run goes on
        proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=err, text=True, env=env, cwd=tmp_path)
    line = proc.stdout.readline().strip()  # the run folder, printed once inside step b
    assert line, (tmp_path / "stderr.txt").read_text()
    return proc, Path(line), calls


def _ticks_after(run_dir: Path, n: int, timeout_s: float = 60.0, stream: str = "tick") -> None:
    """Wait until the record holds at least ``n`` events of ``stream`` (the procedure is really running);
    the bound is generous (a loaded machine), the wait ends as soon as they are there."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if (run_dir / "record.jsonl").read_text().count(f'"stream":"{stream}"') >= n:
            return
        time.sleep(0.02)
    raise AssertionError(f"the procedure did not tick ({stream})")


def _acknowledged(proc: subprocess.Popen[str], timeout_s: float = 60.0) -> None:
    """Wait until the runner has handled the first stop signal (its message on stderr). Two signals sent
    before the process ran its handler are one pending signal (POSIX does not queue them), so a second
    signal is sent only after this; the bound is generous, the wait ends as soon as the line is there."""
    stderr = Path(proc.args[3]).parent / "stderr.txt"  # argv: python runner_dummy.py RUNS CALLS MODE …
    deadline = time.monotonic() + timeout_s
    while "abort requested; stopping at the next checkpoint" not in stderr.read_text():
        assert time.monotonic() < deadline and proc.poll() is None, stderr.read_text()
        time.sleep(0.02)


def _finish(proc: subprocess.Popen[str]) -> tuple[int, str, str]:
    out, _ = proc.communicate(timeout=60)
    return proc.returncode, out, (Path(proc.args[3]).parent / "stderr.txt").read_text()


def test_first_ctrl_c_aborts_at_the_next_checkpoint(tmp_path: Path) -> None:
    proc, run_dir, calls = _start(tmp_path, "forever")
    _ticks_after(run_dir, 5)
    proc.send_signal(signal.SIGINT)
    code, out, err = _finish(proc)
    assert code == 2, (out, err)
    assert "abort requested; stopping at the next checkpoint" in err
    run = load_run(run_dir)
    assert not run.truncated_last_line
    assert run.exit_status == "abort" and run.stop["reason"] == "aborted by the operator (Ctrl-C)"
    assert run.stop["exit_code"] == 2 and "a" in run.steps_completed and "b" not in run.steps_completed
    lines = calls.read_text().splitlines()
    assert {"exciter.safe_state", "rotor.safe_state", "robot.safe_state"} <= set(lines)
    assert lines[-1] == "station.closed"


def test_second_ctrl_c_aborts_at_once(tmp_path: Path) -> None:
    proc, run_dir, calls = _start(tmp_path, "deaf")  # never checkpoints in step b
    _ticks_after(run_dir, 5)
    proc.send_signal(signal.SIGINT)
    _acknowledged(proc)
    _ticks_after(run_dir, run_dir.joinpath("record.jsonl").read_text().count('"stream":"tick"') + 3)
    assert proc.poll() is None  # no checkpoint, so the first Ctrl-C cannot stop it: it still ticks
    proc.send_signal(signal.SIGINT)
    code, out, err = _finish(proc)
    assert code == 2, (out, err)
    run = load_run(run_dir)
    assert run.exit_status == "abort" and run.stop["reason"] == "aborted at once (second Ctrl-C)"
    assert "exciter.safe_state" in calls.read_text().splitlines()


def test_kill_9_leaves_a_readable_record_and_resume_completes_it(tmp_path: Path) -> None:
    proc, run_dir, calls = _start(tmp_path, "forever")
    _ticks_after(run_dir, 20)
    proc.kill()
    proc.communicate(timeout=30)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TruncatedRecordWarning)  # the kill may land mid-line
        crashed = load_run(run_dir)
    assert crashed.stop is None and crashed.steps_completed == {"a": ["a.json"]}
    ticks_before = crashed.events["tick"]["i"].tolist()
    assert ticks_before == list(range(len(ticks_before))) and len(ticks_before) >= 20
    calls.write_text("")

    proc, same_dir, calls = _start(tmp_path, "normal", "--resume", str(run_dir))
    code, out, err = _finish(proc)
    assert code == 0, (out, err)
    assert same_dir == run_dir
    run = load_run(run_dir)
    assert not run.truncated_last_line and len(run.starts) == 2 and run.starts[1]["resume"] is True
    assert run.exit_status == "success" and run.steps_completed == {"a": ["a.json"], "b": []}
    # step a was not redone; the interrupted attempt at b is superseded by the completed one
    assert "exciter.run_a" not in calls.read_text()
    assert len(run.events["exciter"]) == 1
    assert run.events["tick"]["i"].tolist() == list(range(30)) and set(run.events["tick"]["session"]) == {1}
    # the superseded attempt is still in the file, and its seq numbers were not reused
    full = load_run(run_dir, include_superseded=True)
    assert full.events["tick"]["seq"].tolist() == list(range(len(ticks_before) + 30))


STOP_SIGNALS = [signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT]


@pytest.mark.parametrize("sig", STOP_SIGNALS, ids=lambda s: s.name)
def test_every_stop_signal_takes_the_safe_stop(tmp_path: Path, sig: signal.Signals) -> None:
    """What systemd, docker, a CI timeout, a closed terminal or Ctrl-\\ send: the same safe stop as Ctrl-C,
    and the stop document names the signal."""
    proc, run_dir, calls = _start(tmp_path, "forever")
    _ticks_after(run_dir, 5)
    proc.send_signal(sig)
    code, out, err = _finish(proc)
    assert code == 2, (out, err)
    assert f"{sig.name}: abort requested" in err
    run = load_run(run_dir)
    assert run.exit_status == "abort" and run.stop["reason"] == f"aborted by {sig.name}"
    assert run.stop["signal"] == sig.name and run.stop["exit_code"] == 2
    lines = calls.read_text().splitlines()
    safe = [x for x in lines if x.endswith("safe_state")]
    assert safe == ["exciter.safe_state", "rotor.safe_state", "robot.safe_state", "left.safe_state"]
    assert lines[-1] == "station.closed"


@pytest.mark.parametrize("sig", [signal.SIGINT, *STOP_SIGNALS], ids=lambda s: s.name)
def test_a_signal_during_the_report_step_ends_the_run_aborted(tmp_path: Path, sig: signal.Signals) -> None:
    """The report step has no checkpoint: the abort takes effect when it ends, and the run is aborted
    (exit 2), not passed."""
    proc, run_dir, calls = _start(tmp_path, "report")
    _ticks_after(run_dir, 3, stream="report_tick")
    proc.send_signal(sig)
    _acknowledged(proc)
    (tmp_path / "report.release").touch()  # the report step ends now, its abort pending
    code, out, err = _finish(proc)
    assert code == 2, (out, err)
    run = load_run(run_dir)
    assert run.exit_status == "abort" and run.stop["outcome"] == "aborted" and run.stop["signal"] == sig.name
    assert "exciter.safe_state" in calls.read_text().splitlines()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=lambda s: s.name)
def test_a_second_signal_during_the_report_step_aborts_at_once(tmp_path: Path, sig: signal.Signals) -> None:
    proc, run_dir, calls = _start(tmp_path, "report")
    _ticks_after(run_dir, 3, stream="report_tick")
    proc.send_signal(sig)
    _acknowledged(proc)
    ticks = run_dir.joinpath("record.jsonl").read_text().count('"stream":"report_tick"')
    _ticks_after(run_dir, ticks + 3, stream="report_tick")  # the first one did not stop the step
    proc.send_signal(sig)
    code, out, err = _finish(proc)
    assert code == 2, (out, err)
    run = load_run(run_dir)
    assert run.exit_status == "abort" and run.stop["reason"].startswith("aborted at once")
    assert "report" not in run.steps_completed  # cut short: it ends only on report.release, never sent
    assert "exciter.safe_state" in calls.read_text().splitlines()
