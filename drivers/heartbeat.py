"""Device heartbeat shared by the b-CAP, Modbus and SCPI drivers: is the device still answering?

Two parts, so the watchdog never disturbs the protocol:

* :class:`ContactRecord` — **passive**, kept by the link itself: the link lock (every request/reply
  exchange of the procedure holds it), the wall time (``time.monotonic``) of the last byte-level proof
  of life (every reply, including b-CAP ``S_EXECUTING`` keep-alives and Modbus exception responses), and
  a latched failure when the link was closed or broke.
* :class:`Heartbeat` — **active**, driven by the runner's watchdog thread through the device's
  ``heartbeat()``: it raises :class:`DeviceLostError` when the link failed or a request (the procedure's
  or a probe's) has been waiting for a reply for more than ``timeout_s`` — an idle link nobody asked is
  not lost, it gets probed; when the link has been idle for ``interval_s`` it starts one cheap probe (b-CAP
  ``CurPos``, Modbus STATUS read, SCPI ``*OPC?``) in a short-lived thread, **only if the link lock is
  free** (never beside a call in flight: a b-CAP request during a blocking Move would get E_BUSY_PROC).
  ``check()`` itself does no I/O and returns at once, so one dead device never delays the checks of the
  others. A device that goes silent is reported at most ``interval_s`` + ``timeout_s`` + one watchdog
  period after its last reply (at once when its link closes), with the watchdog checking at least once
  per ``interval_s``: the wait is counted on the checks' own cadence, a gap between two checks counting
  up to ``interval_s`` only — when this process did not run (a starved host; on the twin, the
  in-process mocks starve with it) a reply may be sitting unread, so that time is no evidence against
  the device. The hard bound after the controller stalls or dies is the devices' own communication-loss
  stop, not this. A latched link failure is cleared by the next reply (over a fresh link).

A call in flight whose protocol sends no keep-alives (b-CAP without WDT) is bounded by the link's own
receive timeout instead: ``ContactRecord.silent_calls`` is then True and the wait is not checked while
the lock is held.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable, Iterator

__all__ = ["ContactRecord", "DeviceLostError", "Heartbeat", "HeartbeatError", "check_heartbeat_timing"]

log = logging.getLogger(__name__)


class HeartbeatError(RuntimeError):
    """The watchdog's probe found the device unusable. ``device`` names it."""

    def __init__(self, device: str, message: str) -> None:
        self.device = device
        super().__init__(f"{device}: {message}")


class DeviceLostError(HeartbeatError):
    """``device`` asked but silent for ``unanswered_s`` s (> ``limit_s``), or its link failed (``cause``);
    ``age_s``: wall seconds since its last reply."""

    def __init__(self, device: str, age_s: float, limit_s: float, cause: str | None = None, *,
                 unanswered_s: float | None = None, detail: str | None = None) -> None:
        self.age_s, self.limit_s, self.cause, self.unanswered_s = age_s, limit_s, cause, unanswered_s
        waited = f" for {unanswered_s:.2f} s" if unanswered_s is not None else ""
        what = f"link failed ({cause})" if cause else f"no reply{waited}"
        more = f" ({detail})" if detail else ""
        super().__init__(device, f"lost: {what}; last contact {age_s:.2f} s ago (limit {limit_s:g} s){more}")


def check_heartbeat_timing(timeout_s: float, interval_s: float | None) -> tuple[float, float]:
    """Validate ``timeout_s`` (> 0 s) and ``interval_s`` (None → timeout/4; 0 < interval < timeout)."""
    if not (math.isfinite(timeout_s) and timeout_s > 0):
        raise ValueError(f"heartbeat timeout_s={timeout_s!r}: must be a finite number of seconds > 0")
    interval = timeout_s / 4.0 if interval_s is None else float(interval_s)
    if not (math.isfinite(interval) and 0 < interval < timeout_s):
        raise ValueError(f"heartbeat interval_s={interval_s!r}: must be > 0 s and below "
                         f"timeout_s={timeout_s:g}")
    return float(timeout_s), interval


class ContactRecord:
    """The link-level record (thread-safe), one per device. Devices sharing one line (several drives on
    one RS-485 bus) pass the same ``lock`` but keep their own contact times.

    ``lock`` is re-entrant: the probe holds it around a driver call that takes it again.
    """

    def __init__(self, lock: threading.RLock | None = None, *,
                 wall_s: Callable[[], float] = time.monotonic) -> None:
        self.lock = lock if lock is not None else threading.RLock()  # devices on one bus share it
        self.wall_s = wall_s  # the wall clock (seconds; tests inject one)
        self._last_contact = wall_s()
        self._waiting_since: float | None = None  # start of the oldest request not answered yet
        self._busy = 0
        self._failure: str | None = None
        self.silent_calls = False  # True when a call in flight legitimately sends nothing for long
        self.contacts = 0
        self.recovered_from: str | None = None  # the last failure a later reply cleared

    @contextlib.contextmanager
    def exchange(self) -> Iterator[None]:
        """Hold the link for one request/reply exchange (marks a call in flight). An exchange that ends
        in an exception leaves the request counted as unanswered until the next reply."""
        with self.lock:
            self._busy += 1
            if self._waiting_since is None:
                self._waiting_since = self.wall_s()
            ok = False
            try:
                yield
                ok = True
            finally:
                self._busy -= 1
                if ok and self._busy == 0:
                    self._waiting_since = None

    def touch(self) -> None:
        """A reply (or a keep-alive) arrived: the device is alive now (a call still in flight waits anew
        from now, e.g. for the next keep-alive)."""
        now = self.wall_s()
        self._last_contact = now
        self._waiting_since = now if self._busy else None
        self.contacts += 1
        if self._failure is not None:  # a reply on a fresh link (reconnected): the device is back
            self.recovered_from, self._failure = self._failure, None

    def fail(self, reason: str) -> None:
        """The link was closed or broke; latched until a reply arrives (on a fresh link: the closed
        transport itself does not come back), which clears it into :attr:`recovered_from`."""
        if self._failure is None:
            self._failure = reason

    @property
    def failure(self) -> str | None:
        return self._failure

    @property
    def busy(self) -> bool:
        return self._busy > 0

    def age_s(self) -> float:
        """Wall seconds since the last reply."""
        return self.wall_s() - self._last_contact

    @property
    def waiting_since_s(self) -> float | None:
        """Wall time (:attr:`wall_s`) the oldest unanswered request was sent, None when none is."""
        return self._waiting_since

    def unanswered_s(self) -> float:
        """Wall seconds the device has been asked without answering (0 when nothing is pending): an
        idle link is not a lost device until someone asks."""
        since = self._waiting_since
        return 0.0 if since is None else max(0.0, self.wall_s() - since)


