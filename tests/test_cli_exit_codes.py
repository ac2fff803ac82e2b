"""Exit codes mean one thing each (rig.cli.main owns the mapping): 4 for every kind of bad input — the
command line included —, 3 for an I/O fault that reaches main (one line, no traceback) and for one
that hits the record after its stop document, and a completed run refused on --resume as bad input."""

from __future__ import annotations

import errno
import textwrap
from pathlib import Path

import pytest

from rig.cli import main
from rig.record.writer import RunRecord, load_run

PROCEDURE = textwrap.dedent('''
    from dataclasses import dataclass

    NAME = "idle"

    @dataclass(frozen=True)
    class Parameters:
        pass

    def run(ctx, params):
        with ctx.step("idle"):
            ctx.event("note", {"ok": True})
        return {"passed": True, "summary": "nothing to do"}
''')


def _run_dirs(tmp_path: Path) -> list[Path]:
    """The run folders (the runs folder also holds the catalogue of runs)."""
    return [p for p in (tmp_path / "runs").iterdir() if p.is_dir()]


def _procedure(tmp_path: Path) -> Path:
    path = tmp_path / "idle.py"
    path.write_text(PROCEDURE)
    return path


@pytest.mark.parametrize("argv", [["frobnicate"], ["run", "--no-such-option"], ["report"],
                                  ["check", "--config"], ["mock", "toaster"]])
def test_command_line_errors_are_bad_input(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 4  # argparse's own 2 would read as "aborted"
    err = capsys.readouterr().err
    assert "usage: rig" in err and "error:" in err


def test_io_fault_writing_the_stop_document_exits_3_in_one_line(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    def full_disk(self: RunRecord, *args: object, **kwargs: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device", str(self.path))

    monkeypatch.setattr(RunRecord, "stop", full_disk)
    code = main(["run", str(_procedure(tmp_path)), "--runs-dir", str(tmp_path / "runs")])
    err = capsys.readouterr().err
    assert code == 3, err
    line = next(x for x in err.splitlines() if x.startswith("rig: I/O fault"))
    assert line.startswith("rig: I/O fault: [Errno 28] No space left on device: ") and "record.jsonl" in line
    assert "Traceback" not in err


def test_io_fault_closing_the_record_after_a_pass_is_a_fault_not_a_pass(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    real_close = RunRecord.close

    def close_fails(self: RunRecord) -> None:
        real_close(self)
        if self.stopped:
            raise OSError(errno.ENOSPC, "No space left on device", str(self.path))

    monkeypatch.setattr(RunRecord, "close", close_fails)
    code = main(["run", str(_procedure(tmp_path)), "--runs-dir", str(tmp_path / "runs")])
    err = capsys.readouterr().err
    assert code == 3, err
    assert "closing the record failed: OSError: [Errno 28] No space left on device" in err
    (run_dir,) = _run_dirs(tmp_path)
    assert load_run(run_dir).stop["exit_code"] == 0  # written before the failure; the exit says the rest


def test_resume_of_a_completed_run_is_refused_as_bad_input(tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    proc = _procedure(tmp_path)
    assert main(["run", str(proc), "--runs-dir", str(tmp_path / "runs")]) == 0
    (run_dir,) = _run_dirs(tmp_path)
    before = (run_dir / "record.jsonl").read_bytes()
    assert main(["run", str(proc), "--resume", str(run_dir)]) == 4
    assert "already completed successfully; nothing to resume" in capsys.readouterr().err
    assert (run_dir / "record.jsonl").read_bytes() == before  # untouched


@pytest.mark.parametrize(("certificate", "code", "outcome"), [
    ("PASS", 0, "pass"), ("FAIL", 1, "certificate_failed"), ("INCOMPLETE", 1, "incomplete")])
def test_the_printed_outcome_and_exit_code_agree_with_the_certificate(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], certificate: str, code: int,
        outcome: str) -> None:
    """``rig run accuracy`` used to print "pass (exit 0)" beside an INCOMPLETE certificate: a single
    procedure's certificate is INCOMPLETE (it evaluates only its own criteria), which is not a pass."""
    path = tmp_path / "issued.py"
    path.write_text(PROCEDURE.replace('NAME = "idle"', 'NAME = "issued"').replace(
        'return {"passed": True, "summary": "nothing to do"}',
        f'return {{"passed": {certificate == "PASS"}, "summary": "2/2 criteria evaluated pass", '
        f'"certificate_result": "{certificate}"}}'))
    assert main(["run", str(path), "--runs-dir", str(tmp_path / "runs")]) == code
    printed = capsys.readouterr()
    assert f"rig: issued: {outcome} (exit {code})" in (printed.err if code else printed.out)
    (run_dir,) = _run_dirs(tmp_path)
    stop = load_run(run_dir).stop
    assert stop["outcome"] == outcome and stop["verdict"] == {"PASS": "pass", "FAIL": "fail"}.get(
        certificate, "incomplete")


def test_disk_full_mid_run_every_device_is_made_safe_then_the_io_fault_surfaces(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A fault-injecting record: from the 10th tick on every write fails with ENOSPC. The procedure fails,
    every device is still made safe (nothing on disk comes first), and the I/O fault reaches the caller
    (main maps it to exit 3 in one line)."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from runner_dummy import make_module, station_factory

    from rig.config.rig_config import default_config
    from rig.run.runner import Runner

    real_write = RunRecord._write
    ticks = {"n": 0}

    def filling(self: RunRecord, doc_type: str, fields: dict, **kwargs: object) -> dict:
        if doc_type == "event" and fields.get("stream") == "tick":
            ticks["n"] += 1
        if ticks["n"] >= 10:
            raise OSError(errno.ENOSPC, "No space left on device", str(self.path))
        return real_write(self, doc_type, fields, **kwargs)

    monkeypatch.setattr(RunRecord, "_write", filling)
    calls = tmp_path / "calls.txt"
    runner = Runner(make_module("normal"), config=default_config(), station_factory=station_factory(calls),
                    runs_dir=tmp_path / "runs", handle_signals=False)
    with pytest.raises(OSError, match="No space left on device"):
        runner.run({"ticks": 30, "tick_s": 0.0})
    safe = [line for line in calls.read_text().splitlines() if line.endswith("safe_state")]
    assert safe == ["exciter.safe_state", "rotor.safe_state", "robot.safe_state", "left.safe_state"]
    assert calls.read_text().splitlines()[-1] == "station.closed"


def test_late_stop_signals_are_ignored_once_the_command_has_its_outcome(monkeypatch) -> None:
    """A second Ctrl-C arriving while the process exits (after an abort) cannot kill it with SIGINT (-2
    instead of 2): the console entry leaves stop signals ignored; an in-process caller gets its own back."""
    import signal as signal_module

    from rig.cli import main
    from rig.run.safety import STOP_SIGNALS

    before = {sig: signal_module.getsignal(sig) for sig in STOP_SIGNALS}
    try:
        assert main(["list"]) == 0
        assert {sig: signal_module.getsignal(sig) for sig in STOP_SIGNALS} == before
        monkeypatch.setattr("sys.argv", ["rig", "list"])
        assert main() == 0
        assert all(signal_module.getsignal(sig) == signal_module.SIG_IGN for sig in STOP_SIGNALS)
    finally:
        for sig, handler in before.items():
            signal_module.signal(sig, handler)
