"""b-CAP client for DENSO RC8 / RC7M controllers (``../shared/notes/bcap.md`` §6–12, §16).

Typical RC8 sequence (what :meth:`BcapClient.open_robot` and :meth:`BcapClient.close` do)::

    Service_Start → Controller_Connect → Controller_GetRobot → TakeArm → Motor on → ExtSpeed → moves
    → Motor off → GiveArm → Robot_Release → Controller_Disconnect → Service_Stop

Handles are echoed with the VARIANT type the controller returned them in (RC8: VT_UI4). Failures raise
:class:`~drivers.denso.hresult.BcapError`; for controller errors (0x83/0x84xxxxxx) the description is
fetched with ``GetErrorDescription`` when the controller is connected. Units: mm, degrees, percent, s.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from types import TracebackType
from typing import Any

from drivers.denso import bcap
from drivers.denso.hresult import (
    CODES,
    BcapConnectionError,
    BcapError,
    BcapTimeoutError,
    is_controller_error,
    to_signed,
)
from drivers.denso.link import BcapLink
from drivers.denso.variant import EMPTY, VT_BSTR, VT_I4, VT_R4, VT_UI4, Variant
from drivers.transport import Transport

log = logging.getLogger(__name__)

RC8_PROVIDER = "CaoProv.DENSO.VRC"
MOVE_PTP = 1
MOVE_LINEAR = 2
MIN_WDT_MS = 80


def _number(value: float) -> str:
    """A pose number as PacScript text: fixed point, no exponent, trailing zeros dropped."""
    if not math.isfinite(value):
        raise ValueError(f"pose value {value!r} is not finite")
    text = f"{value:.4f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def pose_string(pose: Sequence[float], fig: int = -1, *, pass_mark: str = "@P") -> str:
    """``@P P(x,y,z,rx,ry,rz,fig)`` from x, y, z in mm and rx, ry, rz in degrees.

    ``fig`` -1 lets the controller choose the arm configuration (**UNVERIFIED** on hardware; reuse the
    ``fig`` read from ``CurPos`` for a known configuration).
    """
    if len(pose) != 6:
        raise ValueError(f"pose has {len(pose)} values; expected 6 (x, y, z mm, rx, ry, rz deg)")
    if pass_mark not in ("@P", "@E", "@0") and not (pass_mark.startswith("@") and pass_mark[1:].isdigit()):
        raise ValueError(f"pass_mark={pass_mark!r}: expected @P, @E, @0 or @n")
    return f"{pass_mark} P({','.join(_number(float(v)) for v in pose)},{int(fig)})"


def service_option(wdt_ms: int | None, invoke_timeout_ms: int | None) -> str:
    """Service_Start option string, DENSO's form: ``",WDT=400,InvokeTimeout=180000"``."""
    parts = []
    if wdt_ms is not None:
        if not MIN_WDT_MS <= wdt_ms <= 0x7FFFFFFF:
            raise ValueError(f"wdt_ms={wdt_ms}: must be >= {MIN_WDT_MS} ms")
        parts.append(f"WDT={int(wdt_ms)}")
    if invoke_timeout_ms is not None:
        if not 0 < invoke_timeout_ms <= 0x7FFFFFFF:
            raise ValueError(f"invoke_timeout_ms={invoke_timeout_ms}: must be a positive number of ms")
        parts.append(f"InvokeTimeout={int(invoke_timeout_ms)}")
    return "," + ",".join(parts) if parts else ""


