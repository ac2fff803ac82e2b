"""The rig clock behind one interface: wall time on a bench, virtual time on the simulated rig.

Everything on the rig (drivers, mock servers, procedures, the record) reads one clock, ``now_s()`` in
seconds (monotonic, arbitrary origin), and waits with ``sleep_s(d)``. ``is_virtual`` says which kind it
is; the run record's ``start`` document states it.

- :class:`WallClock` (``drivers.clock``): ``time.monotonic()`` / ``time.sleep()``.
- :class:`VirtualClock` (``drivers.sim.clock``): thread-safe simulated time; ``rate=None`` is *instant*
  (``sleep_s`` advances time at once), ``rate=r`` is *paced* (r virtual seconds per wall second).

Use :func:`make_clock` rather than the classes, so procedures never depend on which one they got.
"""

from __future__ import annotations

from drivers.clock import Clock, ClockError, WallClock, check_duration_s
from drivers.sim.clock import VirtualClock

__all__ = ["Clock", "ClockError", "VirtualClock", "WallClock", "check_duration_s", "make_clock"]


def make_clock(virtual: bool, *, rate: float | None = None, start_s: float = 0.0) -> Clock:
    """Return a :class:`VirtualClock` (``virtual=True``; ``rate`` None = instant, else virtual s per wall
    s; starting at ``start_s``) or a :class:`WallClock` (``virtual=False``; ``rate`` and ``start_s`` must
    then keep their defaults, since wall time can be neither paced nor shifted)."""
    if virtual:
        return VirtualClock(start_s=start_s, rate=rate)
    if rate is not None or start_s != 0.0:
        raise ClockError(f"a wall clock takes no rate or start_s (got rate={rate!r}, start_s={start_s!r}); "
                         "use virtual=True for simulated time")
    return WallClock()
