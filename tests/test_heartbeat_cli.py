"""``rig run`` on the simulated rig with a procedure whose rotor drive stops answering mid-run: the
heartbeat trips the interlock, the command exits 3, the record holds the interlock and the stops."""

from __future__ import annotations

import re
import textwrap
from importlib import resources
from pathlib import Path

from rig.cli import main
from rig.record.catalogue import run_folders
from rig.record.writer import load_run

SIM_TOML = resources.files("rig").joinpath("data/sim.toml").read_text()

PROCEDURE = textwrap.dedent('''
    """Spin the rotor, then its drive goes silent (the mock's fault injection) while the run holds."""
    import time
    from dataclasses import dataclass

    NAME = "silent_rotor"

    @dataclass(frozen=True)
    class Parameters:
        pass

    def run(ctx, params):
        rotor = ctx.device("rotor")
        with ctx.step("spin"):
            rotor.set_rotation_hz(2.0)
            server = next(c.__self__ for label, c in ctx.station._closers if label == "rotor mock server")
            server.inject("no_reply", count=None)
            end = time.monotonic() + 20.0
            while time.monotonic() < end:
                ctx.checkpoint()
                time.sleep(0.02)
        return {"passed": True, "summary": "not reached"}
''')


def test_rig_run_exits_3_when_a_drive_stops_answering(tmp_path: Path, capsys) -> None:
    text = SIM_TOML.replace('clock = "virtual"\n', 'clock = "virtual"\nheartbeat_timeout_s = 1.0\n', 1)
    text = text.replace("ramp_rate_hz_per_s = 2.0\n", "ramp_rate_hz_per_s = 2.0\ntimeout_s = 0.3\n", 1)
    assert text.count("heartbeat_timeout_s") == 1 and "timeout_s = 0.3" in text
    (tmp_path / "rig.toml").write_text(text)
    (tmp_path / "silent_rotor.py").write_text(PROCEDURE)
    code = main(["run", str(tmp_path / "silent_rotor.py"), "--config", str(tmp_path / "rig.toml"),
                 "--runs-dir", str(tmp_path / "runs")])
    assert code == 3, capsys.readouterr().err
    (run_dir,) = run_folders(tmp_path / "runs")
    run = load_run(run_dir)
    assert run.stop["outcome"] == "interlock" and run.stop["exit_code"] == 3
    assert run.interlocks["device"].tolist() == ["rotor"]
    assert re.match(r"lost heartbeat: DeviceLostError: rotor: lost: no reply for \d+\.\d\d s; last contact "
                    r"\d+\.\d\d s ago \(limit 1 s\)", run.interlocks["reason"].iloc[0])
    assert run.start["rig"]["station"]["heartbeat_timeout_s"] == 1.0
    messages = list(run.logs["message"])
    for device in ("exciter", "generator"):
        assert f"{device}: safe_state() done" in messages
    assert any(re.fullmatch(r"robot: (safe_state|halt)\(\) done", m) for m in messages)
    assert [f["device"] for f in run.stop["safe_state_failures"]] == ["rotor"]
