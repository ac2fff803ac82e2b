"""The mock RC8 controller's state machine: b-CAP function calls → results, on a simulated robot body.

No I/O here: :class:`ControllerState.execute` takes a function ID and decoded arguments and returns an
:class:`Outcome`; the server (``bcap_server.py``) handles framing, keep-alives, faults and timing.

Controller error codes for the cases no public source documents (unreachable pose, motor off, ...) are
**chosen by this mock** and kept in ``bcap_args.MOCK_ERRORS``; they are not RC8 firmware codes. Every
call gets an HRESULT: an argument the handlers did not foresee ends in E_FAIL, never in an exception.
Resources are bounded: 1,000 objects (E_MAX_OBJECT beyond, as the reference server), the newest 100
controller errors, the newest 10,000 accepted moves. Each behaviour and its source: ``docs/bcap_mock.md``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Protocol, TypedDict, TypeVar

import numpy as np
from numpy.typing import NDArray

from drivers.clock import Clock
from drivers.mock import bcap_wire as w
from drivers.mock import vp6242
from drivers.mock.bcap_args import (
    JOINT_LIMIT,
    MOTOR_OFF,
    OUT_OF_REACH,
    ROBOT_BUSY,
    VALUE_RETURNING,
    CallFailed,
    _integer,
    _number,
    _numbers,
    _text,
    error_description,
    parse_move_option,
    parse_pose,
)

log = logging.getLogger(__name__)

ROBOT_NAMES = ("Arm", "Arm0", "", "ARM")
MAX_OBJECTS = 1000            # reference server BCAP_OBJECT_MAX
MIN_WDT_MS = 80               # reference server MIN_WDT_INTERVAL (also the InvokeTimeout minimum)
DEFAULT_INVOKE_TIMEOUT_MS = 180_000  # reference server INIT_EXEC_TIMEOUT
MAX_ERRORS = 100              # our choice: the controller keeps the newest errors
MAX_MOVES = 10_000            # our choice: the accepted-move log for tests and the CLI


_T = TypeVar("_T")


class AcceptedMove(TypedDict):
    """One Move the controller accepted (times on the twin's clock)."""

    t_start_s: float
    t_end_s: float
    pose: list[float]  # x, y, z mm; rx, ry, rz deg
    speed_mm_s: float
    accel_mm_s2: float  # acceleration and deceleration: 100 % × ACCEL % × ExtSpeed accel %
    linear: bool


class History(list[_T]):
    """A list that keeps only its newest ``limit`` items (``dropped`` counts the others)."""

    def __init__(self, limit: int, items: Iterable[_T] = ()) -> None:
        super().__init__(items)
        self.limit = limit
        self.dropped = 0

    def append(self, item: _T) -> None:
        super().append(item)
        if len(self) > self.limit:
            excess = len(self) - self.limit
            del self[:excess]
            self.dropped += excess


class RobotBodyLike(Protocol):
    def pose_at(self, t_s: float) -> NDArray[np.float64]: ...
    def move(self, t_start_s: float, target_pose: NDArray[np.float64], speed_mm_s: float, accel_mm_s2: float,
             linear: bool = True) -> float: ...
    def halt(self, t_s: float) -> None: ...
    def is_moving(self, t_s: float) -> bool: ...


@dataclass
class Outcome:
    """Result of one call. ``motion_end_s``: a blocking Move whose reply must wait until that time."""

    hresult: int
    args: list[w.Value] = field(default_factory=list)
    motion_end_s: float | None = None


class ControllerState:
    """One controller; method ``_f<N>`` handles b-CAP function ID N (bcap.md §6).

    ``full_speed_mm_s`` / ``full_accel_mm_s2`` are what 100 % speed / acceleration mean on this controller.
    """

    def __init__(self, robot: RobotBodyLike, clock: Clock, *, full_speed_mm_s: float = 1000.0,
                 full_accel_mm_s2: float = 5000.0) -> None:
        self.robot = robot
        self.clock = clock
        self.full_speed_mm_s = full_speed_mm_s
        self.full_accel_mm_s2 = full_accel_mm_s2
        self.handles: dict[int, tuple[str, str]] = {}
        self._next_handle = 1
        self.wdt_ms: int | None = None  # None: INFINITE, no keep-alives (reference default)
        self.invoke_timeout_ms = DEFAULT_INVOKE_TIMEOUT_MS
        self.arm_taken = False
        self.motor_on = False
        self.speed_percent = 100.0
        self.accel_percent = 100.0
        self.ext_speed_percent = 100.0
        self.ext_accel_percent = 100.0
        self.fig = 5
        self.errors: History[tuple[int, str]] = History(MAX_ERRORS)  # (code, message), oldest first
        self.move_error: int | None = None  # fault injection: HRESULT returned by every Move
        self.moves: History[AcceptedMove] = History(MAX_MOVES)  # for tests and the CLI
        # b-CAP function ID → its handler; any other ID is answered E_NOTIMPL
        self._handlers: dict[int, Callable[[list[w.Value]], Outcome]] = {
            1: self._f1, 2: self._f2, 3: self._f3, 4: self._f4, 7: self._f7, 8: self._f8, 9: self._f9,
            13: self._f13, 17: self._f17, 62: self._f62, 64: self._f64, 70: self._f70, 72: self._f72,
            74: self._f74, 76: self._f76, 84: self._f84, 88: self._f88, 99: self._f99, 101: self._f101,
            102: self._f102, 111: self._f111,
        }

    # ------------------------------------------------------------------------------------- dispatch
    def execute(self, function_id: int, args: list[w.Value]) -> Outcome:
        handler = self._handlers.get(function_id)
        try:
            if handler is None:
                raise CallFailed(w.E_NOTIMPL, f"function {function_id} is not implemented by the mock")
            return handler(args)
        except CallFailed as failed:
            if w.controller_error(failed.code):
                self.errors.append((failed.code, failed.message or error_description(failed.code)))
            bare = failed.code == w.E_MAX_OBJECT  # refused before the call: no argument (reference)
            return Outcome(failed.code, [w.EMPTY] if function_id in VALUE_RETURNING and not bare else [])
        except IndexError:
            return Outcome(w.E_INVALIDARG, [w.EMPTY] if function_id in VALUE_RETURNING else [])
        except Exception:  # a case no handler foresaw: the client still gets an HRESULT
            log.exception("function %d failed inside the mock", function_id)
            return Outcome(w.E_FAIL, [w.EMPTY] if function_id in VALUE_RETURNING else [])

    def _new_handle(self, kind: str, name: str) -> w.Value:
        """A new object handle (VT_UI4, 1..2^31-1, never one in use); E_MAX_OBJECT beyond MAX_OBJECTS."""
        if len(self.handles) >= MAX_OBJECTS:
            raise CallFailed(w.E_MAX_OBJECT, f"{MAX_OBJECTS} objects are open; release some first")
        while self._next_handle in self.handles:
            self._next_handle = self._next_handle % 0x7FFFFFFF + 1
        handle = self._next_handle
        self._next_handle = handle % 0x7FFFFFFF + 1
        self.handles[handle] = (kind, name)
        return w.Value(w.UI4, handle)

    def _handle(self, v: w.Value, kind: str) -> int:
        if v.vt not in (w.I4, w.UI4) or w.unsigned(v.value) not in self.handles:
            raise CallFailed(w.E_HANDLE, f"{kind} handle {v.value!r}")
        handle = w.unsigned(v.value)
        if self.handles[handle][0] != kind:
            raise CallFailed(w.E_HANDLE, f"handle {handle} is a {self.handles[handle][0]}, not a {kind}")
        return handle

    def release_all(self) -> None:
        """Connection lost or Service_Stop: stop the robot, motor off, drop every handle, and the
        Service_Start options back to their defaults (the next client starts as a new connection)."""
        now = self.clock.now_s()
        if self.robot.is_moving(now):
            self.robot.halt(now)
        self.handles.clear()
        self.arm_taken = self.motor_on = False
        self.wdt_ms, self.invoke_timeout_ms = None, DEFAULT_INVOKE_TIMEOUT_MS

    # ------------------------------------------------------------------------------------- service
    def _f1(self, args: list[w.Value]) -> Outcome:  # Service_Start
        """Every Service_Start sets both options, to their defaults when absent (reference server);
        a value below 80 ms is refused with E_INVALIDARG and changes nothing."""
        option = _text(args[0], "option") if args and args[0].vt else ""
        values: dict[str, int | None] = {"WDT": None, "INVOKETIMEOUT": DEFAULT_INVOKE_TIMEOUT_MS}
        for part in filter(None, (p.strip() for p in option.split(","))):
            key, _, value = part.partition("=")
            key = key.strip().upper()
            if key in values:
                if not value.strip().isdigit() or int(value) > 0xFFFFFFFF:
                    raise CallFailed(w.E_INVALIDARG, f"Service_Start option {part!r}: not a number of ms")
                if int(value) < MIN_WDT_MS:
                    raise CallFailed(w.E_INVALIDARG, f"Service_Start option {part!r}: below {MIN_WDT_MS} ms")
                values[key] = int(value)
        self.wdt_ms, self.invoke_timeout_ms = values["WDT"], int(values["INVOKETIMEOUT"] or 0)
        return Outcome(w.S_OK)

    def _f2(self, args: list[w.Value]) -> Outcome:  # Service_Stop
        self.release_all()
        return Outcome(w.S_OK)

    # ---------------------------------------------------------------------------------- controller
    def _f3(self, args: list[w.Value]) -> Outcome:  # Controller_Connect
        provider = _text(args[1], "provider")
        if provider not in ("CaoProv.DENSO.VRC", ""):
            raise CallFailed(w.E_CAO_OBJECT_NOTFOUND, f"provider {provider!r}")
        return Outcome(w.S_OK, [self._new_handle("controller", _text(args[0], "name"))])

    def _f4(self, args: list[w.Value]) -> Outcome:  # Controller_Disconnect
        del self.handles[self._handle(args[0], "controller")]
        return Outcome(w.S_OK)

    def _f7(self, args: list[w.Value]) -> Outcome:  # Controller_GetRobot
        self._handle(args[0], "controller")
        name = _text(args[1], "robot name")
        if name not in ROBOT_NAMES:
            raise CallFailed(w.E_CAO_OBJECT_NOTFOUND, f"robot {name!r}")
        return Outcome(w.S_OK, [self._new_handle("robot", name)])

    def _f8(self, args: list[w.Value]) -> Outcome:  # Controller_GetTask
        self._handle(args[0], "controller")
        return Outcome(w.S_OK, [self._new_handle("task", _text(args[1], "task name"))])

    def _get_variable(self, args: list[w.Value], owner: str, kind: str) -> Outcome:
        """Controller_/Robot_GetVariable: a ``kind`` handle on a variable of the ``owner`` handle args[0]."""
        self._handle(args[0], owner)
        name = _text(args[1], "variable name")
        if name.upper() not in self._variables(owner):
            raise CallFailed(w.E_CAO_OBJECT_NOTFOUND, f"{owner} variable {name!r}")
        return Outcome(w.S_OK, [self._new_handle(kind, name.upper())])

    def _f9(self, args: list[w.Value]) -> Outcome:  # Controller_GetVariable
        return self._get_variable(args, "controller", "cvar")

    def _f13(self, args: list[w.Value]) -> Outcome:  # Controller_GetRobotNames
        self._handle(args[0], "controller")
        return Outcome(w.S_OK, [w.Value(w.ARRAY | w.BSTR, ["Arm0"])])

    def _f17(self, args: list[w.Value]) -> Outcome:  # Controller_Execute
        self._handle(args[0], "controller")
        command = _text(args[1], "command")
        param = args[2] if len(args) > 2 else w.EMPTY
        if command == "ClearError":
            self.errors.clear()
            return Outcome(w.S_OK, [w.EMPTY])
        if command == "GetCurErrorCount":
            return Outcome(w.S_OK, [w.Value(w.I4, len(self.errors))])
        if command == "GetCurErrorInfo":
            index = _integer(param, "error index") if param.vt else 0
            if not 0 <= index < len(self.errors):
                raise CallFailed(w.E_INVALIDARG, f"error index {index}")
            code, message = self.errors[index]
            return Outcome(w.S_OK, [w.Value(w.ARRAY | w.VARIANT, [w.Value(w.I4, w.signed(code)),
                                                                     w.Value(w.BSTR, message)])])
        if command == "GetErrorDescription":
            return Outcome(w.S_OK, [w.Value(w.BSTR, error_description(_integer(param, "code")))])
        raise CallFailed(w.E_INVALID_CMD_NAME, f"Controller_Execute {command!r}")

    # -------------------------------------------------------------------------------------- robot
    def _f62(self, args: list[w.Value]) -> Outcome:  # Robot_GetVariable
        return self._get_variable(args, "robot", "rvar")

    def cur_pos(self) -> list[float]:
        return [*(float(v) for v in self.robot.pose_at(self.clock.now_s())), float(self.fig)]

    def cur_jnt(self) -> list[float]:
        """J1..J6 in degrees from the coarse model of ``vp6242`` (J1, J2, J3, J5); J4 is reported 0 and
        J6 as rz − J1 (our choice: the model does not resolve the wrist roll)."""
        pose = self.robot.pose_at(self.clock.now_s())
        reach = vp6242.solve(pose)
        return [reach.j1_deg, reach.j2_deg, reach.j3_deg, 0.0, reach.j5_deg, float(pose[5]) - reach.j1_deg]

    def _f64(self, args: list[w.Value]) -> Outcome:  # Robot_Execute
        self._handle(args[0], "robot")
        command = _text(args[1], "command")
        param = args[2] if len(args) > 2 else w.EMPTY
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
                raise CallFailed(w.E_INVALIDARG, "Motor needs [on, noWait]")
            if not self.arm_taken:
                raise CallFailed(w.E_ACCESSDENIED, "Motor: TakeArm first")
            self.motor_on = values[0] != 0
        elif command == "ExtSpeed":
            self._ext_speed(_numbers(param, "ExtSpeed"))
        elif command == "CurPos":
            return Outcome(w.S_OK, [w.Value(w.ARRAY | w.R8, self.cur_pos())])
        elif command == "CurJnt":
            return Outcome(w.S_OK, [w.Value(w.ARRAY | w.R8, self.cur_jnt())])
        elif command == "HighCurJntEx":
            stamp_ms = self.clock.now_s() * 1000.0
            return Outcome(w.S_OK, [w.Value(w.ARRAY | w.R8, [stamp_ms, *self.cur_jnt()])])
        else:
            raise CallFailed(w.E_INVALID_CMD_NAME, f"Robot_Execute {command!r}")
        return Outcome(w.S_OK, [w.EMPTY])

    def _ext_speed(self, values: list[float]) -> None:
        if not values or len(values) > 3:
            raise CallFailed(w.E_INVALIDARG, "ExtSpeed takes speed[, accel[, decel]]")
        speed = values[0]
        if speed != -1:
            if not 0 < speed <= 100:
                raise CallFailed(w.E_INVALIDARG, f"ExtSpeed {speed}: 0 < speed <= 100")
            self.ext_speed_percent = speed
        accel = values[1] if len(values) > 1 else -2
        if accel == -2:
            self.ext_accel_percent = self.ext_speed_percent ** 2 / 100.0
        elif accel != -1:
            if not 0 < accel <= 100:
                raise CallFailed(w.E_INVALIDARG, f"ExtSpeed accel {accel}: 0 < accel <= 100")
            self.ext_accel_percent = accel

    def _f70(self, args: list[w.Value]) -> Outcome:  # Robot_Halt
        self._handle(args[0], "robot")
        now = self.clock.now_s()
        if self.robot.is_moving(now):
            self.robot.halt(now)
        return Outcome(w.S_OK)

    _f71 = _f70  # Robot_Hold: stops like Halt (the mock does not resume a held move)

    def _f76(self, args: list[w.Value]) -> Outcome:  # Robot_Unhold
        self._handle(args[0], "robot")
        return Outcome(w.S_OK)

    def _f72(self, args: list[w.Value]) -> Outcome:  # Robot_Move
        self._handle(args[0], "robot")
        comp = int(_number(args[1], "comp"))
        if comp not in (1, 2):
            raise CallFailed(w.E_NOTIMPL, f"comp={comp}: the mock implements 1 (PTP) and 2 (linear)")
        pose, fig = parse_pose(args[2])
        option = parse_move_option(_text(args[3], "option") if len(args) > 3 and args[3].vt else "")
        if self.move_error is not None:
            raise CallFailed(self.move_error, error_description(self.move_error))
        if not self.arm_taken:
            raise CallFailed(w.E_ACCESSDENIED, "Move: TakeArm first")
        if not self.motor_on:
            raise CallFailed(MOTOR_OFF)
        reach = vp6242.solve(pose)
        if reach.violation:
            code = OUT_OF_REACH if "reach" in reach.violation else JOINT_LIMIT
            raise CallFailed(code, f"{error_description(code)}: {reach.violation}")
        speed_pct = float(option.get("SPEED", self.speed_percent))
        accel_pct = float(option.get("ACCEL", self.accel_percent))
        if not (0 < speed_pct <= 100 and 0 < accel_pct <= 100):
            raise CallFailed(w.E_INVALIDARG, f"SPEED={speed_pct}, ACCEL={accel_pct}: must be in (0, 100]")
        speed = self.full_speed_mm_s * speed_pct / 100 * self.ext_speed_percent / 100
        accel = self.full_accel_mm_s2 * accel_pct / 100 * self.ext_accel_percent / 100
        now = self.clock.now_s()
        if self.robot.is_moving(now):
            raise CallFailed(ROBOT_BUSY)
        t_end = self.robot.move(now, np.array(pose), speed, accel, linear=comp == 2)
        if fig is not None and fig >= 0:
            self.fig = fig
        self.moves.append({"t_start_s": now, "t_end_s": t_end, "pose": pose, "speed_mm_s": speed,
                           "accel_mm_s2": accel, "linear": comp == 2})
        return Outcome(w.S_OK, [], None if option.get("NEXT") else t_end)

    def _f74(self, args: list[w.Value]) -> Outcome:  # Robot_Speed
        self._handle(args[0], "robot")
        speed = _number(args[2], "speed")
        if not 0 < speed <= 100:
            raise CallFailed(w.E_INVALIDARG, f"Robot_Speed {speed}: 0 < speed <= 100")
        self.speed_percent = speed
        return Outcome(w.S_OK)

    def _f84(self, args: list[w.Value]) -> Outcome:  # Robot_Release
        del self.handles[self._handle(args[0], "robot")]
        return Outcome(w.S_OK)

    # ------------------------------------------------------------------------------ tasks, variables
    def _f88(self, args: list[w.Value]) -> Outcome:  # Task_Start
        self._handle(args[0], "task")
        return Outcome(w.S_OK)

    _f89 = _f88  # Task_Stop

    def _f99(self, args: list[w.Value]) -> Outcome:  # Task_Release
        del self.handles[self._handle(args[0], "task")]
        return Outcome(w.S_OK)

    def _variables(self, owner: str) -> dict[str, Callable[[], w.Value]]:
        if owner == "controller":
            last_error = w.signed(self.errors[-1][0]) if self.errors else 0
            return {"@ERROR_CODE": lambda: w.Value(w.I4, last_error),
                    "@MODE": lambda: w.Value(w.I4, 3),
                    "@VERSION": lambda: w.Value(w.BSTR, "rig mock RC8 (b-CAP)"),
                    "@EMERGENCY_STOP": lambda: w.Value(w.BOOL, False)}
        return {"@CURRENT_POSITION": lambda: w.Value(w.ARRAY | w.R8, self.cur_pos()),
                "@SERVO_ON": lambda: w.Value(w.BOOL, self.motor_on),
                "@CURRENT_ANGLE": lambda: w.Value(w.ARRAY | w.R8, self.cur_jnt()),
                "@EXTSPEED": lambda: w.Value(w.R4, self.ext_speed_percent),
                "@BUSY_STATUS": lambda: w.Value(w.BOOL, bool(self.robot.is_moving(self.clock.now_s())))}

    def _variable(self, v: w.Value) -> tuple[str, str]:
        handle = w.unsigned(v.value) if v.vt in (w.I4, w.UI4) else -1
        kind, name = self.handles.get(handle, ("", ""))
        if kind not in ("cvar", "rvar"):
            raise CallFailed(w.E_HANDLE, f"variable handle {v.value!r}")
        return ("controller" if kind == "cvar" else "robot"), name

    def _f101(self, args: list[w.Value]) -> Outcome:  # Variable_GetValue
        owner, name = self._variable(args[0])
        return Outcome(w.S_OK, [self._variables(owner)[name]()])

    def _f102(self, args: list[w.Value]) -> Outcome:  # Variable_PutValue
        _owner, name = self._variable(args[0])
        if name == "@SERVO_ON":
            if not self.arm_taken:
                raise CallFailed(w.E_ACCESSDENIED, "@SERVO_ON: TakeArm first")
            self.motor_on = bool(args[1].value)
        elif name == "@EXTSPEED":
            self._ext_speed([_number(args[1], "@EXTSPEED")])
        else:
            raise CallFailed(w.E_ACCESSDENIED, f"{name} is read-only")
        return Outcome(w.S_OK)

    def _f111(self, args: list[w.Value]) -> Outcome:  # Variable_Release
        self._variable(args[0])
        del self.handles[w.unsigned(args[0].value)]
        return Outcome(w.S_OK)

