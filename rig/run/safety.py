"""Safety pieces of the runner: bringing every device to a safe state, the stop signals, the heartbeat
watchdog, and the mapping from what went wrong to an exit code.

Exit codes of ``rig`` (one meaning each; :func:`rig.cli.main` owns the mapping): 0 pass, 1 certificate
failed (FAIL or INCOMPLETE: not a pass), 2 aborted (a stop signal: SIGINT, SIGTERM, SIGHUP, SIGQUIT), 3
interlock, hardware or I/O fault (also an unexpected error inside a procedure: the rig state is then
unknown, which is a fault), 4 bad input (configuration, parameters, command line, a device the procedure
needs but the rig lacks, a run folder that cannot be resumed).

Devices are what :mod:`drivers.roles` says: the station declares each one's role
(:class:`drivers.roles.Assignment`), and the shutdown order is :data:`drivers.roles.SHUTDOWN_ORDER` —
generator output, then the VFD axes (exciter, rotor), then the arm, then the cameras; within a role, the
station's order. Every device is attempted even if an earlier one fails; each outcome is returned (and
recorded by the runner). Names never decide anything.
"""

from __future__ import annotations

import logging
import threading
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from drivers.denso.arm import LimitError as ArmLimitError
from drivers.exciter.limits import LimitError as ExciterLimitError
from drivers.roles import Assignment, shutdown_rank
from rig.config.schema import ConfigError
from rig.run.exit_codes import (  # noqa: F401 — re-exported: the runner's outcomes map to them
    EXIT_ABORTED,
    EXIT_BAD_INPUT,
    EXIT_CERTIFICATE_FAILED,
    EXIT_FAULT,
    EXIT_PASS,
    STOP_SIGNALS,
    Interrupted,
)
from rig.run.procedure import Abort, InterlockTripped, StationView

log = logging.getLogger("rig.run.safety")


def abort_reason(signal_name: str) -> str:
    """The stop document's reason for an abort by ``signal_name`` (first signal)."""
    if signal_name == "SIGINT":
        return "aborted by the operator (Ctrl-C)"
    return f"aborted by {signal_name}"


class StationLike(StationView, Protocol):
    """What the runner needs of a station (:class:`rig.run.station.Station` and the tests' stations), on
    top of what the procedure sees of it."""

    def roster(self) -> list[Assignment]:
        """Every device the runner must make safe, with its declared role (cameras included)."""
        ...

    def snapshot(self) -> dict[str, Any]: ...

    def check_interlocks(self) -> list[tuple[str, str]]:
        """(device, reason) of every device found lost or beyond a limit, without device I/O."""
        ...


def shutdown_order(roster: Sequence[Assignment]) -> list[Assignment]:
    """By role (:data:`drivers.roles.SHUTDOWN_ORDER`), the station's order within a role."""
    return sorted(roster, key=lambda a: shutdown_rank(a.role))  # sorted() is stable


@dataclass
class SafeStateResult:
    device: str
    role: str
    error: str | None = None


def make_safe(roster: Sequence[Assignment]) -> list[SafeStateResult]:
    """``safe_state()`` of every device in :func:`shutdown_order`; never raises, never skips one."""
    results = []
    for entry in shutdown_order(roster):
        try:
            entry.device.safe_state()
            results.append(SafeStateResult(entry.name, entry.role.value))
        except BaseException as exc:  # a second signal here must not skip the remaining devices
            log.error("safe state of %s failed: %s", entry.name, exc, exc_info=True)
            results.append(SafeStateResult(entry.name, entry.role.value, f"{type(exc).__name__}: {exc}"))
    return results


# Driver exceptions that mean "a limit/envelope check refused a command" (nothing was sent).
INTERLOCK_ERROR_TYPES: tuple[type[BaseException], ...] = (InterlockTripped, ArmLimitError, ExciterLimitError)


def _interlock_subject(exc: BaseException) -> str:
    """What the interlock document names: the device of a trip, the quantity or axis a limit refused."""
    if isinstance(exc, InterlockTripped):
        return exc.device
    if isinstance(exc, ExciterLimitError):
        return exc.quantity
    if isinstance(exc, ArmLimitError):
        return exc.axis
    return "limits"


@dataclass
class Classified:
    exit_code: int
    exit_status: str  # success | abort | fail
    outcome: str  # pass | certificate_failed | aborted | interlock | fault | bad_input
    reason: str
    interlock_device: str | None = None


