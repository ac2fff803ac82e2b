"""The oscillating plate (the paper's Figs. 3–8): every marker's trajectory at about 3.5 Hz.

The crank exciter drives the free end of the clamped plate (``targets.plate``) at ``frequency_hz`` with its
fixed amplitude (the crank radius); a marker at distance s from the clamp moves by that amplitude times
the cantilever shape (3ξ² − ξ³)/2, ξ = s / length. The cameras record ``record_s`` seconds of the steady
oscillation. Truth: the ``plate`` event (frequency actually polled, tip amplitude, the displacement axis,
the marker ids and each marker's amplitude) and the polled ``exciter`` events.

With ``targets.plate.body = "shaker"`` the generator drives the electrodynamic shaker at ``frequency_hz``
with peak displacement ``shaker_amplitude_mm`` (volts from the sensitivity table; the limits — frequency,
displacement, (2πf)²·x, velocity, the amplifier's volts — checked before any device is connected,
exit 4). The generator's reported CW frequency, volts and output state are polled as ``generator`` events;
the event's ``frequency_hz`` is their mean and ``amplitude_mm`` the displacement of the reported volts.

Run alone (``rig run plate``) it first calibrates and synchronizes the cameras in the same run folder,
then builds the report (trajectories, amplitude and frequency per marker).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from procedures._alone import alone_plan, run_alone
from procedures._common import (
    amplitude_of,
    hold_polling,
    mount,
    poll_event,
    required,
    run_at,
    stop_polled,
    vfd_config,
)
from procedures.params.plate import DESCRIPTION, NAME, Parameters  # noqa: F401 (its declaration)
from rig.config.rig_config import RigConfig
from rig.config.targets import PlateTarget
from rig.record.events import PlateEvent
from rig.run.acquire import Acquirer, Recording, ReduceOptions
from rig.run.plan import Plan, PlanStep, Vibration, shaker_limits
from rig.run.procedure import Context, ParameterError


def marker_amplitudes_mm(plate: PlateTarget, tip_mm: float) -> dict[str, float]:
    """Amplitude of every plate marker (mm): tip amplitude × (3ξ² − ξ³)/2 at its distance from the clamp."""
    out = {}
    for r in range(plate.rows):
        for c in range(plate.cols):
            xi = (c + 1) * plate.pitch_mm / plate.length_mm
            out[f"plate_r{r}c{c}"] = float(tip_mm * 0.5 * (3 * xi**2 - xi**3))
    return out


def _shaker_vibration(params: Parameters, config: RigConfig) -> Vibration:
    """The shaker at ``frequency_hz`` and ``shaker_amplitude_mm`` (volts from the sensitivity table)."""
    shaker = shaker_limits(config)
    f, amp, table = params.frequency_hz, params.shaker_amplitude_mm, shaker.sensitivity
    if not table.f_min_hz <= f <= table.f_max_hz:
        raise ParameterError("frequency_hz", f"{f:g} Hz is outside the shaker's sensitivity table "
                                             f"{table.f_min_hz:g}..{table.f_max_hz:g} Hz "
                                             "(devices.generator.sensitivity_mm_per_v; no extrapolation)")
    vpp = shaker.amplitude_vpp_for(f, amp)
    return Vibration("generator", ((0.0, f), (params.record_s, f)), amp, f"plate.frequency_hz = {f:g} Hz",
                     f"plate.shaker_amplitude_mm = {amp:g} mm", amplitude_vpp=(vpp, vpp))


def own_plan(params: Parameters, config: RigConfig, *, step_name: str = "plate") -> Plan:
    """Step ``plate``: its driving device at ``frequency_hz`` for ``record_s`` s."""
    body = required(config.targets.plate, "targets.plate").body
    if body == "shaker":
        vibration = _shaker_vibration(params, config)
        ramp_s = 0.0
    else:
        amplitude_mm, amplitude_from = amplitude_of(config, body)
        ramp = vfd_config(config, body).ramp_rate_hz_per_s
        f = params.frequency_hz
        vibration = Vibration(body, ((0.0, f), (params.record_s, f)), amplitude_mm,
                              f"plate.frequency_hz = {f:g} Hz", amplitude_from, max_slope_hz_per_s=ramp,
                              slope_from=f"devices.{body}.ramp_rate_hz_per_s = {ramp:g} Hz/s")
        ramp_s = 2 * f / ramp
    return Plan(NAME, (PlanStep(step_name, params.record_s + ramp_s, vibration=vibration),))


def plan(params: Parameters, config: RigConfig) -> Plan:
    """calibrate, sync, then step ``plate``; nothing is connected."""
    return alone_plan(NAME, own_plan(params, config), config)


def run_step(ctx: Context, params: Parameters, *, step_name: str = "plate") -> None:
    with ctx.step(step_name) as step:
        if step.skipped:
            return
        planned = own_plan(params, ctx.config, step_name=step_name).vibration(step_name)
        frequency_hz, record_s = planned.profile[0][1], planned.profile[-1][0]
        plate = required(ctx.config.targets.plate, "targets.plate")
        if plate.body == "shaker":
            shaker = ctx.shaker()
            mount(ctx, "plate")
            shaker.start(frequency_hz, planned.amplitude_mm)
            poll_event(ctx, "generator", shaker.read_state())
            with Acquirer(ctx, ReduceOptions(mode="track", window_px=41)) as acq:
                held = acq.record(step_name, lambda: hold_polling(
                    ctx, shaker.read_state, "generator", record_s=record_s,
                    poll_interval_s=params.poll_interval_s))
            # the displacement of the volts the generator reports at the frequency it reports
            _plate_event(ctx, plate, held, [s.frequency_hz for s in held.result], setpoint_hz=frequency_hz,
                         tip_mm=float(np.mean([s.displacement_mm for s in held.result])),
                         extra={"body": "shaker",
                                "amplitude_vpp": float(np.mean([s.amplitude_vpp for s in held.result]))})
            shaker.stop()  # amplitude ramped down, output OFF
            poll_event(ctx, "generator", shaker.read_state())
            return
        drive = ctx.vfd_axis(plate.body)
        mount(ctx, "plate")
        run_at(ctx, drive, "exciter", frequency_hz)
        with Acquirer(ctx, ReduceOptions(mode="track", window_px=41)) as acq:
            rec = acq.record(step_name, lambda: hold_polling(
                ctx, drive.read_sample, "exciter", record_s=record_s, poll_interval_s=params.poll_interval_s))
        _plate_event(ctx, plate, rec, [s.frequency_hz for s in rec.result], setpoint_hz=frequency_hz,
                     tip_mm=drive.amplitude_mm, extra={})
        stop_polled(ctx, drive, "exciter")


def _plate_event(ctx: Context, plate: PlateTarget, rec: Recording[Any], polled_hz: list[float], *,
                 setpoint_hz: float, tip_mm: float, extra: dict[str, Any]) -> None:
    """The ``plate`` truth event of recording ``rec`` (its polled frequencies ``polled_hz``, the tip
    amplitude ``tip_mm`` and each marker's, the axis)."""
    axis = plate.axis if plate.axis is not None else plate.normal
    amplitudes = marker_amplitudes_mm(plate, tip_mm)
    ctx.event("plate", PlateEvent(
        t_start_s=rec.t_start_s, t_stop_s=rec.t_stop_s, frequency_hz=float(np.mean(polled_hz)),
        setpoint_hz=setpoint_hz, amplitude_mm=tip_mm,
        axis=[float(v) / float(np.linalg.norm(axis)) for v in axis], marker_ids=list(amplitudes),
        marker_amplitudes_mm=amplitudes, segment=rec.segment, **extra))


def run(ctx: Context, params: Parameters) -> dict[str, Any]:
    return run_alone(ctx, params, run_step)[1]
