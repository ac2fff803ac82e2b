"""The dashboard of one ``rig run`` / ``rig certify``: state, server and frame tap wired to the runner.

``live = LiveDashboard(module, config, host=..., port=...)``; give the runner ``observers=(live.observe,)``
and ``progress=live.progress(bar)``, then ``live.attach(runner)`` (Abort → ``runner.request_abort``). The
server starts when the run's ``start`` document is written (a run refused before it has no dashboard) and
its URL is printed on stderr; if it cannot start (port taken) the run goes on without it, with a warning.
``live.close()`` after the run lets connected pages receive the final state (≤ 1 s), then stops serving.
With the server, the live stereo preview (:mod:`rig.dashboard.live_stereo`) follows the plan's rotor and
sweep recordings in its own thread.
"""

from __future__ import annotations

import logging
import sys
import types
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from rig.config.rig_config import RigConfig
from rig.dashboard.live_stereo import LiveStereo, segments_of
from rig.dashboard.server import DashboardServer
from rig.dashboard.state import DashboardState
from rig.run.frame_tap import FRAMES
from rig.run.runner import Runner

if TYPE_CHECKING:
    from rig.run.plan import Plan

__all__ = ["LiveDashboard", "plan_steps", "run_state"]

log = logging.getLogger("rig.dashboard.server")


def run_plan(module: types.ModuleType, config: RigConfig, parameters: dict[str, Any]) -> Plan | None:
    """The procedure's plan for these recorded parameters (None without a plan, or when it cannot be made:
    the runner validated them; a view must not fail the run)."""
    from rig.run.plan import plan_of
    from rig.run.procedure import validate_parameters

    try:
        return plan_of(module, validate_parameters(module, parameters), config)
    except Exception as exc:
        log.warning("dashboard: no plan for the progress estimate: %s", exc)
        return None


def plan_steps(module: types.ModuleType, config: RigConfig,
               parameters: dict[str, Any]) -> list[tuple[str, float]]:
    """``[(step, duration_s)]`` of the procedure's plan for these recorded parameters ([] without a plan)."""
    plan = run_plan(module, config, parameters)
    return [] if plan is None else [(s.name, float(s.duration_s)) for s in plan.steps]


def run_state(module: types.ModuleType, config: RigConfig) -> DashboardState:
    """The state of one run of ``module``, its steps timed by the plan (the page and the terminal read it)."""
    return DashboardState(module.NAME, plan_steps=lambda start: plan_steps(
        module, config, start.get("parameters") or {}))


class LiveDashboard:
    """See the module docstring. ``host``/``port``/``allow_remote`` as :class:`DashboardServer`."""

    def __init__(self, module: types.ModuleType, config: RigConfig, *, host: str = "127.0.0.1", port: int = 0,
                 allow_remote: bool = False, stream: TextIO | None = None) -> None:
        self.module, self.config = module, config
        self.state = run_state(module, config)
        self.server = DashboardServer(self.state, host=host, port=port, allow_remote=allow_remote,
                                      on_abort=self._abort)
        self.stream = stream or sys.stderr
        self._request_abort: Callable[[str], None] | None = None
        self._runs_dir: Path | None = None
        self.live_stereo: LiveStereo | None = None
        self.started = False

    def attach(self, runner: Runner) -> None:
        self._request_abort = runner.request_abort
        self._runs_dir = runner.runs_dir

    def _abort(self, reason: str) -> None:
        if self._request_abort is not None:
            self._request_abort(reason)

    def observe(self, document: dict[str, Any]) -> None:
        """The record observer: fold the document in; on the first ``start``, start serving."""
        if document.get("type") == "start" and not self.started:
            self.started = True
            try:
                self.server.start()
                FRAMES.reset()
                FRAMES.enabled = True
                print(f"rig: dashboard at {self.server.url} (--no-dashboard to turn it off)",
                      file=self.stream, flush=True)
            except OSError as exc:
                log.warning("the dashboard could not start on %s:%s: %s; the run goes on without it",
                            self.server.host, self.server.port, exc)
            else:
                self._start_live_stereo(document)
        self.state.on_document(document)

    def _start_live_stereo(self, start: dict[str, Any]) -> None:
        """The live stereo preview of the plan's rotor and sweep recordings (none without a plan)."""
        plan = run_plan(self.module, self.config, start.get("parameters") or {})
        segments = {} if plan is None else segments_of(plan)
        if not segments or self._runs_dir is None or not start.get("run_id"):
            return
        self.live_stereo = LiveStereo(self.state, self._runs_dir / str(start["run_id"]), segments)
        self.live_stereo.start()

    def progress(self, inner: Callable[[float | None, str], None]) -> Callable[[float | None, str], None]:
        """A progress callback feeding the dashboard and then ``inner`` (the terminal's bar)."""
        def both(fraction: float | None, message: str) -> None:
            try:
                self.state.on_progress(fraction, message)
            except Exception:
                log.warning("dashboard progress update failed", exc_info=True)
            inner(fraction, message)
        return both

    def close(self) -> None:
        FRAMES.enabled = False
        if self.live_stereo is not None:
            self.live_stereo.close()
        if self.server.port and self.started:
            try:
                self.server.close(linger_s=1.0)
            except Exception:
                log.warning("closing the dashboard failed", exc_info=True)
