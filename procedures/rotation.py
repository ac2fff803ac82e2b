"""The rotating marker (the paper's Figs. 9–15): radius and frequency of a marker on the 10 Hz rotor.

The rotor spins its marker (``targets.rotor``: centre, axis, radius) at ``rotation_hz``; the cameras
record ``record_s`` seconds of steady rotation. Truth: the ``rotation`` event (polled frequency, radius,
centre, axis) and the polled ``rotor`` events; the report gives the reconstructed trajectory, the radius
over time (Fig. 14) and the spectrum of the height (Fig. 15).

Run alone (``rig run rotation``) it first calibrates and synchronizes the cameras in the same run folder.
"""

from __future__ import annotations

from typing import Any

from procedures._alone import alone_plan, run_alone
from procedures.params.rotation import DESCRIPTION, NAME, Parameters  # noqa: F401 (its declaration)
from procedures.sync import rotor_step, spin_and_record
from rig.config.rig_config import RigConfig
from rig.run.acquire import Acquirer, ReduceOptions
from rig.run.plan import Plan
from rig.run.procedure import Context


def own_plan(params: Parameters, config: RigConfig, *, step_name: str = "rotation") -> Plan:
    return Plan(NAME, (rotor_step(step_name, config, rotation_hz=params.rotation_hz,
                                  record_s=params.record_s, source="rotation.rotation_hz"),))


def plan(params: Parameters, config: RigConfig) -> Plan:
    """calibrate, sync, then step ``rotation`` (the rotor at ``rotation_hz``); nothing is connected."""
    return alone_plan(NAME, own_plan(params, config), config)


def run_step(ctx: Context, params: Parameters, *, step_name: str = "rotation") -> None:
    with ctx.step(step_name) as step:
        if step.skipped:
            return
        planned = own_plan(params, ctx.config, step_name=step_name).vibration(step_name)
        with Acquirer(ctx, ReduceOptions(mode="detect")) as acq:
            spin_and_record(ctx, acq, step_name, planned, poll_interval_s=params.poll_interval_s)


def run(ctx: Context, params: Parameters) -> dict[str, Any]:
    return run_alone(ctx, params, run_step)[1]
