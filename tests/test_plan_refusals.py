"""Whole-plan validation through the real ``rig`` command: a plan beyond any limit is refused with exit 4
before any device is connected, naming the parameter, its value, the limit and the ``rig.toml`` field.

On the built-in simulated rig (no run folder is created: the station, and its mock servers, never exist)
and on standalone mock servers (``rig mock robot|exciter|rotor|generator``, each its own process) driven
through a ``rig.toml``: the mocks count every request they receive and report the count when stopped —
after all the refusals below, each must have received none. ``--dry-run`` prints the plan and its checks.
"""

from __future__ import annotations

import os
import re
import select
import signal
import subprocess
import sys
from importlib import resources
from pathlib import Path

import pytest

from rig.cli import main
from tests.certify_support import write_config

ROOT = Path(__file__).resolve().parents[1]
SIM_TOML = resources.files("rig").joinpath("data/sim.toml").read_text()
MOCKS = ("robot", "exciter", "rotor", "generator")

# (procedure, settings, what the message must name) — one per limit; the plate is driven by the shaker
CASES = {
    "frequency": ("sweep", ["max_hz=300"],
                  ["sweep.max_hz = 300 Hz: frequency 300 Hz", "exceeds the exciter's limit 32 Hz",
                   "(limits.exciter.max_frequency_hz)"]),
    "amplitude": ("plate", ["shaker_amplitude_mm=6"],
                  ["plate.shaker_amplitude_mm = 6 mm: displacement 6 mm",
                   "exceeds the generator's limit 5 mm", "(limits.generator.max_displacement_mm)"]),
    "acceleration": ("plate", ["frequency_hz=80", "shaker_amplitude_mm=2"],  # (2π·80)²·2 mm = 505 m/s²
                     ["plate.frequency_hz = 80 Hz with plate.shaker_amplitude_mm = 2 mm",
                      "acceleration (2π·80 Hz)²·2 mm = 505.3", "exceeds the generator's limit 500 m/s²",
                      "(limits.generator.max_acceleration_m_s2)"]),
    "ramp rate": ("sweep", ["duration_s=5"],  # fig17: 1.4 × 29 Hz / 5 s = 8.1 Hz/s
                  ["sweep.duration_s = 5 s", "ramp rate 8.12 Hz/s exceeds the exciter's limit 2 Hz/s",
                   "(limits.exciter.max_ramp_rate_hz_per_s)"]),
    "speed": ("accuracy", ["speed_mm_s=4000"],
              ["accuracy.speed_mm_s = 4000 mm/s: speed 4000 mm/s exceeds the arm's limit 500 mm/s",
               "(limits.robot.max_speed_mm_s)"]),
    "envelope": ("calibrate", ["slide_positions_mm=[0.0, 300.0]"],
                 ["calibrate.slide_positions_mm = [0.0, 300.0] mm", "pose x = 720 mm",
                  "outside the arm's range [150, 650] mm (limits.robot.envelope_x_mm)"]),
    "rotor frequency": ("rotation", ["rotation_hz=20"],
                        ["rotation.rotation_hz = 20 Hz: frequency 20 Hz", "exceeds the rotor's limit 12 Hz",
                         "(limits.rotor.max_frequency_hz)"]),
    "certify, its last step": ("certify", ['preset="fast"', "sweep_max_hz=40"],
                               ["step sweep: certify.sweep_max_hz = 40 Hz: frequency 40 Hz",
                                "(limits.exciter.max_frequency_hz)"]),
}
HOME_POSE = "[700.0, 0.0, 300.0, 90.0, 0.0, 90.0]"
HOME_POSE_MESSAGE = ["devices.robot.home_pose", "x_mm=700 outside the allowed range [150, 650]",
                     "(limits.robot.envelope_x_mm)"]


def _shaker_plate(text: str) -> str:
    text, n = re.subn(r'(\[targets\.plate\]\nbody = )"exciter"', r'\1"shaker"', text)
    assert n == 1
    return text


def _home_pose(text: str, pose: str) -> str:
    text, n = re.subn(r"^home_pose = .*$", f"home_pose = {pose}", text, flags=re.M)
    assert n == 1
    return text