class BcapClient:
    """Function-level b-CAP client on an injected transport.

    Args:
        transport: open transport to the controller (TCP port 5007 or a serial line).
        serial_line: CRC framing, 503-byte packets, retries (the address decides; see :class:`BcapLink`).
        udp: the transport is UDP: 503-byte packets and retries, no CRC.
        retries: attempts per call on a serial line (1..7); TCP never re-sends.
        timeout_s: receive timeout; must exceed the WDT keep-alive period with margin.
        rc7m: RC7M quirks (empty connect strings, no TakeArm/GiveArm, Motor with an I2 scalar).
    """

    def __init__(self, transport: Transport, *, serial_line: bool = False, udp: bool = False,
                 retries: int = 3, timeout_s: float = 3.0, invoke_timeout_s: float = 180.0,
                 rc7m: bool = False, reopen: Callable[[], Transport] | None = None) -> None:
        self.link = BcapLink(transport, serial_line=serial_line, datagram=udp, retries=retries,
                             timeout_s=timeout_s, invoke_timeout_s=invoke_timeout_s, reopen=reopen)
        self.rc7m = rc7m
        self.h_ctrl: Variant | None = None
        self.h_robot: Variant | None = None
        self.service_started = False
        self.arm_taken = False
        self.motor_on = False
        self.h_busy: Variant | None = None  # Robot_GetVariable "@BUSY_STATUS" handle (cached per session)
        self._describing = False
        self._service_options: dict[str, int | None] = {"wdt_ms": 400, "invoke_timeout_ms": 180_000}
        self._robot_name = "Arm"

    # low level ------------------------------------------------------------------------------------
    def call(self, function_id: int, args: Sequence[object] = (), *, timeout_s: float | None = None,
             idempotent: bool = False, attempts: int | None = None) -> Variant:
        """One call; returns the first reply argument (EMPTY when there is none). ``idempotent``: a read
        or a halt, which the link may ask again after a timeout (:class:`BcapLink`)."""
        try:
            reply = self.link.call(function_id, args, timeout_s=timeout_s, idempotent=idempotent,
                                   attempts=attempts)
        except BcapError as exc:
            describable = is_controller_error(exc.hresult) and exc.hresult not in CODES
            if describable and self.h_ctrl is not None and not self._describing:
                raise self._describe(exc) from None
            raise
        return reply[0] if reply else EMPTY

    def _describe(self, exc: BcapError) -> BcapError:
        self._describing = True  # GetErrorDescription failing with a controller error must not recurse
        try:
            text = self.controller_execute("GetErrorDescription", Variant(VT_I4, to_signed(exc.hresult)))
            if text.vt == VT_BSTR and text.value:
                return BcapError(exc.hresult, exc.name, text.value, function=exc.function)
        except BcapError:
            pass
        finally:
            self._describing = False
        return exc

    @staticmethod
    def _handle(reply: Variant, what: str) -> Variant:
        if isinstance(reply.value, bool) or not isinstance(reply.value, int):
            raise BcapError(0x80004005, description=f"{what} returned no handle (vt=0x{reply.vt:04X})")
        return reply

    # service / controller ---------------------------------------------------------------------------
    def service_start(self, *, wdt_ms: int | None = 400, invoke_timeout_ms: int | None = 180_000) -> None:
        """Service_Start with the watchdog (keep-alive period) and invoke timeout options."""
        if wdt_ms is not None and wdt_ms / 1000.0 * 1.5 > self.link.timeout_s:
            raise ValueError(f"wdt_ms={wdt_ms}: the receive timeout {self.link.timeout_s:g} s must exceed "
                             "1.5 × WDT so keep-alives can arrive")
        self.call(bcap.SERVICE_START, [service_option(wdt_ms, invoke_timeout_ms)])
        self._service_options = {"wdt_ms": wdt_ms, "invoke_timeout_ms": invoke_timeout_ms}
        self.service_started = True
        # without WDT a blocking call is silent until it ends: the heartbeat must not count that as lost
        self.link.contact.silent_calls = wdt_ms is None

    def service_stop(self) -> None:
        self.call(bcap.SERVICE_STOP)
        self.service_started = False

    def controller_connect(self, name: str = "rig", provider: str = RC8_PROVIDER, machine: str = "localhost",
                           option: str = "") -> Variant:
        """Controller_Connect; RC7M ignores the strings, so four empty strings are sent there."""
        args = ["", "", "", ""] if self.rc7m else [name, provider, machine, option]
        self.h_ctrl = self._handle(self.call(bcap.CONTROLLER_CONNECT, args), "Controller_Connect")
        return self.h_ctrl

    def controller_disconnect(self) -> None:
        if self.h_ctrl is not None:
            handle, self.h_ctrl = self.h_ctrl, None
            self.call(bcap.CONTROLLER_DISCONNECT, [handle])

    def controller_get_robot(self, name: str = "Arm", option: str = "") -> Variant:
        self.h_busy = None  # belongs to the previous robot handle, if any
        self._robot_name = name
        self.h_robot = self._handle(self.call(bcap.CONTROLLER_GET_ROBOT, [self._ctrl(), name, option]),
                                    "Controller_GetRobot")
        return self.h_robot

    def controller_execute(self, command: str, param: object = None, *, idempotent: bool = False) -> Variant:
        return self.call(bcap.CONTROLLER_EXECUTE, [self._ctrl(), command, param], idempotent=idempotent)

    def clear_error(self) -> None:
        self.controller_execute("ClearError")

    def error_count(self) -> int:
        return int(self.controller_execute("GetCurErrorCount", idempotent=True).value)

    def error_info(self, index: int = 0) -> list[Any]:
        """``[code, message, ...]`` of the current error number ``index``."""
        return list(self.controller_execute("GetCurErrorInfo", Variant(VT_I4, index)).to_python())

    def error_description(self, code: int) -> str:
        return str(self.controller_execute("GetErrorDescription", Variant(VT_I4, to_signed(code))).value)

    # robot ----------------------------------------------------------------------------------------
    def robot_execute(self, command: str, param: object = None, *, timeout_s: float | None = None,
                      idempotent: bool = False) -> Variant:
        return self.call(bcap.ROBOT_EXECUTE, [self._robot(), command, param], timeout_s=timeout_s,
                         idempotent=idempotent)

    def take_arm(self, group: int = 0, keep: int = 1) -> None:
        if not self.rc7m:
            self.robot_execute("TakeArm", Variant(0x2003, [group, keep]))
        self.arm_taken = True

    def give_arm(self) -> None:
        if not self.rc7m:
            self.robot_execute("GiveArm")
        self.arm_taken = False

    def motor(self, on: bool, *, no_wait: bool = False) -> None:
        param = Variant(2, 1 if on else 0) if self.rc7m else Variant(0x2003, [int(on), int(no_wait)])
        self.robot_execute("Motor", param)
        self.motor_on = on

    def ext_speed(self, speed_percent: float, accel_percent: float = -2, decel_percent: float = -2) -> None:
        """ExtSpeed in percent (R4); -1 keeps the current value, -2 means speed²/100."""
        for label, value in (("speed_percent", speed_percent), ("accel_percent", accel_percent),
                             ("decel_percent", decel_percent)):
            if not (0 < value <= 100 or value in (-1, -2)):
                raise ValueError(f"{label}={value}: must be in (0, 100] or -1 / -2")
        self.robot_execute("ExtSpeed", Variant(0x2004, [float(speed_percent), float(accel_percent),
                                                        float(decel_percent)]))

    def cur_pos(self) -> list[float]:
        """``[x, y, z, rx, ry, rz, fig]`` (mm, degrees, fig as a float as the controller sends it)."""
        reply = self.robot_execute("CurPos", idempotent=True)
        values = reply.to_python()
        if not isinstance(values, list) or len(values) < 6:
            raise BcapError(0x80004005, description=f"CurPos returned {reply!r}; expected 7 numbers")
        return [float(v) for v in values]

    def robot_move(self, comp: int, pose: str | Sequence[float], option: str = "", *,
                   fig: int = -1, timeout_s: float | None = None) -> None:
        """Robot_Move (blocking unless ``option`` holds NEXT). ``comp`` 1 = PTP, 2 = linear."""
        if comp not in (1, 2, 3, 4):
            raise ValueError(f"comp={comp}: must be 1 (PTP), 2 (linear), 3 (circular) or 4 (spline)")
        text = pose if isinstance(pose, str) else pose_string(pose, fig)
        self.call(bcap.ROBOT_MOVE, [self._robot(), Variant(VT_I4, comp), text, option], timeout_s=timeout_s)

    def move(self, pose: Sequence[float], *, linear: bool = False, speed_percent: float | None = None,
             fig: int = -1, timeout_s: float | None = None, next_: bool = False) -> None:
        """Move to ``pose`` (x, y, z mm, rx, ry, rz deg): PTP or linear, with an optional SPEED option.

        ``next_=True`` adds the ``NEXT`` option: the controller answers as soon as the motion has started
        (bcap.md §8) and the caller polls :meth:`busy_status` for its end; otherwise the call blocks until
        the arm is at rest (no other request on the connection is served meanwhile: queued by the
        reference server, or E_BUSY_PROC, §10)."""
        parts = []
        if speed_percent is not None:
            if not 0 < speed_percent <= 100:
                raise ValueError(f"speed_percent={speed_percent}: must be in (0, 100]")
            parts.append(f"SPEED={_number(speed_percent)}")
        if next_:
            parts.append("NEXT")
        self.robot_move(MOVE_LINEAR if linear else MOVE_PTP, pose, ",".join(parts), fig=fig,
                        timeout_s=timeout_s)

    def busy_status(self) -> bool:
        """The robot's ``@BUSY_STATUS`` variable: True while a motion is under way.

        The variable handle (Robot_GetVariable) is taken on first use and kept until :meth:`close`
        (Variable_Release); each call is then one Variable_GetValue."""
        if self.h_busy is None:
            reply = self.call(bcap.ROBOT_GET_VARIABLE, [self._robot(), "@BUSY_STATUS", ""])
            self.h_busy = self._handle(reply, "Robot_GetVariable @BUSY_STATUS")
        reply = self.call(bcap.VARIABLE_GET_VALUE, [self.h_busy], idempotent=True)
        value = reply.value
        if isinstance(value, bool):
            return value
        if isinstance(value, int | float) and not isinstance(value, bool):
            return value != 0  # a controller answering with a number instead of VT_BOOL
        raise BcapError(0x80004005, description=f"@BUSY_STATUS returned {reply!r}; expected a boolean")

    def variable_release(self, handle: Variant) -> None:
        self.call(bcap.VARIABLE_RELEASE, [handle])

    def robot_speed(self, speed_percent: float, axis: int = -1) -> None:
        self.call(bcap.ROBOT_SPEED,
                  [self._robot(), Variant(VT_I4, axis), Variant(VT_R4, float(speed_percent))])

    def halt(self, option: str = "", *, attempts: int | None = None) -> None:
        """Robot_Halt (idempotent: asked again after a timeout unless ``attempts`` is 1)."""
        self.call(bcap.ROBOT_HALT, [self._robot(), option], idempotent=True, attempts=attempts)

    def restart_session(self) -> None:
        """A fresh link and session, for a make-safe when the old link is out of step, busy or gone:
        reconnect, Service_Start (the last options), Controller_Connect, Controller_GetRobot. Arm
        ownership and motor are not taken again (a halt is all this session is for)."""
        self.link.reconnect()
        self.h_ctrl = self.h_robot = self.h_busy = None
        self.service_started = self.arm_taken = self.motor_on = False
        self.service_start(**self._service_options)
        self.controller_connect()
        self.controller_get_robot(self._robot_name)

    def robot_release(self) -> None:
        if self.h_robot is not None:
            handle, self.h_robot = self.h_robot, None
            self.h_busy = None  # a variable of the released robot
            self.call(bcap.ROBOT_RELEASE, [handle])

    # sessions ---------------------------------------------------------------------------------------
    def open_robot(self, *, robot_name: str = "Arm", wdt_ms: int | None = 400,
                   invoke_timeout_ms: int | None = 180_000, ext_speed_percent: float | None = None,
                   ext_accel_percent: float = -2, clear_errors: bool = True) -> None:
        """The RC8 start sequence up to motor on (ClearError first if errors are pending), then ExtSpeed
        ``ext_speed_percent`` with acceleration and deceleration ``ext_accel_percent`` (-2: speed²/100)."""
        self.service_start(wdt_ms=wdt_ms, invoke_timeout_ms=invoke_timeout_ms)
        self.controller_connect()
        if clear_errors and not self.rc7m and self.error_count() > 0:
            self.clear_error()
        self.controller_get_robot(robot_name)
        self.take_arm()
        self.motor(True)
        if ext_speed_percent is not None:
            self.ext_speed(ext_speed_percent, ext_accel_percent, ext_accel_percent)

    def close(self) -> None:
        """Release everything in reverse order; every step is attempted even if an earlier one fails.

        A dead link (closed or unresponsive) stops the sequence early: further calls could only time out.
        """
        steps: list[tuple[str, Callable[[], object]]] = []
        if self.h_busy is not None:
            handle, self.h_busy = self.h_busy, None
            steps.append(("Variable_Release @BUSY_STATUS", lambda: self.variable_release(handle)))
        if self.h_robot is not None:
            if self.motor_on:
                steps.append(("Motor off", lambda: self.motor(False)))
            if self.arm_taken:
                steps.append(("GiveArm", self.give_arm))
            steps.append(("Robot_Release", self.robot_release))
        if self.h_ctrl is not None:
            steps.append(("Controller_Disconnect", self.controller_disconnect))
        if self.service_started:
            steps.append(("Service_Stop", self.service_stop))
        for label, step in steps:
            try:
                step()
            except (BcapConnectionError, BcapTimeoutError) as exc:
                log.error("cleanup %s failed, link lost: %s", label, exc)
                break
            except BcapError as exc:
                log.error("cleanup %s failed: %s", label, exc)
        self.h_robot = self.h_ctrl = self.h_busy = None
        self.service_started = self.arm_taken = self.motor_on = False

    def __enter__(self) -> BcapClient:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def _ctrl(self) -> Variant:
        if self.h_ctrl is None:
            raise BcapError(0x80000902, description="no controller handle: call controller_connect() first")
        return self.h_ctrl

    def _robot(self) -> Variant:
        if self.h_robot is None:
            raise BcapError(0x80000902, description="no robot handle: call controller_get_robot() first")
        return self.h_robot


__all__ = ["MOVE_LINEAR", "MOVE_PTP", "RC8_PROVIDER", "VT_UI4", "BcapClient", "pose_string", "service_option"]
