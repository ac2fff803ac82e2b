"""The run's progress on the terminal, drawn from the dashboard's state (:class:`DashboardState`): the same
step count and time remaining (the plan's estimate, :mod:`rig.run.plan`) as the page.

On a terminal (stderr a tty), one line redrawn in place, at most every ``redraw_s`` of the injected clock::

    [#########---------------------]  31 % step 2 of 5: sync 40 % · ≈ 3 min 10 s left · spinning

Otherwise (output captured: a file, CI, journald) plain lines, never a carriage return: one when a step
begins, one when it is done, and one per 10 % of a long step (planned ≥ ``long_step_s``), each prefixed with
the time since the run began by the injected clock::

    rig: +   12 s step 2 of 5: sync began (planned ≈ 1 min 30 s; ≈ 4 min 10 s left)

While a step reports the work it does after its motion (:class:`rig.run.progress.Processing`: reducing a
recording's frames, which the plan does not time), the line shows that work's own bar and count instead of
the step's fraction, and the plan's time left after it (a log line per 10 % of a long such work)::

    [############------------------]       step 3 of 3: sweep · sweep: reducing frames 1,234/≈2,880 · …

Feed it after the state: ``observe`` is a record observer placed after the state's own, ``progress`` the
runner's progress callback called after :meth:`DashboardState.on_progress`.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from typing import Any, TextIO

from rig.dashboard.state import DashboardState, Overview

__all__ = ["TerminalProgress", "duration_text"]

LINE_WIDTH = 120


def duration_text(seconds: float | None) -> str:
    """``"3 min 05 s"`` / ``"42 s"`` as the page writes it; ``"—"`` for None."""
    if seconds is None or not math.isfinite(seconds):
        return "—"
    s = max(0, round(seconds))
    minutes, rest = divmod(s, 60)
    return f"{minutes} min {rest:02d} s" if minutes else f"{rest} s"


class TerminalProgress:
    """See the module docstring.

    Args:
        state: the run's dashboard state (already fed the document or progress this is called with).
        stream: where to write (default ``sys.stderr``).
        is_terminal: draw in place (True) or write log lines (False); default ``stream.isatty()``.
        clock: monotonic seconds (injected in tests), for the redraw rate and the elapsed time.
        long_step_s: a step planned at least this long (rig time, s) is logged per 10 %.
        long_work_items: work after a motion of at least this many items (frames of all cameras: 1000 ≈ 8 s
            of two 60 fps cameras) is logged per 10 % of it.
        redraw_s: the least time between two in-place redraws of a step's progress.
    """

    def __init__(self, state: DashboardState, stream: TextIO | None = None, *,
                 is_terminal: bool | None = None, clock: Callable[[], float] = time.monotonic,
                 long_step_s: float = 30.0, long_work_items: int = 1000, redraw_s: float = 0.1,
                 width: int = 30) -> None:
        self.state = state
        self.stream = stream or sys.stderr
        self.is_terminal = self.stream.isatty() if is_terminal is None else is_terminal
        self.clock = clock
        self.long_step_s = long_step_s
        self.redraw_s = redraw_s
        self.width = width
        self._began_s: float | None = None
        self._last_draw_s = -math.inf
        self._logged_tenths: dict[str, int] = {}  # step → the last 10 % mark logged
        self._logged_processing: dict[str, tuple[int, int]] = {}  # step → (10 % mark logged, items done)
        self.long_work_items = long_work_items
        self._shown = False

    # ---------------------------------------------------------------- inputs
    def observe(self, document: dict[str, Any]) -> None:
        """A record observer (after the state's): a step's begin and end."""
        if self._began_s is None and document.get("type") == "start":
            self._began_s = self.clock()
        if document.get("type") != "step":
            if self.is_terminal:  # the rig time moved on: the time remaining of a step without a fraction
                self._draw_throttled()
            return
        name, begun = str(document.get("name")), document.get("status") == "begin"
        overview = self.state.overview()
        if self.is_terminal:
            self._draw(overview)
            return
        duration_s = overview.duration_of(name) or 0.0
        planned = f"planned ≈ {duration_text(duration_s)}; " if begun and duration_s > 0 else ""
        self._log(f"{self._step_label(overview, name)} {'began' if begun else 'done'} "
                  f"({planned}≈ {duration_text(overview.remaining_s)} left)")

    def progress(self, fraction: float | None, message: str) -> None:
        """The runner's progress callback (after the state's): the running step's fraction and message."""
        if self.is_terminal:
            self._draw_throttled()
            return
        overview = self.state.overview()
        step = overview.step
        if step is not None and overview.processing is not None:  # after a motion: per 10 % of a long work
            done, total = overview.processing
            key = f"{step} (after its motion)"
            last_tenths, last_done = self._logged_processing.get(key, (-1, 0))
            if done < last_done:  # the step's next recording
                last_tenths = -1
            tenths = math.floor(min(1.0, done / total) * 10 + 1e-9) if total > 0 else 0
            self._logged_processing[key] = (max(tenths, last_tenths), done)
            if total >= self.long_work_items and tenths > last_tenths:
                self._log(f"{self._step_label(overview, step)} — {message} (not timed by the plan)")
            return
        if step is None or fraction is None or (overview.duration_of(step) or 0.0) < self.long_step_s:
            return
        tenths = math.floor(fraction * 10 + 1e-9)  # 10 %, 20 %, … 90 %; the step's end has its own line
        if tenths >= 10 or tenths <= self._logged_tenths.get(step, 0):
            return
        self._logged_tenths[step] = tenths
        text = f" — {message}" if message else ""
        self._log(f"{self._step_label(overview, step)} {tenths * 10} %{text} "
                  f"(≈ {duration_text(overview.remaining_s)} left)")

    def close(self) -> None:
        """End the in-place line (before anything else is printed)."""
        if self._shown:
            self.stream.write("\n")
            self.stream.flush()
            self._shown = False

    # ---------------------------------------------------------------- drawing
    @staticmethod
    def _step_label(overview: Overview, step: str) -> str:
        number = overview.number_of(step)
        if number is None:
            return f"step {step}"
        # without a plan the steps are known only as they begin: no "of n"
        return (f"step {number} of {overview.step_count}: {step}" if overview.total_s > 0
                else f"step {number}: {step}")

    def _log(self, text: str) -> None:
        elapsed = 0.0 if self._began_s is None else self.clock() - self._began_s
        self.stream.write(f"rig: +{duration_text(elapsed):>10s} {text}\n")
        self.stream.flush()

    def _draw_throttled(self) -> None:
        now = self.clock()
        if now - self._last_draw_s >= self.redraw_s:
            self._last_draw_s = now
            self._draw(self.state.overview())

    def _draw(self, overview: Overview) -> None:
        if overview.processing is not None and overview.step is not None:
            self._write_line(self._processing_line(overview))
            return
        overall = overview.overall_fraction
        if overall is None:
            bar = "?" * self.width
            head = f"[{bar}]     "
        else:
            filled = round(overall * self.width)
            head = f"[{'#' * filled}{'-' * (self.width - filled)}] {overall * 100:3.0f} %"
        if overview.step is None:
            where = "between steps"
        else:
            where = self._step_label(overview, overview.step)
            if overview.fraction is not None:
                where += f" {overview.fraction * 100:.0f} %"
        parts = [f"{head} {where}", f"≈ {duration_text(overview.remaining_s)} left"]
        if overview.message:
            parts.append(overview.message)
        self._write_line(" · ".join(parts))

    def _processing_line(self, overview: Overview) -> str:
        """The step's work after its motion (not timed by the plan): its own bar and count, then the time
        the plan gives the steps after it."""
        assert overview.processing is not None and overview.step is not None
        done, total = overview.processing
        filled = round(min(1.0, done / total) * self.width) if total > 0 else 0
        after = (f"then ≈ {duration_text(overview.remaining_s)} left" if overview.remaining_s
                 else "the plan's last step")
        return " · ".join([f"[{'#' * filled}{'-' * (self.width - filled)}]       "
                           f"{self._step_label(overview, overview.step)}", overview.message, after])

    def _write_line(self, line: str) -> None:
        self.stream.write("\r" + line[:LINE_WIDTH].ljust(LINE_WIDTH))
        self.stream.flush()
        self._shown = True
