"""The runner in process: validation, verdicts, interlocks, faults, cleanup always, the record it leaves."""

from __future__ import annotations

import contextlib
import sys
import types
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from runner_dummy import FakeStation, make_module, station_factory

from drivers.exciter.limits import MotionLimits
from rig.config.rig_config import default_config
from rig.record.writer import load_run
from rig.run.procedure import ParameterError, param, parse_set, validate_parameters
from rig.run.runner import Runner


def _runner(tmp_path: Path, module: types.ModuleType, **kw: Any) -> tuple[Runner, Path]:
    calls = tmp_path / "calls.txt"
    factory = kw.pop("factory", None) or station_factory(calls, **kw.pop("fail", {}))
    return Runner(module, config=default_config(), station_factory=factory, runs_dir=tmp_path / "runs",
                  watchdog_period_s=0.02, **kw), calls


def _calls(path: Path) -> list[str]:
    return path.read_text().splitlines() if path.exists() else []


def _module(body: Any, name: str = "custom") -> types.ModuleType:
    mod = types.ModuleType(name)
    mod.NAME = name

    @dataclass(frozen=True)
    class Parameters:
        level: float = field(default=1.0, metadata=param(lo=0.0, hi=10.0))
        mode: str = field(default="a", metadata=param(choices=("a", "b")))

    mod.Parameters = Parameters
    mod.run = body
    return mod


def test_success_records_everything_and_makes_every_device_safe(tmp_path: Path) -> None:
    runner, calls = _runner(tmp_path, make_module("normal"))
    out = runner.run({"ticks": 3, "tick_s": 0.0})
    assert (out.exit_code, out.exit_status, out.outcome) == (0, "success", "pass")
    run = load_run(out.run_dir)
    assert run.stop["exit_code"] == 0 and run.stop["verdict"] == "pass" and run.stop["result"]["summary"]
    assert run.start["parameters"] == {"ticks": 3, "tick_s": 0.0}
    assert run.start["devices"] == {"connected": False}  # start is written before the station is built
    assert run.event_documents("devices")[0]["data"] == {"devices": ["exciter", "left", "robot", "rotor"]}
    assert run.start["rig"]["criteria"]["position_max_mm"] == 1.5
    assert run.steps_completed == {"a": ["a.json"], "b": []}
    assert run.events["tick"]["i"].tolist() == [0, 1, 2] and set(run.events["tick"]["step"]) == {"b"}
    c = _calls(calls)
    safe = [x for x in c if x.endswith("safe_state")]
    # vibration sources first, then the arm, then the rest; the station closed after that
    assert safe == ["exciter.safe_state", "rotor.safe_state", "robot.safe_state", "left.safe_state"]
    assert c[-1] == "station.closed" and (out.run_dir / "rig.log").read_text().count("ended: pass") == 1


def test_bad_parameters_exit_4_before_anything_is_built(tmp_path: Path) -> None:
    runner, calls = _runner(tmp_path, make_module("normal"))
    out = runner.run({"ticks": 0})
    assert out.exit_code == 4 and out.run_dir is None and "dummy.ticks: 0 is out of range" in out.reason
    assert _calls(calls) == [] and not (tmp_path / "runs").exists()
    out = runner.run({"tiks": 5})
    assert out.exit_code == 4 and "dummy.tiks: unknown field; allowed in [dummy]: tick_s, ticks" in out.reason


def test_parameter_validation_and_set_parsing() -> None:
    mod = _module(lambda ctx, p: None)
    assert parse_set(["level=2.5", "mode=b", "flag=true", "xs=[1, 2]", "s=hello world"]) == {
        "level": 2.5, "mode": "b", "flag": True, "xs": [1, 2], "s": "hello world"}
    assert validate_parameters(mod, parse_set(["level=3"])).level == 3.0
    with pytest.raises(ParameterError, match=r"custom\.mode: 'c' is not allowed; allowed: 'a', 'b'"):
        validate_parameters(mod, {"mode": "c"})
    with pytest.raises(ParameterError, match=r"custom\.level: 'x' has the wrong type; allowed: a number"):
        validate_parameters(mod, {"level": "x"})
    with pytest.raises(ParameterError, match="is not KEY=VALUE"):
        parse_set(["level"])


