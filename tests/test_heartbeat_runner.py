"""The runner's watchdog with the real device heartbeats, on the simulated station (real drivers over
loopback/ptys to the protocol mocks, paced clock): a healthy run keeps beating through a long move; a mock
that stops answering or closes its connection trips the interlock → ``interlock`` document naming the
device and the reason, exit 3, and the safe state of every other device attempted."""

from __future__ import annotations

import re
import sys
import threading
import time
import types
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import pytest
from heartbeat_support import HEARTBEAT_TIMEOUT_S, run_body_on_sim_station
from runner_dummy import station_factory

from drivers.denso.motion import WaitSettings
from rig.cli import main as cli_main
from rig.config.rig_config import ConfigError, default_config, override
from rig.record.writer import load_run
from rig.run.runner import Runner

MOVE_TARGET = [420.0, 0.0, 300.0, 90.0, 0.0, 90.0]
PATIENT = {"station.heartbeat_timeout_s": 10.0,
           **{f"devices.{name}.timeout_s": 3.0 for name in ("exciter", "rotor", "generator")}}


def _run(tmp_path: Path, body: Callable[[Any, dict[str, Any]], None],
         **settings: Any) -> tuple[Any, Any, dict[str, Any]]:
    """Run ``body(ctx, servers)`` as the one step of a procedure on the simulated station."""
    return run_body_on_sim_station(tmp_path, body, **settings)


