"""The robot arm device used by procedures: safe moves of a DENSO arm through a :class:`BcapClient`.

Safety (DESIGN.md): the workspace envelope and the speed cap are checked **before any byte is sent**;
a violation raises :class:`LimitError` naming the axis, the value and the allowed range. After each
move the pose reported by ``CurPos`` must match the target within the tolerances, else
:class:`PositionMismatchError`. Any failure during a move attempts a halt before re-raising. Moves
are sent with NEXT and their end polled (``motion.py``), so :meth:`DensoArm.halt` works mid-move.

Speeds: ``speed_mm_s`` is converted to the controller's SPEED percent with ``full_speed_mm_s`` (what
100 % means on the controller; ExtSpeed is set to 100 % at :meth:`DensoArm.open`). **UNVERIFIED** on a
real RC8: that SPEED of a linear move scales a Cartesian speed linearly (bcap.md §13). Linear moves are
checked along their straight path (the box and the plain cylinder are convex; an annulus is checked for
cutting its core); a PTP move's real path is not straight, so there only the end points are guaranteed.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from types import TracebackType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drivers.clock import Clock
from drivers.denso import bcap
from drivers.denso.client import BcapClient
from drivers.denso.hresult import BcapError, BcapProtocolError
from drivers.denso.motion import (
    MoveHaltedError,
    MoveTimeoutError,
    WaitSettings,
    move_timeout_s,
    wait_for_rest,
)
from drivers.denso.pose import check_pose, orientation_error_deg
from drivers.heartbeat import Heartbeat, HeartbeatError
from drivers.roles import Arm
from drivers.transport import TransportError

log = logging.getLogger(__name__)


class LimitError(ValueError):
    """A command is outside a configured safety limit; nothing was sent."""

    def __init__(self, axis: str, value: float, allowed: tuple[float, float]) -> None:
        self.axis, self.value, self.allowed = axis, value, allowed
        super().__init__(f"{axis}={value:g} outside the allowed range [{allowed[0]:g}, {allowed[1]:g}]")


class ArmHaltError(RuntimeError):
    """The arm could not be halted by a Robot_Halt; the message says what was done instead."""


@dataclass
class HaltReport:
    """What a make-safe did: ``halted`` when a Robot_Halt was accepted, ``fresh_link`` when that took a
    new connection and session; ``attempts``: one line per attempt; ``elapsed_s``: wall seconds."""

    halted: bool = False
    fresh_link: bool = False
    attempts: list[str] = field(default_factory=list)
    elapsed_s: float = 0.0


class PositionMismatchError(RuntimeError):
    """After a move the controller reports a pose farther from the target than the tolerance."""


def _range(value: Sequence[float], name: str) -> tuple[float, float]:
    low, high = (float(v) for v in value)
    if not (math.isfinite(low) and math.isfinite(high) and low <= high):
        raise ValueError(f"{name}={tuple(value)!r}: expected a finite (min, max) with min <= max")
    return low, high


def _check(axis: str, value: float, allowed: tuple[float, float]) -> None:
    if not allowed[0] <= value <= allowed[1]:
        raise LimitError(axis, value, allowed)


def check_speed(speed_mm_s: float, max_speed_mm_s: float) -> float:
    """A move speed (mm/s) in (0, ``max_speed_mm_s``], returned as a float; else :class:`LimitError`."""
    speed = float(speed_mm_s)
    if not math.isfinite(speed) or speed <= 0:
        raise LimitError("speed_mm_s", speed, (0.0, max_speed_mm_s))
    _check("speed_mm_s", speed, (0.0, max_speed_mm_s))
    return speed


@dataclass(frozen=True)
class OrientationLimits:
    """Allowed Denso angles in degrees (raw rx, ry, rz values as commanded)."""

    rx_deg: tuple[float, float] = (-180.0, 180.0)
    ry_deg: tuple[float, float] = (-180.0, 180.0)
    rz_deg: tuple[float, float] = (-180.0, 180.0)

    def __post_init__(self) -> None:
        for name in ("rx_deg", "ry_deg", "rz_deg"):
            object.__setattr__(self, name, _range(getattr(self, name), name))

    def check(self, pose: NDArray[np.float64]) -> None:
        for name, value in zip(("rx_deg", "ry_deg", "rz_deg"), pose[3:6], strict=True):
            _check(name, float(value), getattr(self, name))


@dataclass(frozen=True)
class BoxEnvelope:
    """Axis-aligned box of allowed flange positions (base frame, mm)."""

    x_mm: tuple[float, float]
    y_mm: tuple[float, float]
    z_mm: tuple[float, float]
    orientation: OrientationLimits = field(default_factory=OrientationLimits)

    def __post_init__(self) -> None:
        for name in ("x_mm", "y_mm", "z_mm"):
            object.__setattr__(self, name, _range(getattr(self, name), name))

    def check(self, pose: NDArray[np.float64]) -> None:
        for name, value in zip(("x_mm", "y_mm", "z_mm"), pose[:3], strict=True):
            _check(name, float(value), getattr(self, name))
        self.orientation.check(pose)


@dataclass(frozen=True)
class CylinderEnvelope:
    """Vertical cylinder (or annulus) of allowed flange positions around the base's J1 axis (mm)."""

    radius_mm: float
    z_mm: tuple[float, float]
    inner_radius_mm: float = 0.0
    orientation: OrientationLimits = field(default_factory=OrientationLimits)

    def __post_init__(self) -> None:
        object.__setattr__(self, "z_mm", _range(self.z_mm, "z_mm"))
        if not (0 <= self.inner_radius_mm < self.radius_mm and math.isfinite(self.radius_mm)):
            raise ValueError(f"inner_radius_mm={self.inner_radius_mm}, radius_mm={self.radius_mm}: "
                             "need 0 <= inner < radius")

    def check(self, pose: NDArray[np.float64]) -> None:
        _check("radius_mm", math.hypot(pose[0], pose[1]), (self.inner_radius_mm, self.radius_mm))
        _check("z_mm", float(pose[2]), self.z_mm)
        self.orientation.check(pose)

    def check_path(self, start: NDArray[np.float64], end: NDArray[np.float64]) -> None:
        """A straight move between two allowed poses may still cut through the inner (forbidden) core."""
        if self.inner_radius_mm <= 0:
            return
        p0, d = np.asarray(start[:2], float), np.asarray(end[:2], float) - np.asarray(start[:2], float)
        t = float(np.clip(-(p0 @ d) / (d @ d), 0.0, 1.0)) if d @ d > 0 else 0.0
        closest = float(np.linalg.norm(p0 + t * d))
        if closest < self.inner_radius_mm:
            raise LimitError("path radius_mm", closest, (self.inner_radius_mm, self.radius_mm))


