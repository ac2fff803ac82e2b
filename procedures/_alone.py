"""A measurement procedure run on its own (``rig run NAME``): calibrate and sync in the same run folder,
then the procedure's own steps, then the report."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

from procedures import calibrate, sync
from procedures._report import REPORT_STEP, evaluated_summary, report_step
from rig.config.rig_config import RigConfig
from rig.run.plan import Plan
from rig.run.procedure import Context

T = TypeVar("T")
P = TypeVar("P")


def alone_plan(procedure: str, own: Plan, config: RigConfig) -> Plan:
    """The plan of a measurement procedure run on its own: calibrate and sync (their defaults), its own
    steps, then the report."""
    return Plan(procedure, calibrate.plan(calibrate.Parameters(), config).steps
                + sync.plan(sync.Parameters(), config).steps + own.steps + (REPORT_STEP,))


def run_alone(ctx: Context, params: P, run_steps: Callable[[Context, P], T]) -> tuple[T, dict[str, Any]]:
    """A measurement procedure run on its own (``rig run NAME``; its whole plan, :func:`alone_plan`, was
    checked against the limits before the station was opened): calibrate and sync in the same run folder,
    the procedure's own steps and the report. Returns what ``run_steps`` returned and the procedure's
    result (``summary`` of the criteria evaluated, ``report`` path)."""
    calibrate.run_step(ctx, calibrate.Parameters())
    sync.run_step(ctx, sync.Parameters())
    done = run_steps(ctx, params)
    result = report_step(ctx)
    return done, {"summary": evaluated_summary(result), "report": result["report"],
                  "passed": result["passed"], "certificate_result": result["certificate_result"]}