def classify(exc: BaseException | None, verdict_passed: bool | None, verdict_summary: str = "",
             certificate_result: str | None = None) -> Classified:
    """Map the end of a procedure (an exception or a verdict) to exit code, stop status and reason.
    ``certificate_result`` (PASS / FAIL / INCOMPLETE, when the procedure issued a certificate) decides
    over the verdict: an INCOMPLETE certificate is not a pass (exit 1, outcome ``incomplete``)."""
    if exc is None:
        if certificate_result == "INCOMPLETE":
            return Classified(EXIT_CERTIFICATE_FAILED, "success", "incomplete",
                              f"certificate INCOMPLETE: {verdict_summary or 'not every criterion evaluated'}")
        if verdict_passed is False or certificate_result == "FAIL":
            return Classified(EXIT_CERTIFICATE_FAILED, "success", "certificate_failed",
                              verdict_summary or "certificate failed")
        return Classified(EXIT_PASS, "success", "pass", verdict_summary or "completed")
    if isinstance(exc, INTERLOCK_ERROR_TYPES):
        return Classified(EXIT_FAULT, "abort", "interlock", f"interlock: {exc}", _interlock_subject(exc))
    if isinstance(exc, KeyboardInterrupt):
        name = exc.signal_name if isinstance(exc, Interrupted) else "SIGINT"
        again = "second Ctrl-C" if name == "SIGINT" else f"second signal, {name}"
        return Classified(EXIT_ABORTED, "abort", "aborted", f"aborted at once ({again})")
    if isinstance(exc, Abort):
        return Classified(EXIT_ABORTED, "abort", "aborted", exc.reason)
    if isinstance(exc, ConfigError):
        return Classified(EXIT_BAD_INPUT, "fail", "bad_input", f"bad input: {exc}")
    return Classified(EXIT_FAULT, "fail", "fault", f"{type(exc).__name__}: {exc}")


def format_exception(exc: BaseException) -> str:
    return "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))


LOST_HEARTBEAT = "lost heartbeat"  # how an interlock on a device that stopped answering begins


def heartbeat_states(roster: Sequence[Assignment], results: Sequence[SafeStateResult],
                     interlock: tuple[str, str] | None) -> dict[str, str]:
    """The stop document's ``heartbeats``: after the safe stop, each device probed once more
    (``heartbeat(wait=True)``): ``answering``; ``recovered`` — answering again after the interlock found
    it lost (a transient loss: the interlock and its exit code stand, the state says the device is back);
    ``lost: why``; ``not probed`` when its safe state failed (that failure is recorded). Never raises."""
    failed = {r.device for r in results if r.error}
    lost_before = interlock[0] if interlock is not None and interlock[1].startswith(LOST_HEARTBEAT) else None
    states: dict[str, str] = {}
    for entry in roster:
        if entry.name in failed:
            states[entry.name] = "not probed (its safe state failed)"
            continue
        try:
            answering = entry.device.heartbeat(wait=True) is not False
        except Exception as exc:
            states[entry.name] = f"lost: {type(exc).__name__}: {exc}"
            continue
        if not answering:
            states[entry.name] = "lost: device reports the link is down"
        else:
            states[entry.name] = "recovered" if entry.name == lost_before else "answering"
    return states


def check_heartbeats(roster: Sequence[Assignment], *, wait: bool = False) -> tuple[str, str] | None:
    """Call every device's ``heartbeat()``; the first (device, reason) lost, or None. The drivers' own
    heartbeats do no I/O in the caller (``drivers/heartbeat.py``), so checkpoints may call this too;
    ``wait=True`` probes each device now instead (after the procedure ended: the links are free)."""
    for entry in roster:
        try:
            ok = entry.device.heartbeat(wait=True) if wait else entry.device.heartbeat()
        except Exception as exc:
            return entry.name, f"{LOST_HEARTBEAT}: {type(exc).__name__}: {exc}"
        if ok is False:
            return entry.name, f"{LOST_HEARTBEAT}: device reports the link is down"
    return None


class Watchdog:
    """Background thread: every ``period_s`` wall seconds, call each device's ``heartbeat()`` and the
    ``extra_checks`` (returning ``[(device, reason)]``). The first failure calls ``on_trip(device, reason)``
    once. It keeps polling until :meth:`stop` — after a trip, and in :meth:`quiet` mode while the runner
    makes the devices safe — because the heartbeats' probes of idle links are also what keeps every drive's
    communication-loss stop from firing while another device is being brought to rest."""

    def __init__(self, roster: Sequence[Assignment], on_trip: Callable[[str, str], None], *,
                 period_s: float = 0.25,
                 extra_checks: Callable[[], list[tuple[str, str]]] | None = None) -> None:
        self._devices = list(roster)
        self._extra = extra_checks
        self._on_trip = on_trip
        self._period_s = float(period_s)
        self._stop = threading.Event()
        self._quiet = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="rig-watchdog", daemon=True)
        self.tripped: tuple[str, str] | None = None

    def start(self) -> Watchdog:
        if self._devices or self._extra:
            self._thread.start()
        return self

    def quiet(self) -> None:
        """Keep polling (probes keep idle links alive) but trip no more: cleanup has begun."""
        self._quiet.set()

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
            if trip is not None and self.tripped is None and not self._quiet.is_set():
                self.tripped = trip
                self._on_trip(*trip)