def _hold(ctx: Any, seconds: float) -> None:
    """Wait with checkpoints (wall time), as a procedure holding a vibration does."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        ctx.checkpoint()
        time.sleep(0.02)


def _done(run: Any) -> set[str]:
    done = (m for m in run.logs["message"] if re.fullmatch(r"\w+: (safe_state|halt)\(\) done", m))
    return {m.split(":")[0] for m in done}


def test_healthy_run_keeps_beating_through_a_long_move_and_an_idle_hold(tmp_path: Path) -> None:
    def body(ctx: Any, servers: dict[str, Any]) -> None:
        ctx.device("robot").wait = WaitSettings(wait_mode="blocking")  # a blocking Move: keep-alives only
        ctx.device("robot").move_to(MOVE_TARGET, speed_mm_s=17.5)  # 2 s wall: only keep-alives for it
        _hold(ctx, 2.0 * HEARTBEAT_TIMEOUT_S)  # every device idle: probed, answering

    out, run, seen = _run(tmp_path, body)
    assert out.exit_code == 0, out.reason
    assert run.interlocks.empty and run.exit_status == "success"
    devices = seen["station"].devices
    for name in ("robot", "exciter", "rotor", "generator"):
        monitor = devices[name].heartbeat_monitor
        assert monitor.probes_sent >= 2 and monitor.probe_errors == [], name
    assert devices["robot"].client.link.keepalives_seen >= 3


def test_exciter_that_stops_answering_trips_the_interlock_and_the_rest_is_made_safe(tmp_path: Path) -> None:
    def body(ctx: Any, servers: dict[str, Any]) -> None:
        ctx.device("exciter").set_frequency(2.0)
        servers["exciter"].inject("no_reply", count=None)  # executes every request, answers none
        _hold(ctx, 20.0)

    out, run, seen = _run(tmp_path, body)
    assert out.exit_code == 3 and out.outcome == "interlock", out.reason
    assert run.interlocks["device"].tolist() == ["exciter"]
    reason = run.interlocks["reason"].iloc[0]
    assert reason.startswith("lost heartbeat: DeviceLostError: exciter: lost: no reply for ")
    assert f"(limit {HEARTBEAT_TIMEOUT_S:g} s)" in reason and "last contact" in reason
    assert run.exit_status == "abort" and "interlock on exciter" in run.stop["reason"]
    assert "work" not in run.steps_completed
    assert {"robot", "rotor", "generator"} <= _done(run)  # every other device made safe
    failures = run.stop["safe_state_failures"]
    assert [f["device"] for f in failures] == ["exciter"]  # attempted, but nothing answers
    assert run.stop["heartbeats"]["exciter"] == "not probed (its safe state failed)"
    assert run.stop["heartbeats"]["rotor"] == "answering"
    world, clock = seen["station"].world, seen["station"].clock
    assert world.exciter.frequency_hz(clock.now_s() + 60.0) == 0.0  # the unanswered stop still reached it


@pytest.mark.parametrize("fault", ["no_reply", "disconnect"])
def test_rotor_lost_while_being_polled_is_the_interlock_with_its_document(tmp_path: Path, fault: str) -> None:
    """The procedure's own poll fails first (Modbus time-out), before the heartbeat limit: the runner's
    final probe of every device finds the rotor lost, so this is an interlock on the rotor with its
    document, like every other device fault — not a plain fault."""
    def body(ctx: Any, servers: dict[str, Any]) -> None:
        rotor = ctx.device("rotor")
        rotor.set_frequency(2.0)
        servers["rotor"].inject(fault, count=None)
        while True:
            rotor.read_sample()  # raises VfdCommunicationError after the 0.3 s × 2 attempts
            ctx.checkpoint()

    out, run, _seen = _run(tmp_path, body)
    assert out.exit_code == 3 and out.outcome == "interlock", out.reason
    assert run.interlocks["device"].tolist() == ["rotor"]
    assert run.interlocks["reason"].iloc[0].startswith("lost heartbeat: DeviceLostError: rotor: lost")
    assert {"robot", "exciter", "generator"} <= _done(run)


def test_interlock_during_a_blocking_move_halts_the_arm_on_a_fresh_link(tmp_path: Path) -> None:
    """The trip interrupts the procedure while it waits for a blocking Move: the controller still
    executes it and will not take a Robot_Halt on that connection (the reference server queues it, an
    RC8 may refuse it with E_BUSY_PROC), so the arm's safe state closes the connection — the controller
    ends that session, stopping the arm short of its target — and halts again on a fresh session."""
    def body(ctx: Any, servers: dict[str, Any]) -> None:
        ctx.device("robot").wait = WaitSettings(wait_mode="blocking")  # fallback for controllers without NEXT
        threading.Timer(0.3, servers["exciter"].inject, args=("no_reply",), kwargs={"count": None}).start()
        # 70 s virtual = 35 s wall: the halt must come before the arm arrives, and the loss is seen ~1.5 s
        # after the fault on an idle machine (a loaded one took > 5 s: the arm arrived at 7 mm/s)
        ctx.device("robot").move_to(MOVE_TARGET, speed_mm_s=1.0)

    out, run, seen = _run(tmp_path, body)
    assert out.exit_code == 3 and run.interlocks["device"].tolist() == ["exciter"], out.reason
    assert [f for f in run.stop["safe_state_failures"] if f["device"] == "robot"] == []
    report = seen["station"].devices["robot"].last_make_safe
    assert report.halted and report.fresh_link, report
    assert {"rotor", "generator"} <= _done(run)
    world, clock = seen["station"].world, seen["station"].clock
    assert not world.robot.is_moving(clock.now_s())
    assert world.robot.pose_at(clock.now_s())[0] < MOVE_TARGET[0] - 5.0  # stopped, not arrived


def test_arm_connection_closed_mid_move_is_the_interlock(tmp_path: Path) -> None:
    def body(ctx: Any, servers: dict[str, Any]) -> None:
        ctx.device("exciter").set_frequency(2.0)
        servers["robot"].faults.close_mid_move = True
        ctx.device("robot").move_to(MOVE_TARGET, speed_mm_s=17.5)

    # a closed link is lost at once, whatever the limit: the healthy devices get a limit and reply time-outs
    # a loaded host cannot reach (at load 12 the exciter's pty link once went 2 × 0.3 s without a reply and
    # the exciter, not the arm, was lost first)
    out, run, seen = _run(tmp_path, body, **PATIENT)
    assert out.exit_code == 3 and out.outcome == "interlock", out.reason
    assert run.interlocks["device"].tolist() == ["robot"]
    reason = run.interlocks["reason"].iloc[0]
    assert "robot: lost: link failed (b-CAP link closed during Robot_Move" in reason
    assert {"exciter", "rotor", "generator"} <= _done(run)
    # the arm was halted over a fresh connection, which answers: the state says so (the interlock and
    # its exit code stand); the latched "link closed" no longer reports the arm lost
    assert run.stop["heartbeats"] == {"robot": "recovered", "exciter": "answering", "rotor": "answering",
                                      "generator": "answering", "left": "answering", "right": "answering"}
    assert "robot answers again after it was lost (the interlock stands)" in list(run.logs["message"])
    world, clock = seen["station"].world, seen["station"].clock
    assert world.exciter.frequency_hz(clock.now_s() + 60.0) == 0.0


def test_generator_disconnected_mid_sweep_is_the_interlock(tmp_path: Path) -> None:
    def body(ctx: Any, servers: dict[str, Any]) -> None:
        timer = threading.Timer(0.5, servers["generator"].inject, args=("disconnect",))
        timer.start()
        try:
            ctx.device("generator").sweep(5.0, 10.0, 40.0, amplitude_mm=0.5)  # 10 s wall at rate 4
        finally:
            timer.cancel()

    # a closed link is lost at once: the healthy devices get limits a loaded host cannot reach
    out, run, _ = _run(tmp_path, body, rate=4.0, **PATIENT)
    assert out.exit_code == 3 and out.outcome == "interlock", out.reason
    assert "work" not in run.steps_completed  # the sweep was interrupted, not waited out
    assert run.interlocks["device"].tolist() == ["generator"]
    assert "generator: lost: link failed (SCPI link closed" in run.interlocks["reason"].iloc[0]
    assert {"robot", "exciter", "rotor"} <= _done(run)


def test_every_checkpoint_checks_the_heartbeats_not_only_the_watchdog(tmp_path: Path) -> None:
    calls = tmp_path / "calls.txt"

    def body(ctx: Any, servers: dict[str, Any]) -> None:
        ctx.station.devices["rotor"].alive = False
        ctx.checkpoint()
        raise AssertionError("the checkpoint did not trip")

    mod = types.ModuleType("checkpoint_probe")
    mod.NAME = "checkpoint_probe"

    @dataclass(frozen=True)
    class Parameters:
        pass

    mod.Parameters = Parameters
    mod.run = lambda ctx, params: body(ctx, {})
    runner = Runner(mod, config=default_config(), station_factory=station_factory(calls),
                    runs_dir=tmp_path / "runs", watchdog_period_s=600.0)  # the watchdog never polls
    out = runner.run({})
    assert out.exit_code == 3 and out.outcome == "interlock"
    run = load_run(out.run_dir)
    assert run.interlocks["device"].tolist() == ["rotor"]
    assert run.interlocks["reason"].iloc[0] == "lost heartbeat: device reports the link is down"


def test_heartbeat_timeout_is_validated_and_documented(capsys: Any) -> None:
    with pytest.raises(ConfigError, match=r"station\.heartbeat_timeout_s: 0\.1 is out of range; "
                                          r"allowed: 0\.5 ≤ value ≤ 60"):
        override(default_config(), "station.heartbeat_timeout_s", 0.1)
    with pytest.raises(ConfigError, match=r"station\.heartbeat_timeout_s: 'fast' has the wrong type"):
        override(default_config(), "station.heartbeat_timeout_s", "fast")
    assert default_config().station.heartbeat_timeout_s == 2.0
    assert cli_main(["check", "--schema"]) == 0
    out = capsys.readouterr().out
    assert "station.heartbeat_timeout_s: a number = 2.0  [0.5 ≤ value ≤ 60]\n    Wall seconds without" in out