def test_certificate_failure_exits_1(tmp_path: Path) -> None:
    verdict = {"passed": False, "summary": "2 of 9 criteria failed"}
    runner, _ = _runner(tmp_path, _module(lambda ctx, p: verdict))
    out = runner.run()
    assert out.exit_code == 1 and out.outcome == "certificate_failed"
    run = load_run(out.run_dir)
    assert run.exit_status == "success" and run.stop["verdict"] == "fail"
    assert run.stop["reason"] == "2 of 9 criteria failed"


def test_procedure_exception_is_a_fault_exit_3_with_traceback_logged(tmp_path: Path) -> None:
    def body(ctx: Any, p: Any) -> None:
        ctx.device("exciter").command("go")
        raise ZeroDivisionError("oops")

    runner, calls = _runner(tmp_path, _module(body))
    out = runner.run()
    assert out.exit_code == 3 and out.outcome == "fault" and out.reason == "ZeroDivisionError: oops"
    assert load_run(out.run_dir).stop["exit_status"] == "fail"
    assert "Traceback" in (out.run_dir / "rig.log").read_text()
    assert "exciter.safe_state" in _calls(calls)


def test_a_procedures_warnings_are_in_the_record_not_only_in_rig_log(tmp_path: Path) -> None:
    def body(ctx: Any, p: Any) -> None:
        ctx.log.info("routine")
        ctx.log.warning("sync: %d frames lost; recording again (2 of 3)", 36)

    runner, _ = _runner(tmp_path, _module(body))
    out = runner.run()
    assert out.exit_code == 0
    logs = load_run(out.run_dir).logs
    mine = logs[logs["message"].str.startswith("procedures.custom: ")]
    assert mine[["level", "message"]].values.tolist() == [
        ["warning", "procedures.custom: sync: 36 frames lost; recording again (2 of 3)"]]
    assert "recording again" in (out.run_dir / "rig.log").read_text()


def test_missing_device_is_bad_input_exit_4(tmp_path: Path) -> None:
    runner, _ = _runner(tmp_path, _module(lambda ctx, p: ctx.device("generator")))
    out = runner.run()
    assert out.exit_code == 4 and "procedure needs [devices.generator]" in out.reason


def test_limit_refused_by_a_driver_is_an_interlock_exit_3(tmp_path: Path) -> None:
    limits = MotionLimits(max_frequency_hz=30.0, max_displacement_mm=10.0, max_acceleration_m_s2=250.0,
                          max_ramp_rate_hz_per_s=2.0)

    def body(ctx: Any, p: Any) -> None:
        limits.check_point(31.0, 4.0, context="exciter")  # what a driver does before sending
        ctx.device("exciter").command("never sent")

    runner, calls = _runner(tmp_path, _module(body))
    out = runner.run()
    assert out.exit_code == 3 and out.outcome == "interlock"
    run = load_run(out.run_dir)
    assert run.exit_status == "abort" and "frequency 31 Hz exceeds the limit 30 Hz" in run.stop["reason"]
    assert "frequency 31 Hz exceeds the limit 30 Hz" in run.interlocks["reason"].iloc[0]
    assert "exciter.never sent" not in _calls(calls) and "exciter.safe_state" in _calls(calls)


