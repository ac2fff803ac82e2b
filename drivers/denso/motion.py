"""Waiting for the end of a ``NEXT`` move by polling ``@BUSY_STATUS`` (``../shared/notes/bcap.md`` §8, §10).

A Robot_Move without ``NEXT`` keeps the controller executing that one call until the arm is at rest, and
no other request on that connection is served meanwhile — including Robot_Halt: DENSO's reference server
queues it behind the Move, a controller may refuse it with E_BUSY_PROC (docs/bcap_mock.md). With ``NEXT`` the
controller answers at once; :func:`wait_for_rest` then polls ``@BUSY_STATUS`` every ``poll_interval_s``
of the injected clock, taking the link lock only for each poll, so a Robot_Halt from another thread (the
runner's safe state after an interlock or a second Ctrl-C) goes out at once and is accepted.

The wait is bounded by :func:`move_timeout_s` (path length and angle over the commanded speeds, times a
factor, plus a margin); on expiry a Robot_Halt is sent and :class:`MoveTimeoutError` raised.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

from drivers.clock import Clock
from drivers.denso.client import BcapClient

log = logging.getLogger(__name__)

WAIT_MODES = ("next", "blocking")


class MoveTimeoutError(TimeoutError):
    """The controller still reported the arm busy when the move's time bound expired; a halt was sent."""


class MoveHaltedError(RuntimeError):
    """A Robot_Halt (from another thread, e.g. the runner's safe state) stopped the move short."""


@dataclass(frozen=True)
class WaitSettings:
    """How a move waits for the arm to come to rest.

    Args:
        wait_mode: ``"next"`` (default): Robot_Move with NEXT, then poll ``@BUSY_STATUS`` — a halt can be
            sent mid-move. ``"blocking"``: Robot_Move without NEXT, for controllers that lack NEXT or
            ``@BUSY_STATUS``; the call returns when the arm is at rest, and a Robot_Halt cannot pass it on
            that connection (the arm's safe state then closes it and halts on a fresh one).
        poll_interval_s: clock seconds between two ``@BUSY_STATUS`` polls, in (0, 5].
        timeout_factor: the bound is ``timeout_factor`` × the nominal duration (≥ 1) …
        timeout_margin_s: … plus this many seconds (≥ 0; covers acceleration and settling).
        full_rot_speed_deg_s: orientation speed at 100 % SPEED assumed for the bound (deg/s, > 0).
            **UNVERIFIED** for a real RC8 (a smaller value only lengthens the bound).
    """

    wait_mode: str = "next"
    poll_interval_s: float = 0.05
    timeout_factor: float = 1.5
    timeout_margin_s: float = 5.0
    full_rot_speed_deg_s: float = 120.0

    def __post_init__(self) -> None:
        if self.wait_mode not in WAIT_MODES:
            raise ValueError(f"wait_mode={self.wait_mode!r}: expected one of {WAIT_MODES}")
        checks = (("poll_interval_s", self.poll_interval_s, 0.0, 5.0, False),
                  ("timeout_factor", self.timeout_factor, 1.0, math.inf, True),
                  ("timeout_margin_s", self.timeout_margin_s, 0.0, math.inf, True),
                  ("full_rot_speed_deg_s", self.full_rot_speed_deg_s, 0.0, math.inf, False))
        for name, value, low, high, low_ok in checks:
            ok = math.isfinite(value) and (value >= low if low_ok else value > low) and value <= high
            if not ok:
                bracket = "[" if low_ok else "("
                raise ValueError(f"{name}={value!r}: must be in {bracket}{low:g}, {high:g}]")


def move_timeout_s(distance_mm: float, angle_deg: float, speed_mm_s: float, speed_percent: float,
                   settings: WaitSettings) -> float:
    """Bound (s) on one move: factor × max(distance / speed, angle / (full rot speed × percent)) + margin."""
    rot_speed = settings.full_rot_speed_deg_s * speed_percent / 100.0
    nominal_s = max(distance_mm / speed_mm_s, angle_deg / rot_speed)
    return settings.timeout_factor * nominal_s + settings.timeout_margin_s


def wait_for_rest(client: BcapClient, clock: Clock, settings: WaitSettings, *, timeout_s: float,
                  t_start_s: float, halt: Callable[[], None], what: str) -> int:
    """Poll ``@BUSY_STATUS`` until the arm is at rest; return the number of polls.

    Each poll is one locked call; between polls only ``clock.sleep_s`` runs (no lock held). When the
    controller still reports busy at ``t_start_s + timeout_s`` (clock time), ``halt()`` is attempted and
    :class:`MoveTimeoutError` raised naming ``what``, the bound and the polls made.
    """
    deadline = t_start_s + timeout_s
    polls = 0
    while True:
        polls += 1
        if not client.busy_status():
            return polls
        now = clock.now_s()
        if now >= deadline:
            halted = "a Robot_Halt was sent"
            try:
                halt()
            except Exception as exc:  # report it: the timeout is the error
                halted = f"the Robot_Halt failed too ({type(exc).__name__}: {exc})"
                log.error("halt after a move timeout failed: %s", exc)
            raise MoveTimeoutError(
                f"{what}: the controller still reports @BUSY_STATUS true {now - t_start_s:.3f} s after the "
                f"start (bound {timeout_s:.3f} s, {polls} polls); {halted} — check the arm")
        clock.sleep_s(min(settings.poll_interval_s, deadline - now))