Envelope = BoxEnvelope | CylinderEnvelope


def envelope_from_config(config: Mapping[str, Any]) -> Envelope:
    """``{"box": {"x_mm": [a, b], "y_mm": [...], "z_mm": [...]}}`` or ``{"cylinder": {"radius_mm": r,
    "z_mm": [a, b], "inner_radius_mm": r0}}``, plus optional ``"orientation": {"rx_deg": [a, b], ...}``."""
    orientation = OrientationLimits(**{k: tuple(v) for k, v in config.get("orientation", {}).items()})
    unknown = set(config) - {"box", "cylinder", "orientation"}
    if unknown or ("box" in config) == ("cylinder" in config):
        raise ValueError(f"envelope keys {sorted(config)}: give exactly one of 'box' or 'cylinder' "
                         "(and optionally 'orientation')")
    if "box" in config:
        box = config["box"]
        return BoxEnvelope(tuple(box["x_mm"]), tuple(box["y_mm"]), tuple(box["z_mm"]), orientation)
    cyl = config["cylinder"]
    return CylinderEnvelope(float(cyl["radius_mm"]), tuple(cyl["z_mm"]),
                            float(cyl.get("inner_radius_mm", 0.0)), orientation)


@dataclass(frozen=True)
class MoveResult:
    """One completed move: poses (x, y, z mm; rx, ry, rz deg) and controller-clock times (s)."""

    commanded_pose: list[float]
    reported_pose: list[float]
    t_start_s: float
    t_end_s: float
    position_error_mm: float
    orientation_error_deg: float


