"""The ``rig`` command end to end on the simulated rig: help, bad configuration (exit 4 naming the field),
interlocks (exit 3, nothing sent, reason recorded), Ctrl-C mid-sweep (exit 2, exciter stopped)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import textwrap
import time
from importlib import resources
from pathlib import Path

import pytest

from rig.cli import main
from rig.record.catalogue import run_folders
from rig.record.writer import load_run

ROOT = Path(__file__).resolve().parents[1]
SIM_TOML = resources.files("rig").joinpath("data/sim.toml").read_text()

PROCEDURE = textwrap.dedent('''
    """A test procedure on the real station: moves the arm and runs the exciter."""
    import time
    from dataclasses import dataclass, field
    from rig.run.procedure import param

    NAME = "probe"

    @dataclass(frozen=True)
    class Parameters:
        x_mm: float = field(default=420.0, metadata=param(lo=-5000.0, hi=5000.0))
        frequency_hz: float = field(default=5.0, metadata=param(lo=0.0, hi=100.0))
        hold_s: float = field(default=0.0, metadata=param(lo=0.0, hi=600.0))

    def run(ctx, params):
        arm, exciter = ctx.device("robot"), ctx.device("exciter")
        with ctx.step("move") as step:
            result = arm.move_to([params.x_mm, 0.0, 300.0, 90.0, 0.0, 90.0])
            ctx.event("arm", {"commanded_pose": result.commanded_pose, "reported_pose": result.reported_pose,
                              "t_start_s": result.t_start_s, "t_end_s": result.t_end_s})
        with ctx.step("vibrate") as step:
            exciter.set_frequency(params.frequency_hz)
            ctx.event("exciter", {"frequency_hz": exciter.frequency_hz(), "setpoint_hz": params.frequency_hz,
                                  "status": "running"})
            print("VIBRATING", flush=True)
            end = time.monotonic() + params.hold_s
            while time.monotonic() < end:
                ctx.checkpoint()
                ctx.progress(None, "holding")
                time.sleep(0.02)
        return {"passed": True, "summary": "probe done"}
''')


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _bad_toml(tmp_path: Path, old: str, new: str) -> Path:
    assert old in SIM_TOML
    return _write(tmp_path, "rig.toml", SIM_TOML.replace(old, new, 1))


def test_help_everywhere(capsys: pytest.CaptureFixture[str]) -> None:
    for command in ([], ["certify"], ["run"], ["report"], ["check"], ["list"], ["mock"]):
        argv = [*command, "--help"]
        with pytest.raises(SystemExit) as info:
            main(argv)
        assert info.value.code == 0
    assert "usage: rig" in capsys.readouterr().out
    assert main([]) == 0


@pytest.mark.parametrize(("old", "new", "message"), [
    ("max_speed_mm_s = 500.0", 'max_speed_mm_s = "fast"',
     "limits.robot.max_speed_mm_s: 'fast' has the wrong type; allowed: a number"),
    ("[limits.exciter]\n", "[limits.exciter]\nmax_jerk = 3.0\n",
     "limits.exciter.max_jerk: unknown field; allowed in [limits.exciter]"),
    ("max_frequency_hz = 32.0", "max_frequency_hz = -32.0",
     "limits.exciter.max_frequency_hz: -32.0 is out of range; allowed: 0 < value ≤ 2000"),
    ('driver = "denso-bcap"', 'driver = "ur-rtde"',
     "devices.robot.driver: 'ur-rtde' is not allowed; allowed: 'denso-bcap'"),
])
def test_bad_rig_toml_exits_4_naming_the_field(tmp_path: Path, capsys: pytest.CaptureFixture[str], old: str,
                                               new: str, message: str) -> None:
    bad = _bad_toml(tmp_path, old, new)
    proc = _write(tmp_path, "probe.py", PROCEDURE)
    assert main(["run", str(proc), "--config", str(bad), "--runs-dir", str(tmp_path / "runs")]) == 4
    assert message in capsys.readouterr().err
    assert main(["check", "--config", str(bad), "--no-devices"]) == 4
    assert message in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()


def test_bad_parameter_and_unknown_procedure_exit_4(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    proc = _write(tmp_path, "probe.py", PROCEDURE)
    assert main(["run", str(proc), "--set", "frequency_hz=500", "--runs-dir", str(tmp_path)]) == 4
    assert "probe.frequency_hz: 500 is out of range; allowed: 0 ≤ value ≤ 100" in capsys.readouterr().err
    assert main(["run", "no-such-procedure", "--runs-dir", str(tmp_path)]) == 4
    assert "'no-such-procedure' is not a procedure" in capsys.readouterr().err
    assert main(["report", str(tmp_path / "nothing")]) == 4


def test_run_on_the_simulated_rig_passes(tmp_path: Path) -> None:
    proc = _write(tmp_path, "probe.py", PROCEDURE)
    assert main(["run", str(proc), "--runs-dir", str(tmp_path / "runs")]) == 0
    (run_dir,) = run_folders(tmp_path / "runs")
    run = load_run(run_dir)
    assert run.exit_status == "success" and run.steps_completed.keys() == {"move", "vibrate"}
    assert run.start["clock"] == "virtual" and run.start["devices"] == {"connected": False}
    assert run.event_documents("devices")[0]["data"]["simulated"]  # the station's snapshot, once connected
    assert run.events["arm"]["commanded_pose"][0] == [420.0, 0.0, 300.0, 90.0, 0.0, 90.0]
    assert any(re.fullmatch(r"exciter: (safe_state|stop)\(\) done", m) for m in run.logs["message"])
    assert (run_dir / "rig.log").stat().st_size > 0


@pytest.mark.parametrize(("setting", "reason"), [
    ("x_mm=900", "x_mm=900 outside the allowed range [150, 650]"),
    ("frequency_hz=40", "frequency 40 Hz exceeds the limit 32 Hz"),
])
def test_out_of_envelope_or_over_limit_exits_3_with_nothing_sent(tmp_path: Path, setting: str,
                                                                 reason: str) -> None:
    proc = _write(tmp_path, "probe.py", PROCEDURE)
    assert main(["run", str(proc), "--set", setting, "--runs-dir", str(tmp_path / "runs")]) == 3
    (run_dir,) = run_folders(tmp_path / "runs")
    run = load_run(run_dir)
    assert run.exit_status == "abort" and run.stop["outcome"] == "interlock" and reason in run.stop["reason"]
    assert reason in run.interlocks["reason"].iloc[0]
    if setting.startswith("x_mm"):
        assert "arm" not in run.events  # the move was refused before any byte was sent
    else:
        assert "exciter" not in run.events


def test_ctrl_c_mid_run_stops_the_exciter_and_exits_2(tmp_path: Path) -> None:
    proc_file = _write(tmp_path, "probe.py", PROCEDURE)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "rig.cli", "run", str(proc_file), "--set", "hold_s=60",
                             "--runs-dir", str(tmp_path / "runs")], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path)
    assert proc.stdout.readline().strip() == "VIBRATING"
    time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2, err
    (run_dir,) = run_folders(tmp_path / "runs")
    run = load_run(run_dir)
    assert run.exit_status == "abort" and run.stop["reason"] == "aborted by the operator (Ctrl-C)"
    messages = list(run.logs["message"])
    assert any(re.fullmatch(r"exciter: (safe_state|stop)\(\) done", m) for m in messages)
    assert any(re.fullmatch(r"robot: (safe_state|halt)\(\) done", m) for m in messages)
    assert "vibrate" not in run.steps_completed


def test_report_of_a_run_still_going_exits_4_and_writes_nothing(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    from rig.record.writer import RunRecord, record_is_open

    class Clock:
        is_virtual = True

        def now_s(self) -> float:
            return 0.0

    rec = RunRecord.create(tmp_path / "runs", "sweep", {}, {"station": {"simulated": True}}, Clock(),
                           versions={})
    try:
        before = sorted(p.relative_to(rec.run_dir) for p in rec.run_dir.rglob("*"))
        assert main(["report", str(rec.run_dir)]) == 4
        assert "is still running (a rig process has its record open)" in capsys.readouterr().err
        assert sorted(p.relative_to(rec.run_dir) for p in rec.run_dir.rglob("*")) == before
    finally:
        rec.close()
    assert not record_is_open(rec.run_dir)  # closed without a stop document: what a killed run leaves
