"""A dummy procedure and fake devices for the runner's own tests (they test the runner, not a driver).

Run as a script: ``python runner_dummy.py RUNS_DIR CALLS_FILE MODE [--resume RUN_DIR]``; prints the run folder
once the procedure is inside step ``b`` and exits with the runner's exit code. Devices append every call to
CALLS_FILE (one line each, flushed), so the parent test can see what was done even after a kill.

MODE: ``normal`` (step b ends after 30 ticks), ``forever`` (step b checkpoints but never ends),
``deaf`` (step b never checkpoints: only a second Ctrl-C can stop it), ``heartbeat`` (the exciter's
heartbeat fails after 5 ticks, while step b never checkpoints), ``report`` (as ``normal``, then a step
``report`` without a checkpoint that ticks until the file ``report.release`` appears in the working folder).
"""

from __future__ import annotations

import contextlib
import sys
import time
import types
from dataclasses import dataclass, field
from pathlib import Path

from drivers.roles import Assignment, Role
from rig.config.rig_config import default_config
from rig.run.procedure import param
from rig.run.runner import Runner


class FakeDevice:
    def __init__(self, name: str, calls: Path, *, fail_safe: bool = False) -> None:
        self.name = name
        self.calls = calls
        self.fail_safe = fail_safe
        self.alive = True

    def _log(self, what: str) -> None:
        with open(self.calls, "a") as fh:
            fh.write(f"{self.name}.{what}\n")
            fh.flush()

    def command(self, what: str) -> None:
        self._log(what)

    def safe_state(self) -> None:
        self._log("safe_state")
        if self.fail_safe:
            raise ConnectionError(f"{self.name} does not answer")

    def heartbeat(self, *, wait: bool = False) -> bool:
        return self.alive

    def read_back(self) -> dict:
        return {"calls": "see CALLS_FILE"}

    def snapshot(self) -> dict:
        return {"type": "fake"}


ROLES = {"robot": Role.ARM, "exciter": Role.VIBRATION_SOURCE, "rotor": Role.VIBRATION_SOURCE,
         "left": Role.CAMERA}


class FakeStation:
    """A station of fake devices; ``roles`` maps each name to its role (default :data:`ROLES`)."""

    def __init__(self, calls: Path, roles: dict[str, Role] | None = None, **fail: bool) -> None:
        self.roles = dict(ROLES if roles is None else roles)
        self.devices = {n: FakeDevice(n, calls, fail_safe=fail.get(n, False)) for n in self.roles}
        self.calls = calls

    def roster(self) -> list[Assignment]:
        return [Assignment(n, self.roles[n], d) for n, d in self.devices.items()]

    def snapshot(self) -> dict:
        return {"devices": sorted(self.devices)}

    def check_interlocks(self) -> list[tuple[str, str]]:
        return []


def station_factory(calls: Path, **fail: bool):
    @contextlib.contextmanager
    def factory(config, clock):
        station = FakeStation(calls, **fail)
        try:
            yield station
        finally:
            with open(calls, "a") as fh:
                fh.write("station.closed\n")
    return factory


def make_module(mode: str, announce: bool = False) -> types.ModuleType:
    mod = types.ModuleType("dummy_procedure")
    mod.NAME = "dummy"

    @dataclass(frozen=True)
    class Parameters:
        ticks: int = field(default=30, metadata=param(lo=1, hi=100000))
        tick_s: float = field(default=0.01, metadata=param(lo=0.0, hi=1.0))

    def run(ctx, params):
        exciter = ctx.device("exciter")
        with ctx.step("a") as step:
            if not step.skipped:
                exciter.command("run_a")
                ctx.event("exciter", {"setpoint_hz": 5.0})
                step.output(ctx.write_json("a.json", {"value": 1}))
        with ctx.step("b") as step:
            if not step.skipped:
                if announce:
                    print(ctx.run_dir, flush=True)
                i = 0
                while mode in ("forever", "deaf", "heartbeat") or i < params.ticks:
                    ctx.event("tick", {"i": i})
                    exciter.command(f"tick{i}")
                    if mode == "heartbeat" and i == 5:
                        exciter.alive = False
                    if mode in {"normal", "forever"}:
                        ctx.checkpoint()
                    time.sleep(params.tick_s)
                    i += 1
        if mode == "report":  # a last step without checkpoints, like the report: it ticks until the test
            with ctx.step("report"):  # creates report.release in the working folder (or 10⁵ ticks)
                for i in range(100_000):
                    ctx.event("report_tick", {"i": i})
                    if Path("report.release").exists():
                        break
                    time.sleep(params.tick_s)
        return {"passed": True, "summary": "dummy done"}

    mod.Parameters = Parameters
    mod.run = run
    return mod


def main(argv: list[str]) -> int:
    runs_dir, calls, mode = Path(argv[0]), Path(argv[1]), argv[2]
    resume = argv[4] if len(argv) > 4 and argv[3] == "--resume" else None
    runner = Runner(make_module(mode, announce=True), config=default_config(),
                    station_factory=station_factory(calls), runs_dir=runs_dir, watchdog_period_s=0.05)
    outcome = runner.run({}, resume=resume)
    print(f"OUTCOME {outcome.exit_code} {outcome.outcome} {outcome.reason}", flush=True)
    return outcome.exit_code


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