def test_watchdog_interrupts_a_blocked_procedure_at_once(tmp_path: Path) -> None:
    """The heartbeat is lost while the procedure sits in a call that never checkpoints."""
    runner, calls = _runner(tmp_path, make_module("heartbeat"))
    out = runner.run({"tick_s": 0.01})  # step b never ends by itself: only the interlock ends the run
    assert out.exit_code == 3 and out.outcome == "interlock"
    run = load_run(out.run_dir)
    assert run.interlocks["device"].tolist() == ["exciter"]
    assert run.interlocks["reason"].iloc[0] == "lost heartbeat: device reports the link is down"
    assert run.stop["reason"] == ("interlock: interlock on exciter: lost heartbeat: "
                                  "device reports the link is down")
    assert "b" not in run.steps_completed and "exciter.safe_state" in _calls(calls)


def test_station_interlock_check_trips_at_the_checkpoint(tmp_path: Path) -> None:
    calls = tmp_path / "calls.txt"

    class Guarded(FakeStation):
        armed = False

        def check_interlocks(self) -> list[tuple[str, str]]:
            return [("robot", "pose (900, 0, 300) mm outside the envelope")] if self.armed else []

    @contextlib.contextmanager
    def factory(config: Any, clock: Any):
        yield Guarded(calls)

    def body(ctx: Any, p: Any) -> None:
        ctx.station.armed = True
        ctx.checkpoint()
        ctx.device("robot").command("moved anyway")

    runner, _ = _runner(tmp_path, _module(body), factory=factory)
    out = runner.run()
    assert out.exit_code == 3 and "outside the envelope" in out.reason
    assert "robot.moved anyway" not in _calls(calls)
    assert load_run(out.run_dir).interlocks["device"].tolist() == ["robot"]


def test_every_device_is_attempted_when_one_fails_to_stop(tmp_path: Path) -> None:
    runner, calls = _runner(tmp_path, make_module("normal"), fail={"exciter": True})
    out = runner.run({"ticks": 1})
    assert out.exit_code == 3 and out.outcome == "fault"
    assert "exciter: ConnectionError: exciter does not answer" in out.reason
    assert [x for x in _calls(calls) if x.endswith("safe_state")] == [
        "exciter.safe_state", "rotor.safe_state", "robot.safe_state", "left.safe_state"]
    run = load_run(out.run_dir)
    assert run.stop["safe_state_failures"][0]["device"] == "exciter"
    assert any("safe state of exciter" in m for m in run.logs["message"])


def test_station_that_cannot_be_built_exits_3_and_records_why(tmp_path: Path) -> None:
    @contextlib.contextmanager
    def factory(config: Any, clock: Any):
        raise ConnectionRefusedError("tcp://10.0.0.5:5007 refused")
        yield

    runner, _ = _runner(tmp_path, make_module("normal"), factory=factory)
    out = runner.run()
    assert out.exit_code == 3 and out.outcome == "fault" and "refused" in out.reason
    run = load_run(out.run_dir)  # the run folder exists: start (no device snapshot), then stop with why
    assert run.start["devices"] == {"connected": False} and run.start["parameters"]["ticks"] == 30
    assert run.stop["exit_status"] == "fail" and run.stop["exit_code"] == 3
    assert run.stop["reason"] == ("could not build the station: ConnectionRefusedError: "
                                  "tcp://10.0.0.5:5007 refused")
    assert "devices" not in run.events and not run.steps_completed
    log_text = (out.run_dir / "rig.log").read_text()
    assert "Traceback" in log_text and "ConnectionRefusedError" in log_text  # the traceback, in the run's log


def test_request_abort_stops_at_the_next_checkpoint(tmp_path: Path) -> None:
    holder: dict[str, Runner] = {}

    def body(ctx: Any, p: Any) -> None:
        for i in range(100):
            if i == 3:
                holder["r"].request_abort("operator pressed stop")
            ctx.checkpoint()
            ctx.event("tick", {"i": i})

    runner, _ = _runner(tmp_path, _module(body))
    holder["r"] = runner
    out = runner.run()
    assert out.exit_code == 2 and out.reason == "operator pressed stop"
    assert load_run(out.run_dir).events["tick"]["i"].tolist() == [0, 1, 2]
