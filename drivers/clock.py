"""The rig clock: one monotonic time base, in seconds, shared by every device and procedure.

Drivers take a ``clock`` argument (anything with the :class:`Clock` methods) and never call
:func:`time.sleep` directly for device timing, so the same code runs on the bench with a
:class:`WallClock` and on the simulated rig with ``drivers.sim.clock.VirtualClock``.
"""

from __future__ import annotations

import math
import time
from typing import Protocol, runtime_checkable

__all__ = ["Clock", "ClockError", "WallClock", "check_duration_s"]


class ClockError(ValueError):
    """A clock was asked something impossible (negative or non-finite duration, time going backwards)."""


def check_duration_s(duration_s: float, name: str = "duration_s") -> float:
    """Return ``duration_s`` as float; raise :class:`ClockError` unless it is finite and ≥ 0."""
    value = float(duration_s)
    if not math.isfinite(value) or value < 0.0:
        raise ClockError(f"{name} must be a finite number of seconds ≥ 0, got {duration_s!r}")
    return value


@runtime_checkable
class Clock(Protocol):
    """Monotonic time in seconds plus a sleep that respects it."""

    def now_s(self) -> float:
        """Current time in seconds (monotonic; origin arbitrary but shared by the whole rig)."""
        ...

    def sleep_s(self, duration_s: float) -> None:
        """Wait ``duration_s`` seconds (≥ 0) of this clock's time."""
        ...

    @property
    def is_virtual(self) -> bool:
        """True for simulated time (recorded as ``"virtual"`` in the run record)."""
        ...


class WallClock:
    """The real clock: :func:`time.monotonic` and :func:`time.sleep`."""

    @property
    def is_virtual(self) -> bool:
        return False

    def now_s(self) -> float:
        return time.monotonic()

    def sleep_s(self, duration_s: float) -> None:
        time.sleep(check_duration_s(duration_s))

    def __repr__(self) -> str:
        return "WallClock()"