class DensoArm(Arm):
    """A DENSO arm behind a b-CAP client.

    Args:
        client: a :class:`BcapClient` on an open transport (the arm runs the session on :meth:`open`).
        envelope: allowed flange poses (:class:`BoxEnvelope` or :class:`CylinderEnvelope`).
        max_speed_mm_s: speed cap; also the default move speed unless :meth:`set_speed` lowers it.
        position_tolerance_mm: allowed distance between target and reported position after a move.
        orientation_tolerance_deg: allowed rotation between target and reported orientation.
        full_speed_mm_s: the controller's 100 % speed (SPEED percent = speed_mm_s / full_speed_mm_s).
        max_accel_mm_s2: acceleration and deceleration cap, commanded once at :meth:`open` as ExtSpeed's
            accel/decel percent of ``full_accel_mm_s2`` (None: the controller's own 100 %).
        full_accel_mm_s2: the controller's 100 % acceleration (mm/s²).
        clock: the rig clock (times of each move).
        linear: linear (MOVE L) moves by default, else PTP (MOVE P).
        heartbeat_timeout_s: :meth:`heartbeat` reports the controller lost after this many wall seconds
            without any packet from it (keep-alives count); must exceed the WDT keep-alive period.
        wait: how a move waits for the end of motion (:class:`~drivers.denso.motion.WaitSettings`):
            by default Robot_Move with NEXT and ``@BUSY_STATUS`` polls every 0.05 s of ``clock``, so
            :meth:`halt` from another thread is accepted mid-move; ``WaitSettings(wait_mode="blocking")``
            for controllers without NEXT (a halt cannot pass the Move on its connection, so
            :meth:`safe_state` halts on a fresh one; the default for an RC7M client).
    """

    def __init__(self, client: BcapClient, *, envelope: Envelope, max_speed_mm_s: float,
                 position_tolerance_mm: float, clock: Clock, orientation_tolerance_deg: float = 0.1,
                 full_speed_mm_s: float = 1000.0, linear: bool = True,
                 heartbeat_timeout_s: float = 2.0, wait: WaitSettings | None = None,
                 make_safe_deadline_s: float = 15.0, max_accel_mm_s2: float | None = None,
                 full_accel_mm_s2: float = 5000.0) -> None:
        if not (0 < max_speed_mm_s <= full_speed_mm_s and math.isfinite(max_speed_mm_s)):
            raise ValueError(f"max_speed_mm_s={max_speed_mm_s}: must be in (0, full_speed_mm_s="
                             f"{full_speed_mm_s}]")
        if not position_tolerance_mm > 0 or not orientation_tolerance_deg > 0:
            raise ValueError(f"position_tolerance_mm={position_tolerance_mm}, orientation_tolerance_deg="
                             f"{orientation_tolerance_deg}: both must be > 0")
        self.client = client
        self.envelope = envelope
        self.max_speed_mm_s = float(max_speed_mm_s)
        self.speed_mm_s = float(max_speed_mm_s)
        self.position_tolerance_mm = float(position_tolerance_mm)
        self.orientation_tolerance_deg = float(orientation_tolerance_deg)
        self.full_speed_mm_s = float(full_speed_mm_s)
        if max_accel_mm_s2 is not None and not (0 < max_accel_mm_s2 <= full_accel_mm_s2
                                                and math.isfinite(max_accel_mm_s2)):
            raise ValueError(f"max_accel_mm_s2={max_accel_mm_s2}: must be in (0, full_accel_mm_s2="
                             f"{full_accel_mm_s2}]")
        # ExtSpeed's accel/decel percent (-2: the controller's speed²/100, i.e. 100 % at ExtSpeed 100)
        self.accel_percent = -2.0 if max_accel_mm_s2 is None else 100.0 * max_accel_mm_s2 / full_accel_mm_s2
        self.clock = clock
        self.linear = linear
        self.last_move: MoveResult | None = None
        self.fig: int = -1
        # RC7M: NEXT + @BUSY_STATUS is documented for RC8 only (bcap.md §12): blocking by default
        self.wait = wait or WaitSettings(wait_mode="blocking" if client.rc7m else "next")
        # last pose read from CurPos (None after a failed move)
        self._pose_known: NDArray[np.float64] | None = None
        self.halts_sent = 0  # Robot_Halts accepted or unanswered, any thread (a move halted under way)
        if not (math.isfinite(make_safe_deadline_s) and make_safe_deadline_s > 0):
            raise ValueError(f"make_safe_deadline_s={make_safe_deadline_s}: must be > 0 s")
        self.make_safe_deadline_s = float(make_safe_deadline_s)
        self.last_make_safe: HaltReport | None = None
        self.wdt_ms: int | None = None  # the watchdog the session was opened with (open())
        self.heartbeat_monitor = Heartbeat("robot", client.link.contact, self._probe,
                                           timeout_s=heartbeat_timeout_s)

    # ------------------------------------------------------------------------------------ session
    def open(self, *, wdt_ms: int | None = 400) -> None:
        """Service_Start with the watchdog ``wdt_ms`` (keep-alive period, ms; None: none — rig.toml's
        ``devices.robot.wdt_ms``) … TakeArm, Motor on, ExtSpeed 100 % with the acceleration cap."""
        if wdt_ms is not None and wdt_ms / 1000.0 >= self.heartbeat_monitor.timeout_s:
            raise ValueError(f"wdt_ms={wdt_ms}: the keep-alive period must be shorter than the heartbeat "
                             f"timeout {self.heartbeat_monitor.timeout_s:g} s")
        self.client.open_robot(wdt_ms=wdt_ms, ext_speed_percent=100.0, ext_accel_percent=self.accel_percent)
        self.wdt_ms = wdt_ms
        self._pose_known = np.asarray(self.client.cur_pos()[:6], dtype=float)  # the first move starts here

    def close(self) -> None:
        """Motor off, GiveArm, releases, Service_Stop (every step attempted)."""
        self.client.close()

    def __enter__(self) -> DensoArm:
        if not self.client.service_started:
            self.open()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    # ------------------------------------------------------------------------------------- limits
    def check_pose(self, pose: Sequence[float] | NDArray[np.float64]) -> NDArray[np.float64]:
        """Validate a target against the envelope; return it as an array (6,). Sends nothing."""
        target = check_pose(pose)
        self.envelope.check(target)
        return target

    def check_speed(self, speed_mm_s: float) -> float:
        return check_speed(speed_mm_s, self.max_speed_mm_s)

    def set_speed(self, speed_mm_s: float) -> None:
        """Default speed of later moves (mm/s, at most ``max_speed_mm_s``)."""
        self.speed_mm_s = self.check_speed(speed_mm_s)

    # ------------------------------------------------------------------------------------- motion
    def move_to(self, pose: Sequence[float] | NDArray[np.float64], speed_mm_s: float | None = None, *,
                linear: bool | None = None) -> MoveResult:
        """Move the flange to ``pose`` and verify the reported pose; returns when the arm is at rest.

        In ``"next"`` wait mode the move is bounded in clock time (``motion.move_timeout_s`` of the
        distance from the current pose): :class:`MoveTimeoutError` after a halt on expiry;
        :class:`MoveHaltedError` when a :meth:`halt` (e.g. from the runner's safe state) stopped it."""
        target = self.check_pose(pose)
        speed = self.check_speed(self.speed_mm_s if speed_mm_s is None else speed_mm_s)
        linear = self.linear if linear is None else linear
        polling = self.wait.wait_mode == "next"
        annulus = (self.envelope if isinstance(self.envelope, CylinderEnvelope)
                   and self.envelope.inner_radius_mm > 0 else None)
        start = self._pose_known  # the start of the move's time bound and of the path check
        if start is None and (polling or (linear and annulus is not None)):
            start = self.position()
        if linear and annulus is not None and start is not None:
            annulus.check_path(start, target)  # never moves before the check
        percent = speed / self.full_speed_mm_s * 100.0
        halts_before = self.halts_sent
        t_start = self.clock.now_s()
        try:
            self.client.move(target.tolist(), linear=linear, speed_percent=percent, fig=self.fig,
                             next_=polling)
            if polling and start is not None:
                timeout_s = move_timeout_s(float(np.linalg.norm(target[:3] - start[:3])),
                                           orientation_error_deg(start, target), speed, percent, self.wait)
                wait_for_rest(self.client, self.clock, self.wait, timeout_s=timeout_s, t_start_s=t_start,
                              halt=self.halt, what=f"move to {target.tolist()} at {speed:g} mm/s")
            t_end = self.clock.now_s()
            reported = self.position()
        except (BcapError, BcapProtocolError, TransportError, OSError) as exc:
            self._pose_known = None
            log.error("move to %s failed (%s); attempting a halt", target.tolist(), exc)
            self._try_halt()
            raise
        except BaseException as exc:  # interrupted (interlock, Ctrl-C) while the arm moves on its own
            self._pose_known = None
            if polling and not isinstance(exc, MoveTimeoutError):  # (the timeout has sent its halt)
                self._try_halt()
            raise
        if self.halts_sent != halts_before:
            raise MoveHaltedError(f"the move to {target.tolist()} was halted under way; the controller "
                                  f"reports the arm at rest at {reported.tolist()}")
        position_error = float(np.linalg.norm(reported[:3] - target[:3]))
        angle_error = orientation_error_deg(reported, target)
        result = MoveResult(target.tolist(), reported.tolist(), t_start, t_end, position_error, angle_error)
        self.last_move = result
        if position_error > self.position_tolerance_mm or angle_error > self.orientation_tolerance_deg:
            raise PositionMismatchError(
                f"after the move to {target.tolist()} the controller reports {reported.tolist()}: "
                f"{position_error:.3f} mm (tolerance {self.position_tolerance_mm:g} mm), "
                f"{angle_error:.3f} deg (tolerance {self.orientation_tolerance_deg:g} deg)")
        return result

    def position(self) -> NDArray[np.float64]:
        """Current flange pose (6,) from ``CurPos``: x, y, z mm; rx, ry, rz deg."""
        values = self.client.cur_pos()
        if len(values) > 6:
            self.fig = int(values[6])
        self._pose_known = np.asarray(values[:6], dtype=float)
        return self._pose_known.copy()

    def halt(self, *, attempts: int | None = None) -> None:
        """Stop the arm now (Robot_Halt). Thread-safe; in ``"next"`` wait mode it is accepted mid-move
        (the moving thread holds the link only for each ``@BUSY_STATUS`` poll)."""
        with self.client.link.contact.lock:  # (re-entrant) a polling mover sees the count with the result
            self.halts_sent += 1
            try:
                self.client.halt(attempts=attempts)
            except BcapError:
                self.halts_sent -= 1  # refused (e.g. E_BUSY_PROC): it stopped nothing
                raise

    # ---------------------------------------------------------------------------------- heartbeat
    def heartbeat(self, *, wait: bool = False) -> bool:
        """Watchdog probe (thread-safe, no I/O in the caller's thread, returns at once; ``wait=True``
        probes now in the caller's thread instead, for ``rig check``).

        Raises :class:`~drivers.heartbeat.DeviceLostError` naming the device, the age of the last packet
        from the controller and the limit, when the link was closed or nothing (not even an S_EXECUTING
        keep-alive of a running Move) arrived for ``heartbeat_timeout_s``. When the link has been idle
        for a quarter of that, one ``CurPos`` is sent from a helper thread — only while no call is in
        flight (a request during a blocking Move would wait behind it, or get E_BUSY_PROC, bcap.md §10).
        """
        return self.heartbeat_monitor.verify() if wait else self.heartbeat_monitor.check()

    def _probe(self) -> None:
        client, link = self.client, self.client.link
        timeout_s = min(link.timeout_s, self.heartbeat_monitor.timeout_s / 2.0)
        if client.h_robot is not None:
            link.call(bcap.ROBOT_EXECUTE, [client.h_robot, "CurPos", None], timeout_s=timeout_s, attempts=1)
        elif client.h_ctrl is not None:
            link.call(bcap.CONTROLLER_EXECUTE, [client.h_ctrl, "GetCurErrorCount", None],
                      timeout_s=timeout_s, attempts=1)
        else:
            raise HeartbeatError("robot", "no b-CAP session to probe (open() not called or closed)")

    def safe_state(self) -> None:
        """The runner's "make safe": :meth:`make_safe`; :class:`ArmHaltError` when no halt was accepted
        before the deadline (the message lists every attempt)."""
        report = self.make_safe()
        if not report.halted:
            raise ArmHaltError(f"no Robot_Halt accepted within {report.elapsed_s:.1f} s: "
                               + "; ".join(report.attempts))

    def make_safe(self, deadline_s: float | None = None) -> HaltReport:
        """Halt the arm, on a fresh link if need be, within ``deadline_s`` wall seconds (default
        ``make_safe_deadline_s``); the outcome is returned and kept in :attr:`last_make_safe`.

        First a Robot_Halt on the current link, if its lock comes free within the receive timeout. When
        that fails — the link is busy with a blocking Move (the reference server queues the halt behind
        it, a controller may refuse it with E_BUSY_PROC), out of step, silent or closed — the connection
        is closed (the controller ends that session and stops the arm: the mock does; **UNVERIFIED** on a
        real RC8) and a new one is opened: Service_Start, Controller_Connect, Controller_GetRobot,
        Robot_Halt; repeated until the deadline.
        """
        link = self.client.link
        deadline = time.monotonic() + (self.make_safe_deadline_s if deadline_s is None else deadline_s)
        started = time.monotonic()
        report = HaltReport()
        self.last_make_safe = report
        errors = (BcapError, BcapProtocolError, TransportError, OSError)
        if link.contact.lock.acquire(timeout=min(link.timeout_s, max(0.0, deadline - time.monotonic()))):
            try:
                self.halt(attempts=1)  # a busy or out-of-step link is left for a fresh one at once
                report.halted = True
                report.attempts.append("Robot_Halt on the current link: accepted")
            except errors as exc:
                report.attempts.append(f"Robot_Halt on the current link: {exc}")
            finally:
                link.contact.lock.release()
        else:
            report.attempts.append(f"current link busy for {link.timeout_s:g} s (a call in flight)")
        while not report.halted and time.monotonic() < deadline:
            link.transport.close()  # ends a call in flight in another thread, and the controller's session
            try:
                with link.contact.lock:
                    self.client.restart_session()
                    self.halt()
                report.halted = report.fresh_link = True
                report.attempts.append("Robot_Halt on a fresh link: accepted")
            except errors as exc:
                report.attempts.append(f"Robot_Halt on a fresh link: {exc}")
                time.sleep(min(0.2, max(0.0, deadline - time.monotonic())))
        report.elapsed_s = time.monotonic() - started
        (log.info if report.halted else log.error)("make safe: %s", "; ".join(report.attempts))
        return report

    def _try_halt(self) -> None:
        try:
            self.halt()
        except (BcapError, TransportError, OSError) as exc:
            log.error("halt after a failed move also failed: %s", exc)

    def read_back(self, *, settle_s: float = 0.2) -> dict[str, Any]:
        """The controller's own report (:class:`drivers.roles.Arm`): the pose read twice ``settle_s``
        (s, rig clock, > 0) apart and ``moved_mm``, how far the flange moved in between (0 when halted)."""
        first = self.position()
        self.clock.sleep_s(settle_s)
        second = self.position()
        return {"pose": [float(v) for v in second], "settle_s": settle_s,
                "moved_mm": float(np.linalg.norm(second[:3] - first[:3]))}

    def snapshot(self) -> dict[str, Any]:
        """Configuration and last state, for the run record."""
        link = self.client.link
        return {
            "driver": "denso.bcap",
            "transport": link.transport.url,
            "serial_line": link.serial_line,
            "timeout_s": link.timeout_s,
            "wdt_ms": self.wdt_ms,
            "envelope": {type(self.envelope).__name__: asdict(self.envelope)},
            "max_speed_mm_s": self.max_speed_mm_s,
            "speed_mm_s": self.speed_mm_s,
            "full_speed_mm_s": self.full_speed_mm_s,
            "position_tolerance_mm": self.position_tolerance_mm,
            "orientation_tolerance_deg": self.orientation_tolerance_deg,
            "linear": self.linear,
            "wait": asdict(self.wait),
            "last_move": asdict(self.last_move) if self.last_move else None,
            "last_make_safe": asdict(self.last_make_safe) if self.last_make_safe else None,
        }