def _refuse(args: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    code = main(args)
    err = capsys.readouterr().err
    assert code == 4, err
    assert "Traceback" not in err
    return err


# ------------------------------------------------------------------------------------------- built-in rig
@pytest.mark.parametrize("limit", list(CASES))
def test_a_plan_beyond_a_limit_is_refused_on_the_built_in_rig(limit: str, tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    procedure, settings, expected = CASES[limit]
    config = write_config(tmp_path)
    config.write_text(_shaker_plate(config.read_text()))
    command = ["certify"] if procedure == "certify" else ["run", procedure]
    err = _refuse([*command, "--config", str(config), *(a for s in settings for a in ("--set", s))], capsys)
    assert all(e in err for e in expected), err
    assert "refused before connecting any device" in err
    assert not (tmp_path / "runs").exists()  # no run folder: the station (and its mock servers) never existed


def test_a_home_pose_outside_the_envelope_is_refused_on_the_built_in_rig(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = write_config(tmp_path)
    config.write_text(_home_pose(config.read_text(), HOME_POSE))
    err = _refuse(["run", "calibrate", "--config", str(config)], capsys)
    assert all(e in err for e in HOME_POSE_MESSAGE), err
    assert not (tmp_path / "runs").exists()


# ------------------------------------------------------------------------------------------- dry run
def test_dry_run_prints_the_whole_certification_plan_and_passes(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["certify", "--dry-run", "--set", 'preset="fast"']) == 0
    out = capsys.readouterr().out
    for step in ("calibrate", "sync", "accuracy_grid", "accuracy_iso9283", "accuracy_frame", "sweep"):
        assert re.search(rf"^  {step}\s+≈", out, re.M), out
    assert "exciter 2 → 12 Hz at 4 mm" in out and "arm 8 poses" in out  # the fast preset: 2³ grid, 2–12 Hz
    assert re.search(r"^  PASS  sweep\s+exciter\s+acceleration\s+22.74 m/s²\s+≤ 250 m/s²\s+margin \+227.3",
                     out, re.M), out
    assert "FAIL" not in out and "all 26 checks pass; nothing was connected" in out
    # sim.toml sets the band's criteria, which the fast preset cannot evaluate: the plan says what it costs
    left_out = (r"^  band\s+not timed\s+left out by this preset.*criteria\.band_amplitude_error_pct.* "
                r"stay NOT EVALUATED .*INCOMPLETE \(exit 1\); --set band=true adds the step$")
    assert re.search(left_out, out, re.M), out


def test_dry_run_of_the_full_preset_leaves_no_criterion_unevaluated(capsys: pytest.CaptureFixture[str]
                                                                    ) -> None:
    assert main(["certify", "--dry-run"]) == 0
    assert "NOT EVALUATED" not in capsys.readouterr().out


def test_dry_run_of_a_plan_beyond_the_limits_fails_with_exit_4(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", "sweep", "--dry-run", "--set", "max_hz=40"]) == 4
    captured = capsys.readouterr()
    failed = r"^  FAIL  sweep\s+exciter\s+frequency\s+40 Hz\s+≤ 32 Hz\s+margin -8 "
    assert re.search(failed, captured.out, re.M), captured.out
    assert re.search(r"^  PASS  calibrate\s+arm\s+speed", captured.out, re.M)
    assert "refused (exit 4): step sweep: sweep.max_hz = 40 Hz" in captured.err


def test_dry_run_needs_no_reachable_device(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # a real bench's configuration whose devices do not exist: the dry run still shows the plan
    config = tmp_path / "rig.toml"
    config.write_text(_bench_config({name: 9 + k for k, name in enumerate(MOCKS)}, tmp_path))
    assert main(["run", "rotation", "--dry-run", "--config", str(config)]) == 0
    assert "rotor 10 Hz at 60 mm" in capsys.readouterr().out


# ------------------------------------------------------------------------------------------- standalone mocks
def _bench_config(ports: dict[str, int], tmp_path: Path) -> str:
    """sim.toml turned into a bench: devices at tcp://127.0.0.1:<port>, video-file cameras, wall clock."""
    text = SIM_TOML.split("\n[sim]")[0]
    text = text.replace("simulated = true", "simulated = false")
    text = text.replace('clock = "virtual"', 'clock = "wall"')
    text = re.sub(r'^runs_dir = .*$', f'runs_dir = "{(tmp_path / "runs").as_posix()}"', text, flags=re.M)
    for name, port in ports.items():
        text, n = re.subn(rf'(\[devices\.{name}\][^\[]*?address = )"mock://\w+"',
                          rf'\g<1>"tcp://127.0.0.1:{port}"', text, flags=re.S)
        assert n == 1
    text = text.replace('driver = "sim"', f'driver = "file"\nsource = "{(tmp_path / "cam.avi").as_posix()}"')
    return _shaker_plate(text)


@pytest.fixture
def standalone_mocks() -> dict[str, subprocess.Popen]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    procs = {name: subprocess.Popen([sys.executable, "-m", "rig.cli", "mock", name, "--port", "0"],
                                    stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)
             for name in MOCKS}
    try:
        yield procs
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait(timeout=30)


def _port(proc: subprocess.Popen) -> int:
    ready, _, _ = select.select([proc.stdout], [], [], 300.0)  # a loaded machine starts a mock slowly
    assert ready, "the mock server printed nothing in 300 s"
    line = proc.stdout.readline()  # the serving line
    match = re.search(r"tcp://127\.0\.0\.1:(\d+)", line)
    assert match, line
    return int(match.group(1))


def _requests_received(proc: subprocess.Popen) -> int:
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=60)
    match = re.search(r"requests received: (\d+)", out)
    assert proc.returncode == 0 and match, out
    return int(match.group(1))


def test_refusals_send_nothing_to_standalone_mock_servers(standalone_mocks: dict[str, subprocess.Popen],
                                                          tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    ports = {name: _port(proc) for name, proc in standalone_mocks.items()}
    config = tmp_path / "rig.toml"
    config.write_text(_bench_config(ports, tmp_path))
    for procedure, settings, expected in CASES.values():
        command = ["certify"] if procedure == "certify" else ["run", procedure]
        sets = [a for s in settings for a in ("--set", s)]
        err = _refuse([*command, "--config", str(config), *sets], capsys)
        assert all(e in err for e in expected), err
    bad_home = tmp_path / "bad_home.toml"
    bad_home.write_text(_home_pose(config.read_text(), HOME_POSE))
    err = _refuse(["run", "calibrate", "--config", str(bad_home)], capsys)
    assert all(e in err for e in HOME_POSE_MESSAGE), err
    assert not (tmp_path / "runs").exists()
    received = {name: _requests_received(proc) for name, proc in standalone_mocks.items()}
    assert received == dict.fromkeys(MOCKS, 0)


def test_the_mock_servers_count_the_requests_they_receive() -> None:
    """The counters the refusal test relies on do count (one request each, over a real socket)."""
    import socket

    from pymodbus.client import ModbusTcpClient

    from drivers.mock.generator_instrument import GeneratorInstrument
    from drivers.mock.generator_server import GeneratorServer
    from drivers.mock.vfd_drive import DriveModel
    from drivers.mock.vfd_server import VfdServer
    from drivers.sim.clock import VirtualClock
    from drivers.sim.world import World

    world = World(VirtualClock(), seed=0)
    with VfdServer(DriveModel(world.exciter, world.clock), mode="tcp") as server:
        assert server.requests_received == 0
        client = ModbusTcpClient("127.0.0.1", port=server.port, timeout=5.0, retries=0)
        assert client.connect()
        try:
            client.read_holding_registers(0x2000, count=1, device_id=1)
        finally:
            client.close()
        assert server.requests_received == 1
    with GeneratorServer(GeneratorInstrument(world.shaker, world.clock), mode="tcp") as server:
        assert server.requests_received == 0
        with socket.create_connection(("127.0.0.1", server.port), timeout=5.0) as sock:
            sock.sendall(b"*IDN?\n")
            assert sock.makefile().readline()
        assert server.requests_received == 1


def test_calibrate_carries_out_the_plan_that_was_checked(tmp_path: Path) -> None:
    """What the runner checked is what runs: the commanded arm poses are the plan's, in order."""
    from procedures import calibrate
    from rig.config.rig_config import load_config
    from rig.record.catalogue import run_folders
    from rig.record.writer import load_run
    from rig.run.procedure import validate_parameters

    config = write_config(tmp_path)
    settings = {"frames_per_position": 2, "settle_s": 0.0}
    code = main(["run", "calibrate", "--config", str(config), *(a for k, v in settings.items()
                                                                for a in ("--set", f"{k}={v}"))])
    (run_dir,) = run_folders(tmp_path / "runs")
    run = load_run(run_dir)
    assert code in (0, 1), run.stop  # a verdict either way: the procedure ran to its end
    planned = calibrate.plan(validate_parameters(calibrate, settings), load_config(config))
    commanded = [tuple(p) for p in run.events["arm"]["commanded_pose"]]
    assert commanded == list(planned.moves("calibrate").poses) and len(commanded) == 6
