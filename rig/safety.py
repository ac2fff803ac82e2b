"""Safety pieces of the runner: bringing every device to a safe state, the heartbeat watchdog, and the
mapping from what went wrong to an exit code.

Exit codes of ``rig``: 0 pass, 1 certificate failed, 2 aborted (Ctrl-C), 3 interlock or hardware fault
(also an unexpected error inside a procedure: the rig state is then unknown, which is a fault), 4 bad
input (configuration, parameters, a device the procedure needs but the rig lacks).

Device duck-typing (what the runner calls, when present):

- ``safe_state()`` — the device's own "make safe" (exciter/rotor: output off, frequency 0; generator:
  output off; arm: halt and release). Preferred.
- ``stop()`` / ``halt()`` — used when there is no ``safe_state()``.
- ``heartbeat()`` — called by the watchdog thread every ``period_s`` and at every checkpoint; must be
  thread-safe and return within about a second; returns False or raises when the device is lost (the
  drivers' heartbeats return at once: see ``drivers/heartbeat.py``).

The shutdown order is: vibration sources (exciter, rotor, generator/shaker) first, then the arm, then
everything else (cameras…). Every device is attempted even if an earlier one fails; each failure is
returned (and recorded by the runner).
"""

from __future__ import annotations

import logging
import threading
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from drivers.denso.arm import LimitError as ArmLimitError
from drivers.exciter.limits import LimitError as ExciterLimitError
from rig.config_schema import ConfigError
from rig.procedure import Abort, InterlockTripped

log = logging.getLogger("rig.safety")

EXIT_PASS, EXIT_CERTIFICATE_FAILED, EXIT_ABORTED, EXIT_FAULT, EXIT_BAD_INPUT = 0, 1, 2, 3, 4
_FIRST = ("exciter", "rotor", "generator", "shaker")
_ARM = ("robot", "arm")


def shutdown_order(names: list[str]) -> list[str]:
    """Vibration sources first, then the arm, then the rest (each group in the given order)."""
    first = [n for n in names if any(k in n for k in _FIRST)]
    arm = [n for n in names if n not in first and any(k in n for k in _ARM)]
    return first + arm + [n for n in names if n not in first and n not in arm]


@dataclass
class SafeStateResult:
    device: str
    action: str  # "safe_state" | "stop" | "halt" | "none"
    error: str | None = None


def make_safe(devices: dict[str, Any]) -> list[SafeStateResult]:
    """Bring every device to its safe state (see module docstring); never raises."""
    results = []
    for name in shutdown_order(list(devices)):
        dev = devices[name]
        action = next((a for a in ("safe_state", "stop", "halt") if callable(getattr(dev, a, None))), "none")
        if action == "none":
            results.append(SafeStateResult(name, action))
            continue
        try:
            getattr(dev, action)()
            results.append(SafeStateResult(name, action))
        except BaseException as exc:
            log.error("safe state of %s failed: %s", name, exc, exc_info=True)
            results.append(SafeStateResult(name, action, f"{type(exc).__name__}: {exc}"))
    return results


# Driver exceptions that mean "a limit/envelope check refused a command" (nothing was sent).
INTERLOCK_ERROR_TYPES: tuple[type[BaseException], ...] = (InterlockTripped, ArmLimitError, ExciterLimitError)


@dataclass
class Classified:
    exit_code: int
    exit_status: str  # success | abort | fail
    outcome: str  # pass | certificate_failed | aborted | interlock | fault | bad_input
    reason: str
    interlock_device: str | None = None


def classify(exc: BaseException | None, verdict_passed: bool | None, verdict_summary: str = "") -> Classified:
    """Map the end of a procedure (an exception or a verdict) to exit code, stop status and reason."""
    if exc is None:
        if verdict_passed is False:
            return Classified(EXIT_CERTIFICATE_FAILED, "success", "certificate_failed",
                              verdict_summary or "certificate failed")
        return Classified(EXIT_PASS, "success", "pass", verdict_summary or "completed")
    if isinstance(exc, INTERLOCK_ERROR_TYPES):
        device = next((getattr(exc, a) for a in ("device", "quantity", "axis") if getattr(exc, a, None)),
                      "limits")
        return Classified(EXIT_FAULT, "abort", "interlock", f"interlock: {exc}", str(device))
    if isinstance(exc, KeyboardInterrupt):
        return Classified(EXIT_ABORTED, "abort", "aborted", "aborted at once (second Ctrl-C)")
    if isinstance(exc, Abort):
        return Classified(EXIT_ABORTED, "abort", "aborted", exc.reason)
    if isinstance(exc, ConfigError):
        return Classified(EXIT_BAD_INPUT, "fail", "bad_input", f"bad input: {exc}")
    return Classified(EXIT_FAULT, "fail", "fault", f"{type(exc).__name__}: {exc}")


def format_exception(exc: BaseException) -> str:
    return "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))


def check_heartbeats(devices: dict[str, Any]) -> tuple[str, str] | None:
    """Call every device's ``heartbeat()``; the first (device, reason) lost, or None. The drivers' own
    heartbeats do no I/O in the caller (``drivers/heartbeat.py``), so checkpoints may call this too."""
    for name, dev in devices.items():
        beat = getattr(dev, "heartbeat", None)
        if not callable(beat):
            continue
        try:
            ok = beat()
        except Exception as exc:
            return name, f"lost heartbeat: {type(exc).__name__}: {exc}"
        if ok is False:
            return name, "lost heartbeat: device reports the link is down"
    return None


class Watchdog:
    """Background thread: every ``period_s`` wall seconds, call each device's ``heartbeat()`` and the
    ``extra_checks`` (returning ``[(device, reason)]``). The first failure calls ``on_trip(device, reason)``
    once and the watchdog stops."""

    def __init__(self, devices: dict[str, Any], on_trip: Callable[[str, str], None], *,
                 period_s: float = 0.25,
                 extra_checks: Callable[[], list[tuple[str, str]]] | None = None) -> None:
        self._devices = {n: d for n, d in devices.items() if callable(getattr(d, "heartbeat", None))}
        self._extra = extra_checks
        self._on_trip = on_trip
        self._period_s = float(period_s)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="rig-watchdog", daemon=True)
        self.tripped: tuple[str, str] | None = None

    def start(self) -> Watchdog:
        if self._devices or self._extra:
            self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)

    def poll_once(self) -> tuple[str, str] | None:
        """One round of checks; returns the first (device, reason) that failed, or None."""
        lost = check_heartbeats(self._devices)
        if lost is not None:
            return lost
        if self._extra is not None:
            trips = self._extra()
            if trips:
                return trips[0]
        return None

    def _loop(self) -> None:
        while not self._stop.wait(self._period_s):
            try:
                trip = self.poll_once()
            except Exception as exc:
                trip = ("watchdog", f"interlock check failed: {type(exc).__name__}: {exc}")
            if trip is not None:
                self.tripped = trip
                self._on_trip(*trip)
                return
