"""The stop document's ``safe_state``: what each device reports after the runner made it safe — read from
the device, so a drive that did not stop shows as running, a silent one as an error."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from drivers.roles import Assignment, Role
from rig.config.rig_config import default_config
from rig.record.writer import load_run
from rig.run.readback import read_back
from rig.run.runner import Runner
from rig.run.safety import SafeStateResult, make_safe
from tests.runner_dummy import make_module


class Clock:
    def __init__(self) -> None:
        self.t_s = 0.0

    def now_s(self) -> float:
        return self.t_s

    def sleep_s(self, d: float) -> None:
        self.t_s += d

    is_virtual = True


class Drive:
    """A VFD axis whose stop may be ignored (``obeys=False``: it keeps running at 12 Hz)."""

    def __init__(self, obeys: bool = True, answers: bool = True) -> None:
        self.hz, self.obeys, self.answers = 12.0, obeys, answers

    def command(self, what: str) -> None:  # what the dummy procedure sends
        pass

    def safe_state(self) -> None:
        if self.obeys:
            self.hz = 0.0

    def read_back(self) -> dict[str, Any]:
        if not self.answers:
            raise TimeoutError("no Modbus reply within 0.5 s")
        return {"frequency_hz": self.hz, "setpoint_hz": self.hz,
                "status": "stopped" if self.hz == 0 else "running"}

    def heartbeat(self, *, wait: bool = False) -> bool:
        return True

    def snapshot(self) -> dict[str, Any]:
        return {}


class Arm:
    """Position from the clock: still when halted, else drifting at ``speed_mm_s`` along x."""

    def __init__(self, clock: Clock, halts: bool = True) -> None:
        self.clock, self.halts, self.halted = clock, halts, False

    def safe_state(self) -> None:
        self.halted = self.halts

    def position(self) -> np.ndarray:
        x = 400.0 if self.halted else 400.0 + 50.0 * self.clock.now_s()
        return np.array([x, 0.0, 300.0, 90.0, 0.0, 90.0])

    def read_back(self) -> dict[str, Any]:  # as DensoArm.read_back: two reads 0.2 s apart
        first = self.position()
        self.clock.sleep_s(0.2)
        second = self.position()
        return {"pose": second.tolist(), "moved_mm": float(np.linalg.norm(second[:3] - first[:3]))}


class Generator:
    def safe_state(self) -> None:
        pass

    def read_back(self) -> dict[str, Any]:
        return {"output_on": False}


def _roster(devices: dict[str, Any]) -> list[Assignment]:
    roles = {"exciter": Role.VIBRATION_SOURCE, "rotor": Role.VIBRATION_SOURCE, "robot": Role.ARM,
             "generator": Role.GENERATOR}
    return [Assignment(n, roles[n], d) for n, d in devices.items()]


def test_read_back_reports_what_the_devices_say() -> None:
    clock = Clock()
    devices = {"exciter": Drive(), "rotor": Drive(obeys=False), "robot": Arm(clock), "generator": Generator()}
    results = make_safe(_roster(devices))
    assert [r.device for r in results] == ["generator", "exciter", "rotor", "robot"]  # by role
    state = read_back(_roster(devices), results)
    assert state["exciter"] == {"frequency_hz": 0.0, "setpoint_hz": 0.0, "status": "stopped"}
    assert state["rotor"] == {"frequency_hz": 12.0, "setpoint_hz": 12.0, "status": "running"}
    assert state["robot"]["moved_mm"] == 0.0 and state["robot"]["pose"][0] == 400.0
    assert state["generator"] == {"output_on": False}


def test_read_back_moving_arm_silent_drive_and_failed_safe_state() -> None:
    clock = Clock()
    devices = {"exciter": Drive(answers=False), "rotor": Drive(), "robot": Arm(clock, halts=False)}
    results = [SafeStateResult("exciter", "vibration_source"), SafeStateResult("robot", "arm"),
               SafeStateResult("rotor", "vibration_source", "ConnectionError: gone")]
    state = read_back(_roster(devices), results)
    assert state["exciter"] == {"error": "TimeoutError: no Modbus reply within 0.5 s"}
    assert np.isclose(state["robot"]["moved_mm"], 50.0 * 0.2)  # 50 mm/s for 0.2 s of the rig clock
    assert "rotor" not in state  # its safe-state failure is recorded in safe_state_failures instead


def test_runner_writes_the_read_back_into_the_stop_document(tmp_path: Path) -> None:
    import contextlib

    devices = {"exciter": Drive(obeys=False), "rotor": Drive()}

    @contextlib.contextmanager
    def factory(config: Any, clock: Any):
        yield SimpleNamespace(devices=devices, roster=lambda: _roster(devices), snapshot=dict,
                              check_interlocks=list)

    out = Runner(make_module("normal"), config=default_config(), station_factory=factory,
                 runs_dir=tmp_path / "runs", handle_signals=False).run({"ticks": 2, "tick_s": 0.0})
    assert out.exit_code == 0
    state = load_run(out.run_dir).stop["safe_state"]
    assert state == {"exciter": {"frequency_hz": 12.0, "setpoint_hz": 12.0, "status": "running"},
                     "rotor": {"frequency_hz": 0.0, "setpoint_hz": 0.0, "status": "stopped"}}
