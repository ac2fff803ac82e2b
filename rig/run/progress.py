"""Progress messages with structure: the work a step does after its motion, which the plan does not time.

A procedure's progress callback takes ``(fraction | None, message)``; ``fraction`` is the step's motion
done. After the motion a step may still work for a while (the Acquirer reducing a recording's frames when
its cameras are read after ``stop()``): it reports ``(None, Processing(...))``, a message that is also plain
text for any view, and carries ``done`` of ``total`` items, so a view can show that work and its count
instead of a finished step with no time left (:mod:`rig.dashboard.state`, :mod:`rig.dashboard.terminal`).
"""

from __future__ import annotations

__all__ = ["Processing"]


class Processing(str):
    """``"<what> <done>/<total>"``, e.g. ``"sweep: reducing frames 1,234/≈2,880"``; ``total`` may be an
    estimate (``approximate``: then written ``≈``, and ``done`` may pass it)."""

    done: int
    total: int

    def __new__(cls, what: str, done: int, total: int, *, approximate: bool = False) -> Processing:
        text = f"{what} {done:,}/{'≈' if approximate else ''}{total:,}"
        message = super().__new__(cls, text)
        message.done, message.total = int(done), int(total)
        return message

    @property
    def fraction(self) -> float | None:
        """``done / total`` in 0–1 (None without a total)."""
        return min(1.0, self.done / self.total) if self.total > 0 else None
