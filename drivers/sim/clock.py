"""Virtual time for the simulated rig, shared by the procedure thread and the mock servers' threads.

Two modes:

* **instant** (``rate=None``): time stands still until someone sleeps or calls ``advance_to``.
  ``sleep_s(d)`` moves the clock to ``max(now, t_call + d)`` at once, without real waiting. When several
  threads sleep at the same moment the clock ends at the latest of their wake-up times (not at the sum).
* **paced** (``rate=r``): virtual time = ``start_s + r × (wall seconds since construction)``;
  ``sleep_s(d)`` waits ``d / r`` real seconds. ``rate=1`` is real time, ``rate=10`` ten times faster.

All methods are thread-safe. Threads may block in :meth:`VirtualClock.wait_until` until another thread
advances the clock (instant mode) or until the time arrives (paced mode).
"""

from __future__ import annotations

import math
import threading
import time

from drivers.clock import ClockError, check_duration_s

__all__ = ["ClockError", "VirtualClock"]


class VirtualClock:
    """Simulated rig time in seconds (see module docstring for the two modes)."""

    def __init__(self, start_s: float = 0.0, rate: float | None = None) -> None:
        start = float(start_s)
        if not math.isfinite(start):
            raise ClockError(f"start_s must be finite, got {start_s!r}")
        if rate is not None:
            rate = float(rate)
            if not math.isfinite(rate) or rate <= 0.0:
                raise ClockError(f"rate must be a finite number > 0 (virtual s per wall s) or None, "
                                 f"got {rate!r}")
        self._start_s = start
        self._rate = rate
        self._now_s = start  # instant mode only
        self._wall0_s = time.monotonic()
        self._cond = threading.Condition()

    @property
    def is_virtual(self) -> bool:
        return True

    @property
    def rate(self) -> float | None:
        """Virtual seconds per wall second in paced mode; None in instant mode."""
        return self._rate

    @property
    def is_instant(self) -> bool:
        return self._rate is None

    def now_s(self) -> float:
        if self._rate is None:
            with self._cond:
                return self._now_s
        return self._start_s + self._rate * (time.monotonic() - self._wall0_s)

    def advance_to(self, t_s: float) -> None:
        """Instant mode: move the clock to ``t_s`` if that is later than now (never backwards)."""
        target = float(t_s)
        if not math.isfinite(target):
            raise ClockError(f"t_s must be finite, got {t_s!r}")
        if self._rate is not None:
            raise ClockError("advance_to is only allowed in instant mode (rate=None); this clock is paced")
        with self._cond:
            if target > self._now_s:
                self._now_s = target
                self._cond.notify_all()

    def sleep_s(self, duration_s: float) -> None:
        """Let ``duration_s`` (≥ 0) virtual seconds pass (instantly, or paced by ``rate``)."""
        d = check_duration_s(duration_s)
        if self._rate is None:
            with self._cond:
                target = self._now_s + d
                if target > self._now_s:
                    self._now_s = target
                    self._cond.notify_all()
            return
        time.sleep(d / self._rate)

    def sleep_until_s(self, t_s: float) -> None:
        """Sleep until the clock reads ``t_s`` (no-op if it already does)."""
        self.sleep_s(max(0.0, float(t_s) - self.now_s()))

    def wait_until(self, t_s: float, timeout_s: float | None = None) -> bool:
        """Block (really) until the clock reaches ``t_s`` by other threads' doing; True if it did.

        In instant mode this does not advance the clock itself (use :meth:`sleep_until_s` for that);
        ``timeout_s`` is in wall seconds.
        """
        target = float(t_s)
        if self._rate is not None:
            wait = max(0.0, (target - self.now_s()) / self._rate)
            if timeout_s is not None and wait > timeout_s:
                time.sleep(check_duration_s(timeout_s, "timeout_s"))
                return False
            time.sleep(wait)
            return True
        with self._cond:
            return self._cond.wait_for(lambda: self._now_s >= target, timeout=timeout_s)

    def __repr__(self) -> str:
        mode = "instant" if self._rate is None else f"paced×{self._rate:g}"
        return f"VirtualClock({mode}, now_s={self.now_s():.6f})"