class Heartbeat:
    """The active part (see the module docstring).

    Args:
        device: name used in errors ("robot", "exciter", ...).
        record: the link's :class:`ContactRecord`.
        probe: one cheap exchange through the driver (it takes ``record.lock`` itself); raises on failure;
            may return a text describing a device-reported fault (then ``check`` raises
            :class:`HeartbeatError` with it: the device answers but is not fit to run).
        timeout_s: a device silent for longer is lost (wall seconds).
        interval_s: idle time after which a probe is sent (default ``timeout_s / 4``).

    Making the device safe after a loss is the runner's job (it stops every device at once after an
    interlock); the heartbeat only reports.
    """

    def __init__(self, device: str, record: ContactRecord, probe: Callable[[], object], *,
                 timeout_s: float = 2.0, interval_s: float | None = None) -> None:
        self.device = device
        self.record = record
        self.probe = probe
        self.timeout_s, self.interval_s = check_heartbeat_timing(timeout_s, interval_s)
        self._probing = threading.Lock()
        self._beat_lock = threading.Lock()
        self._last_check_s: float | None = None  # wall time of the previous check
        self._wait_seen: float | None = None  # the wait (its start) the previous check saw
        self._unanswered_beat_s = 0.0  # that wait's length on the beat clock
        self.probes_sent = 0
        self.probe_errors: list[str] = []
        self.device_problem: str | None = None

    def check(self) -> bool:
        """Raise :class:`DeviceLostError` if the device is lost (:class:`HeartbeatError` if its last probe
        found a device fault); else maybe start a probe; return True."""
        rec = self.record
        age = rec.age_s()
        if rec.failure is not None:
            raise DeviceLostError(self.device, age, self.timeout_s, rec.failure)
        if self.device_problem is not None:
            raise HeartbeatError(self.device, self.device_problem)
        if rec.busy and rec.silent_calls:
            return True  # a call without keep-alives in flight: bounded by the link's own timeout
        unanswered = self._unanswered_on_beat_clock()
        if unanswered > self.timeout_s:
            detail = f"last probe: {self.probe_errors[-1]}" if self.probe_errors else None
            raise DeviceLostError(self.device, age, self.timeout_s, unanswered_s=unanswered, detail=detail)
        if age > self.interval_s and not rec.busy and self._probing.acquire(blocking=False):
            threading.Thread(target=self._probe, name=f"heartbeat-{self.device}", daemon=True).start()
        return True

    def _unanswered_on_beat_clock(self) -> float:
        """How long the pending request has waited, counted on the checks' own progress: the wall time
        between two checks counts up to ``interval_s``, no more. A longer gap means this process was not
        running (a starved host, or the interpreter busy elsewhere): a reply may be sitting unread, and an
        in-process mock (the twin) was starved alike, so that time is no evidence against the device.
        With the watchdog checking every 0.25 s the count equals the wall time."""
        now = self.record.wall_s()
        since = self.record.waiting_since_s
        with self._beat_lock:
            last, self._last_check_s = self._last_check_s, now
            if since is None:
                self._wait_seen, self._unanswered_beat_s = None, 0.0
            elif since != self._wait_seen or last is None:  # a wait that began after the last check
                self._wait_seen = since
                self._unanswered_beat_s = min(max(0.0, now - since), self.interval_s)
            else:
                self._unanswered_beat_s += min(max(0.0, now - last), self.interval_s)
            return self._unanswered_beat_s

    def verify(self) -> bool:
        """One probe now, in the caller's thread (waiting for the link lock): for ``rig check``, which
        must know the device answers rather than that nothing is pending. Raises like :meth:`check`."""
        with self.record.lock:
            try:
                problem = self.probe()
            except Exception as exc:
                raise DeviceLostError(self.device, self.record.age_s(), self.timeout_s, self.record.failure,
                                      detail=f"probe failed: {type(exc).__name__}: {exc}") from exc
        if isinstance(problem, str) and problem:
            raise HeartbeatError(self.device, problem)
        return self.check()

    def _probe(self) -> None:
        try:
            if not self.record.lock.acquire(blocking=False):
                return  # the procedure is talking to the device: its reply is the proof of life
            try:
                self.probes_sent += 1
                problem = self.probe()
                # a fault the drive reports now; cleared by a later clean probe (after a fault reset)
                self.device_problem = problem if isinstance(problem, str) and problem else None
            except Exception as exc:  # the age (or the latched failure) decides; keep the reason
                self.probe_errors.append(f"{type(exc).__name__}: {exc}")
                del self.probe_errors[:-5]
                log.warning("%s heartbeat probe failed: %s: %s", self.device, type(exc).__name__, exc)
            finally:
                self.record.lock.release()
        finally:
            self._probing.release()
