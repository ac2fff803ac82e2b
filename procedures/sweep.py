"""Frequency sweep: constant amplitude, frequency rising monotonically to 30 Hz (the paper's Figs. 16–19).

The crank exciter shakes the sweep column (``targets.sweep_column``) with its fixed amplitude (the crank
radius) while its frequency follows a monotone profile from ``start_hz`` to ``max_hz`` in ``duration_s``
(then holds ``hold_s`` at ``max_hz``). ``shape="fig17"`` rises slowly first and faster later, like the
time–frequency characteristic of the paper's Fig. 17 (slopes 0.4, 1.0, 1.2 and 1.4 × the mean slope over
the four quarters); ``"linear"`` and ``"log"`` are the plain alternatives. Every profile point and the
steepest slope are checked before any device is connected (:func:`plan`; exit 4) against the limits of
the device that drives the column's ``body``: ``[limits.exciter]`` for the crank exciter,
``[limits.generator]`` for the shaker (fed by the generator).

Exciter (``body = "exciter"``): timed setpoint updates follow the profile at the crank's amplitude.
Shaker (``body = "shaker"``), at the constant displacement ``shaker_amplitude_mm`` (it has no crank):
``shape = "linear"`` or ``"log"`` is the generator's own phase-continuous sweep at constant volts, then
``hold_s`` at ``max_hz`` with the sweep off — constant displacement only where the sensitivity table is
flat, so a table varying by more than ``FLAT_SENSITIVITY_TOLERANCE`` over the sweep is refused
(ParameterError naming ``devices.generator.sensitivity_mm_per_v``, exit 4); ``shape = "fig17"`` (a points
profile the built-in sweep cannot follow) runs as phase-continuous CW frequency steps every
``update_interval_s`` (:mod:`procedures._shaker`: each step at the profile's mean frequency over it, volts
per step from the table). A sweep outside the sensitivity table is refused (exit 4). Before any device is
connected: frequency, displacement, (2πf)²·x, velocity, slope and the amplifier's volts (exit 4).

Truth: the ``sweep`` event (commanded profile in rig time, amplitude, axis, marker ids) and the polled
actual frequencies as ``exciter`` events; for the shaker, the generator cannot report its instantaneous
sweep frequency, so the profile is the commanded law or staircase (``profile_source`` says so) and the
generator's reported state, CW frequency and sweep settings are polled as ``generator`` events. The
cameras record the whole sweep.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

from drivers.exciter.shaker import Shaker
from drivers.exciter.sweep import FrequencySample, LogSweep, PointsSweep, SweepProfile
from procedures._alone import alone_plan, run_alone
from procedures._common import (
    amplitude_of,
    mount,
    poll_event,
    required,
    run_at,
    stop_polled,
    vfd_config,
)
from procedures._shaker import StaircaseRun, arm_first_step, follow_staircase, phase_origin, staircase_plan
from procedures.params.sweep import DESCRIPTION, NAME, Parameters  # noqa: F401 (its declaration)
from rig.config.rig_config import RigConfig
from rig.config.targets import SweepColumnTarget
from rig.record.events import SweepEvent
from rig.run.acquire import Acquirer, ReduceOptions
from rig.run.plan import GeneratorSweep, Plan, PlanStep, Vibration, shaker_limits
from rig.run.procedure import Context, ParameterError

FLAT_SENSITIVITY_TOLERANCE = 0.005  # max (s_max − s_min)/s_min of the shaker table over a sweep (0.5 %)
FIG17 = ((0.0, 0.0), (0.25, 0.10), (0.5, 0.35), (0.75, 0.65), (1.0, 1.0))  # (t/T, (f − f0)/(f1 − f0))


def profile_of(params: Parameters) -> SweepProfile:
    """The commanded profile (time from the sweep's start, s → Hz)."""
    f0, f1, T = params.start_hz, params.max_hz, params.duration_s
    if params.shape == "log":
        rise: list[tuple[float, float]] = list(LogSweep(f0, f1, T).points(params.update_interval_s))
    elif params.shape == "linear":
        rise = [(0.0, f0), (T, f1)]
    else:
        rise = [(u * T, f0 + v * (f1 - f0)) for u, v in FIG17]
    if params.hold_s > 0:
        rise.append((T + params.hold_s, f1))
    return PointsSweep(rise)


def _origins(params: Parameters) -> tuple[str, str]:
    """What the frequency and the slope follow from (the ``frequency_from``, ``slope_from`` of the plan)."""
    return (f"sweep.max_hz = {params.max_hz:g} Hz",
            f"sweep.start_hz = {params.start_hz:g} Hz, sweep.max_hz = {params.max_hz:g} Hz, "
            f"sweep.duration_s = {params.duration_s:g} s, sweep.shape = {params.shape}")


def _exciter_vibration(params: Parameters, body: str, config: RigConfig) -> tuple[Vibration, float]:
    """The VFD-driven column: the profile's setpoints every ``update_interval_s`` at the body's amplitude;
    the duration adds the ramp to ``start_hz`` and the stop at the drive's configured rate."""
    profile = profile_of(params)
    amplitude_mm, amplitude_from = amplitude_of(config, body)
    ramp = vfd_config(config, body).ramp_rate_hz_per_s
    frequency_from, slope_from = _origins(params)
    vibration = Vibration(body, tuple(profile.points(params.update_interval_s)), amplitude_mm,
                          frequency_from=frequency_from, amplitude_from=amplitude_from,
                          max_slope_hz_per_s=profile.max_slope_hz_per_s(), slope_from=slope_from)
    return vibration, profile.duration_s + (params.start_hz + params.max_hz) / ramp


def shaker_vibration(params: Parameters, config: RigConfig) -> Vibration:
    """The shaker at ``shaker_amplitude_mm``: the generator's own sweep at constant volts (linear, log:
    the sensitivity table must be flat over it), or a staircase of CW steps with the volts of each
    (fig17). Outside the table, or a table not flat enough: ParameterError (exit 4)."""
    shaker = shaker_limits(config)
    table, amp = shaker.sensitivity, params.shaker_amplitude_mm
    f0, f1 = params.start_hz, params.max_hz
    if not (table.f_min_hz <= f0 and f1 <= table.f_max_hz):
        raise ParameterError("devices.generator.sensitivity_mm_per_v",
                             f"the shaker sweep {f0:g}..{f1:g} Hz leaves the sensitivity table "
                             f"{table.f_min_hz:g}..{table.f_max_hz:g} Hz (no extrapolation)")
    profile = profile_of(params)
    points = profile.points(params.update_interval_s)
    frequency_from, slope_from = _origins(params)
    common = Vibration("generator", tuple(points), amp, frequency_from=frequency_from,
                       amplitude_from=f"sweep.shaker_amplitude_mm = {amp:g} mm",
                       max_slope_hz_per_s=profile.max_slope_hz_per_s(), slope_from=slope_from)
    if params.shape == "fig17":  # stepped: every step's frequency with the volts for the amplitude there
        steps = staircase_plan(points, params.update_interval_s)
        stairs = [(t, f) for t, f in steps] + [(points[-1][0], steps[-1][1])]
        return dataclasses.replace(common, profile=tuple(stairs),
                                   amplitude_vpp=tuple(shaker.amplitude_vpp_for(f, amp) for _, f in stairs))
    knots = [f0, f1, *(f for f, _ in table.points if f0 < f < f1)]
    sens = [table.mm_per_v(f) for f in knots]
    spread = (max(sens) - min(sens)) / min(sens)
    if spread > FLAT_SENSITIVITY_TOLERANCE:
        raise ParameterError("devices.generator.sensitivity_mm_per_v",
                             f"the sensitivity varies by {100 * spread:.3g} % over {f0:g}..{f1:g} Hz; the "
                             "generator sweeps at constant volts, so the displacement would not be "
                             f"constant: at most {100 * FLAT_SENSITIVITY_TOLERANCE:g} % is allowed (narrow "
                             "the sweep, use shape = \"fig17\" — stepped, volts per step — or the exciter)")
    vpp = shaker.amplitude_vpp_for(f0, amp)
    return dataclasses.replace(common, amplitude_vpp=tuple(vpp for _ in points),
                               generator_sweep=GeneratorSweep(f0, f1, params.duration_s, params.shape, vpp))


def own_plan(params: Parameters, config: RigConfig, *, step_name: str = "sweep") -> Plan:
    """Step ``sweep``: the column's driving device over the whole profile (hold included)."""
    body = required(config.targets.sweep_column, "targets.sweep_column").body
    if body == "shaker":
        vibration = shaker_vibration(params, config)
        duration_s = vibration.duration_s
    else:
        vibration, duration_s = _exciter_vibration(params, body, config)
    return Plan(NAME, (PlanStep(step_name, duration_s, vibration=vibration),))


def plan(params: Parameters, config: RigConfig) -> Plan:
    """calibrate, sync, then step ``sweep``; nothing is connected."""
    return alone_plan(NAME, own_plan(params, config), config)


def run_step(ctx: Context, params: Parameters, *, step_name: str = "sweep") -> None:
    """Carry the sweep out as step ``step_name`` (skipped on --resume when done)."""
    with ctx.step(step_name) as step:
        if step.skipped:
            return
        planned = own_plan(params, ctx.config, step_name=step_name).vibration(step_name)
        column = required(ctx.config.targets.sweep_column, "targets.sweep_column")
        if column.body == "shaker":
            _run_shaker(ctx, params, column, step_name)
            return
        profile = PointsSweep(planned.profile)  # the setpoints checked before the station was opened
        exciter = ctx.vfd_axis(column.body)
        mount(ctx, "sweep_column")
        ctx.progress(None, f"sweep: exciter to {profile.start_hz:g} Hz")
        run_at(ctx, exciter, "exciter", profile.start_hz)

        def on_sample(sample: FrequencySample) -> None:
            poll_event(ctx, "exciter", sample)
            ctx.progress(min(1.0, sample.frequency_hz / profile.stop_hz),
                         f"sweep: {sample.frequency_hz:.2f} Hz")

        with Acquirer(ctx, ReduceOptions(mode="track", window_px=51)) as acq:
            rec = acq.record(step_name, lambda: exciter.sweep(
                profile, update_interval_s=params.update_interval_s, on_sample=on_sample))
        result = rec.result
        ctx.event("sweep", SweepEvent(
            t_start_s=result.t_start_s, t_stop_s=result.t_stop_s, amplitude_mm=exciter.amplitude_mm,
            axis=list(column.axis), marker_ids=[f"col{k}" for k in range(column.count)],
            profile=[list(p) for p in result.profile], segment=step_name,
            recording=[rec.t_start_s, rec.t_stop_s]))
        stop_polled(ctx, exciter, "exciter")


def _run_shaker(ctx: Context, params: Parameters, column: SweepColumnTarget, step_name: str) -> None:
    """The generator's own sweep at constant displacement; ``generator`` events polled throughout."""
    shaker = ctx.shaker()
    mount(ctx, "sweep_column")
    f0, f1, T = params.start_hz, params.max_hz, params.duration_s

    def on_poll() -> None:
        poll_event(ctx, "generator", shaker.read_state())

    ctx.progress(None, f"sweep: shaker {params.shape} sweep {f0:g} → {f1:g} Hz in {T:g} s")
    if params.shape == "fig17":
        _run_shaker_steps(ctx, params, column, shaker, step_name=step_name, on_poll=on_poll)
        return
    with Acquirer(ctx, ReduceOptions(mode="track", window_px=51)) as acq:
        rec = acq.record(step_name, lambda: shaker.sweep(
            f0, f1, T, spacing=params.shape, amplitude_mm=params.shaker_amplitude_mm, hold_s=params.hold_s,
            poll_interval_s=params.update_interval_s, on_poll=on_poll))
    result = rec.result
    t0 = result.t_start_s
    # the generator's sweep law, sampled densely enough that straight lines between points follow it: a
    # chord of the log law runs ahead of it by ≤ (ln(f1/f0)·Δ/T)²/8 relative, which the phase accumulates
    # over the sweep's N cycles (≈ ⅔ of that × N cycles: with Δ = T/2000, 5e-5 cycles = 0.02° for 1 → 30 Hz;
    # a 0.05-s floor had let a 6-s sweep's reference lead by 0.25°, a spurious 0.06-ms delay); 2000 points
    law = LogSweep(f0, f1, T).points(T / 2000) if params.shape == "log" else [(0.0, f0), (T, f1)]
    profile = [[t0 + t, f] for t, f in law] + [list(p) for p in result.profile if p[0] > t0 + T]
    ctx.event("sweep", SweepEvent(
        t_start_s=t0, t_stop_s=result.t_stop_s, amplitude_mm=params.shaker_amplitude_mm,
        axis=list(column.axis), marker_ids=[f"col{k}" for k in range(column.count)], profile=profile,
        segment=step_name, recording=[rec.t_start_s, rec.t_stop_s], body="shaker",
        amplitude_vpp=result.amplitude_vpp, spacing=result.spacing,
        profile_source="commanded: the generator's built-in sweep (start, stop, time, spacing; "
                       "phase-continuous), which it does not report instant by instant; its reported "
                       "settings and state are the generator events"))
    poll_event(ctx, "generator", shaker.read_state())  # the sweep ended with amplitude down, output OFF


def _run_shaker_steps(ctx: Context, params: Parameters, column: SweepColumnTarget, shaker: Shaker, *,
                      step_name: str, on_poll: Callable[[], None]) -> None:
    """The Fig. 17 points profile as timed frequency steps (:mod:`procedures._shaker`), armed at the first
    step with the output OFF so that the recording's phase restart makes the staircase's phase law exact."""
    profile = profile_of(params)
    points = profile.points(params.update_interval_s)
    plan = staircase_plan(points, params.update_interval_s)
    arm_first_step(shaker, plan[0][1], params.shaker_amplitude_mm)
    with Acquirer(ctx, ReduceOptions(mode="track", window_px=51)) as acq:
        fiducial = acq.fiducial

        def drive() -> tuple[StaircaseRun, tuple[float, float], str]:
            origin, how = phase_origin(ctx, shaker, fiducial)
            return follow_staircase(ctx, shaker, plan, total_s=points[-1][0],
                                    amplitude_mm=params.shaker_amplitude_mm, on_step=on_poll,
                                    origin_s=0.5 * (origin[0] + origin[1])), origin, how

        rec = acq.record(step_name, drive)
    result, origin, how = rec.result
    ctx.event("sweep", SweepEvent(
        t_start_s=result.t_start_s, t_stop_s=result.t_stop_s, amplitude_mm=params.shaker_amplitude_mm,
        axis=list(column.axis), marker_ids=[f"col{k}" for k in range(column.count)],
        profile=[list(p) for p in result.profile], segment=step_name,
        recording=[rec.t_start_s, rec.t_stop_s], body="shaker", amplitude_vpp=result.amplitude_vpp,
        spacing="steps",
        profile_source=f"commanded staircase: phase-continuous CW frequency steps every "
                       f"{params.update_interval_s:g} s, each at the Fig. 17 profile's mean frequency over "
                       "its step (volts per step from the sensitivity table), at the times the commands "
                       "were sent, from the phase restart at the first profile time",
        phase_origin_s=list(origin), phase_origin=how,
        step_brackets_s=[list(b) for b in result.brackets]))
    poll_event(ctx, "generator", shaker.read_state())  # after the stop: amplitude down, output OFF


def run(ctx: Context, params: Parameters) -> dict[str, Any]:
    return run_alone(ctx, params, run_step)[1]
