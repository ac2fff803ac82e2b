"""The mock RC8 controller's state machine: b-CAP function calls → results, on a simulated robot body.

No I/O here: :class:`ControllerState.execute` takes a function ID and decoded arguments and returns an
:class:`Outcome`; the server (``bcap_server.py``) handles framing, keep-alives, faults and timing.

Controller error codes for the cases no public source documents (unreachable pose, motor off, ...) are
**chosen by this mock** and kept in ``bcap_args.MOCK_ERRORS``; they are not RC8 firmware codes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from drivers.denso import hresult as hr
from drivers.denso.variant import (
    EMPTY,
    VT_ARRAY,
    VT_BOOL,
    VT_BSTR,
    VT_I4,
    VT_R4,
    VT_R8,
    VT_UI4,
    VT_VARIANT,
    Variant,
)
from drivers.mock import vp6242
from drivers.mock.bcap_args import (
    JOINT_LIMIT,
    MOTOR_OFF,
    OUT_OF_REACH,
    ROBOT_BUSY,
    VALUE_RETURNING,
    CallFailed,
    _number,
    _numbers,
    _text,
    error_description,
    parse_move_option,
    parse_pose,
)

ROBOT_NAMES = ("Arm", "Arm0", "", "ARM")


class RobotBodyLike(Protocol):
    def pose_at(self, t_s: float) -> np.ndarray: ...
    def move(self, t_start_s: float, target_pose: Any, speed_mm_s: float, accel_mm_s2: float,
             linear: bool = True) -> float: ...
    def halt(self, t_s: float) -> None: ...
    def is_moving(self, t_s: float) -> bool: ...


class ClockLike(Protocol):
    def now_s(self) -> float: ...


@dataclass
class Outcome:
    """Result of one call. ``motion_end_s``: a blocking Move whose reply must wait until that time."""

    hresult: int
    args: list[Variant] = field(default_factory=list)
    motion_end_s: float | None = None


class ControllerState:
    """One controller; method ``_f<N>`` handles b-CAP function ID N (bcap.md §6).

    ``full_speed_mm_s`` / ``full_accel_mm_s2`` are what 100 % speed / acceleration mean on this controller.
    """

    def __init__(self, robot: RobotBodyLike, clock: ClockLike, *, full_speed_mm_s: float = 1000.0,
                 full_accel_mm_s2: float = 5000.0) -> None:
        self.robot = robot
        self.clock = clock
        self.full_speed_mm_s = full_speed_mm_s
        self.full_accel_mm_s2 = full_accel_mm_s2
        self.handles: dict[int, tuple[str, str]] = {}
        self._next_handle = 1
        self.wdt_ms: int | None = None
        self.invoke_timeout_ms = 180_000
        self.arm_taken = False
        self.motor_on = False
        self.speed_percent = 100.0
        self.accel_percent = 100.0
        self.ext_speed_percent = 100.0
        self.ext_accel_percent = 100.0
        self.fig = 5
        self.errors: list[tuple[int, str]] = []
        self.move_error: int | None = None  # fault injection: HRESULT returned by every Move
        self.moves: list[dict[str, Any]] = []  # log of accepted moves (for tests and the CLI)

    # ------------------------------------------------------------------------------------- dispatch
    def execute(self, function_id: int, args: list[Variant]) -> Outcome:
        handler: Callable[[list[Variant]], Outcome] | None = getattr(
            self, f"_f{function_id}", None)
        try:
            if handler is None:
                raise CallFailed(hr.E_NOTIMPL, f"function {function_id} is not implemented by the mock")
            return handler(args)
        except CallFailed as failed:
            if hr.is_controller_error(failed.code):
                self.errors.append((failed.code, failed.message or error_description(failed.code)))
            return Outcome(failed.code, [EMPTY] if function_id in VALUE_RETURNING else [])
        except IndexError:
            return Outcome(hr.E_INVALIDARG, [EMPTY] if function_id in VALUE_RETURNING else [])

    def _new_handle(self, kind: str, name: str) -> Variant:
        handle = self._next_handle
        self._next_handle += 1
        self.handles[handle] = (kind, name)
        return Variant(VT_UI4, handle)

    def _handle(self, v: Variant, kind: str) -> int:
        if v.vt not in (VT_I4, VT_UI4) or hr.to_unsigned(v.value) not in self.handles:
            raise CallFailed(hr.E_HANDLE, f"{kind} handle {v.value!r}")
        handle = hr.to_unsigned(v.value)
        if self.handles[handle][0] != kind:
            raise CallFailed(hr.E_HANDLE, f"handle {handle} is a {self.handles[handle][0]}, not a {kind}")
        return handle

    def release_all(self) -> None:
        """Connection lost or Service_Stop: stop the robot, motor off, drop every handle."""
        now = self.clock.now_s()
        if self.robot.is_moving(now):
            self.robot.halt(now)
        self.handles.clear()
        self.arm_taken = self.motor_on = False

    # ------------------------------------------------------------------------------------- service
    def _f1(self, args: list[Variant]) -> Outcome:  # Service_Start
        option = _text(args[0], "option") if args else ""
        for part in filter(None, (p.strip() for p in option.split(","))):
            key, _, value = part.partition("=")
            if key.strip().upper() in ("WDT", "INVOKETIMEOUT"):
                if not value.strip().isdigit():
                    raise CallFailed(hr.E_INVALIDARG, f"Service_Start option {part!r}")
                if key.strip().upper() == "WDT":
                    self.wdt_ms = max(80, int(value))
                else:
                    self.invoke_timeout_ms = int(value)
        return Outcome(hr.S_OK)

    def _f2(self, args: list[Variant]) -> Outcome:  # Service_Stop
        self.release_all()
        self.wdt_ms = None
        return Outcome(hr.S_OK)

    # ---------------------------------------------------------------------------------- controller
    def _f3(self, args: list[Variant]) -> Outcome:  # Controller_Connect
        provider = _text(args[1], "provider")
        if provider not in ("CaoProv.DENSO.VRC", ""):
            raise CallFailed(hr.E_CAO_OBJECT_NOTFOUND, f"provider {provider!r}")
        return Outcome(hr.S_OK, [self._new_handle("controller", _text(args[0], "name"))])

    def _f4(self, args: list[Variant]) -> Outcome:  # Controller_Disconnect
        del self.handles[self._handle(args[0], "controller")]
        return Outcome(hr.S_OK)

    def _f7(self, args: list[Variant]) -> Outcome:  # Controller_GetRobot
        self._handle(args[0], "controller")
        name = _text(args[1], "robot name")
        if name not in ROBOT_NAMES:
            raise CallFailed(hr.E_CAO_OBJECT_NOTFOUND, f"robot {name!r}")
        return Outcome(hr.S_OK, [self._new_handle("robot", name)])

    def _f8(self, args: list[Variant]) -> Outcome:  # Controller_GetTask
        self._handle(args[0], "controller")
        return Outcome(hr.S_OK, [self._new_handle("task", _text(args[1], "task name"))])

    def _get_variable(self, args: list[Variant], owner: str, kind: str) -> Outcome:
        """Controller_/Robot_GetVariable: a ``kind`` handle on a variable of the ``owner`` handle args[0]."""
        self._handle(args[0], owner)
        name = _text(args[1], "variable name")
        if name.upper() not in self._variables(owner):
            raise CallFailed(hr.E_CAO_OBJECT_NOTFOUND, f"{owner} variable {name!r}")
        return Outcome(hr.S_OK, [self._new_handle(kind, name.upper())])

    def _f9(self, args: list[Variant]) -> Outcome:  # Controller_GetVariable
        return self._get_variable(args, "controller", "cvar")

    def _f13(self, args: list[Variant]) -> Outcome:  # Controller_GetRobotNames
        self._handle(args[0], "controller")
        return Outcome(hr.S_OK, [Variant(VT_ARRAY | VT_BSTR, ["Arm0"])])

    def _f17(self, args: list[Variant]) -> Outcome:  # Controller_Execute
        self._handle(args[0], "controller")
        command = _text(args[1], "command")
        param = args[2] if len(args) > 2 else EMPTY
        if command == "ClearError":
            self.errors.clear()
            return Outcome(hr.S_OK, [EMPTY])
        if command == "GetCurErrorCount":
            return Outcome(hr.S_OK, [Variant(VT_I4, len(self.errors))])
        if command == "GetCurErrorInfo":
            index = int(_number(param, "error index")) if param.vt else 0
            if not 0 <= index < len(self.errors):
                raise CallFailed(hr.E_INVALIDARG, f"error index {index}")
            code, message = self.errors[index]
            return Outcome(hr.S_OK, [Variant(VT_ARRAY | VT_VARIANT, [Variant(VT_I4, hr.to_signed(code)),
                                                                     Variant(VT_BSTR, message)])])
        if command == "GetErrorDescription":
            return Outcome(hr.S_OK, [Variant(VT_BSTR, error_description(int(_number(param, "code"))))])
        raise CallFailed(hr.E_INVALID_CMD_NAME, f"Controller_Execute {command!r}")

    # -------------------------------------------------------------------------------------- robot
    def _f62(self, args: list[Variant]) -> Outcome:  # Robot_GetVariable
        return self._get_variable(args, "robot", "rvar")

    def cur_pos(self) -> list[float]:
        return [*(float(v) for v in self.robot.pose_at(self.clock.now_s())), float(self.fig)]

    def _f64(self, args: list[Variant]) -> Outcome:  # Robot_Execute
        self._handle(args[0], "robot")
        command = _text(args[1], "command")
        param = args[2] if len(args) > 2 else EMPTY
        if command == "TakeArm":
            values = _numbers(param, "TakeArm")
            if len(values) > 1 and values[1] == 0:
                self.speed_percent = self.accel_percent = 100.0
            self.arm_taken = True
        elif command == "GiveArm":
            self.arm_taken = False
        elif command == "Motor":
            values = _numbers(param, "Motor")
            if not values:
                raise CallFailed(hr.E_INVALIDARG, "Motor needs [on, noWait]")
            if not self.arm_taken:
                raise CallFailed(hr.E_ACCESSDENIED, "Motor: TakeArm first")
            self.motor_on = values[0] != 0
        elif command == "ExtSpeed":
            self._ext_speed(_numbers(param, "ExtSpeed"))
        elif command == "CurPos":
            return Outcome(hr.S_OK, [Variant(VT_ARRAY | VT_R8, self.cur_pos())])
        else:
            raise CallFailed(hr.E_INVALID_CMD_NAME, f"Robot_Execute {command!r}")
        return Outcome(hr.S_OK, [EMPTY])

    def _ext_speed(self, values: list[float]) -> None:
        if not values or len(values) > 3:
            raise CallFailed(hr.E_INVALIDARG, "ExtSpeed takes speed[, accel[, decel]]")
        speed = values[0]
        if speed != -1:
            if not 0 < speed <= 100:
                raise CallFailed(hr.E_INVALIDARG, f"ExtSpeed {speed}: 0 < speed <= 100")
            self.ext_speed_percent = speed
        accel = values[1] if len(values) > 1 else -2
        if accel == -2:
            self.ext_accel_percent = self.ext_speed_percent ** 2 / 100.0
        elif accel != -1:
            if not 0 < accel <= 100:
                raise CallFailed(hr.E_INVALIDARG, f"ExtSpeed accel {accel}: 0 < accel <= 100")
            self.ext_accel_percent = accel

    def _f70(self, args: list[Variant]) -> Outcome:  # Robot_Halt
        self._handle(args[0], "robot")
        now = self.clock.now_s()
        if self.robot.is_moving(now):
            self.robot.halt(now)
        return Outcome(hr.S_OK)

    _f71 = _f70  # Robot_Hold: stops like Halt (the mock does not resume a held move)

    def _f76(self, args: list[Variant]) -> Outcome:  # Robot_Unhold
        self._handle(args[0], "robot")
        return Outcome(hr.S_OK)

    def _f72(self, args: list[Variant]) -> Outcome:  # Robot_Move
        self._handle(args[0], "robot")
        comp = int(_number(args[1], "comp"))
        if comp not in (1, 2):
            raise CallFailed(hr.E_NOTIMPL, f"comp={comp}: the mock implements 1 (PTP) and 2 (linear)")
        pose, fig = parse_pose(args[2])
        option = parse_move_option(_text(args[3], "option") if len(args) > 3 and args[3].vt else "")
        if self.move_error is not None:
            raise CallFailed(self.move_error, error_description(self.move_error))
        if not self.arm_taken:
            raise CallFailed(hr.E_ACCESSDENIED, "Move: TakeArm first")
        if not self.motor_on:
            raise CallFailed(MOTOR_OFF)
        reach = vp6242.solve(pose)
        if reach.violation:
            code = OUT_OF_REACH if "reach" in reach.violation else JOINT_LIMIT
            raise CallFailed(code, f"{error_description(code)}: {reach.violation}")
        speed_pct = float(option.get("SPEED", self.speed_percent))
        accel_pct = float(option.get("ACCEL", self.accel_percent))
        if not (0 < speed_pct <= 100 and 0 < accel_pct <= 100):
            raise CallFailed(hr.E_INVALIDARG, f"SPEED={speed_pct}, ACCEL={accel_pct}: must be in (0, 100]")
        speed = self.full_speed_mm_s * speed_pct / 100 * self.ext_speed_percent / 100
        accel = self.full_accel_mm_s2 * accel_pct / 100 * self.ext_accel_percent / 100
        now = self.clock.now_s()
        if self.robot.is_moving(now):
            raise CallFailed(ROBOT_BUSY)
        t_end = self.robot.move(now, np.array(pose), speed, accel, linear=comp == 2)
        if fig is not None and fig >= 0:
            self.fig = fig
        self.moves.append({"t_start_s": now, "t_end_s": t_end, "pose": pose, "speed_mm_s": speed,
                           "linear": comp == 2})
        return Outcome(hr.S_OK, [], None if option.get("NEXT") else t_end)

    def _f74(self, args: list[Variant]) -> Outcome:  # Robot_Speed
        self._handle(args[0], "robot")
        speed = _number(args[2], "speed")
        if not 0 < speed <= 100:
            raise CallFailed(hr.E_INVALIDARG, f"Robot_Speed {speed}: 0 < speed <= 100")
        self.speed_percent = speed
        return Outcome(hr.S_OK)

    def _f84(self, args: list[Variant]) -> Outcome:  # Robot_Release
        del self.handles[self._handle(args[0], "robot")]
        return Outcome(hr.S_OK)

    # ------------------------------------------------------------------------------ tasks, variables
    def _f88(self, args: list[Variant]) -> Outcome:  # Task_Start
        self._handle(args[0], "task")
        return Outcome(hr.S_OK)

    _f89 = _f88  # Task_Stop

    def _f99(self, args: list[Variant]) -> Outcome:  # Task_Release
        del self.handles[self._handle(args[0], "task")]
        return Outcome(hr.S_OK)

    def _variables(self, owner: str) -> dict[str, Callable[[], Variant]]:
        if owner == "controller":
            last_error = hr.to_signed(self.errors[-1][0]) if self.errors else 0
            return {"@ERROR_CODE": lambda: Variant(VT_I4, last_error),
                    "@MODE": lambda: Variant(VT_I4, 3),
                    "@VERSION": lambda: Variant(VT_BSTR, "rig mock RC8 (b-CAP)"),
                    "@EMERGENCY_STOP": lambda: Variant(VT_BOOL, False)}
        return {"@CURRENT_POSITION": lambda: Variant(VT_ARRAY | VT_R8, self.cur_pos()),
                "@SERVO_ON": lambda: Variant(VT_BOOL, self.motor_on),
                "@EXTSPEED": lambda: Variant(VT_R4, self.ext_speed_percent),
                "@BUSY_STATUS": lambda: Variant(VT_BOOL, bool(self.robot.is_moving(self.clock.now_s())))}

    def _variable(self, v: Variant) -> tuple[str, str]:
        handle = hr.to_unsigned(v.value) if v.vt in (VT_I4, VT_UI4) else -1
        kind, name = self.handles.get(handle, ("", ""))
        if kind not in ("cvar", "rvar"):
            raise CallFailed(hr.E_HANDLE, f"variable handle {v.value!r}")
        return ("controller" if kind == "cvar" else "robot"), name

    def _f101(self, args: list[Variant]) -> Outcome:  # Variable_GetValue
        owner, name = self._variable(args[0])
        return Outcome(hr.S_OK, [self._variables(owner)[name]()])

    def _f102(self, args: list[Variant]) -> Outcome:  # Variable_PutValue
        _owner, name = self._variable(args[0])
        if name == "@SERVO_ON":
            if not self.arm_taken:
                raise CallFailed(hr.E_ACCESSDENIED, "@SERVO_ON: TakeArm first")
            self.motor_on = bool(args[1].value)
        elif name == "@EXTSPEED":
            self._ext_speed([_number(args[1], "@EXTSPEED")])
        else:
            raise CallFailed(hr.E_ACCESSDENIED, f"{name} is read-only")
        return Outcome(hr.S_OK)

    def _f111(self, args: list[Variant]) -> Outcome:  # Variable_Release
        self._variable(args[0])
        del self.handles[hr.to_unsigned(args[0].value)]
        return Outcome(hr.S_OK)

