"""Frequency sweep: constant amplitude, frequency rising monotonically to 30 Hz (the paper's Figs. 16–19).

The crank exciter shakes the sweep column (``targets.sweep_column``) with its fixed amplitude (the crank
radius) while its frequency follows a monotone profile from ``start_hz`` to ``max_hz`` in ``duration_s``
(then holds ``hold_s`` at ``max_hz``). ``shape="fig17"`` rises slowly first and faster later, like the
time–frequency characteristic of the paper's Fig. 17 (slopes 0.4, 1.0, 1.2 and 1.4 × the mean slope over
the four quarters); ``"linear"`` and ``"log"`` are the plain alternatives. Every profile point and the
steepest slope are checked before anything moves (exit 3, nothing sent) against the limits of the device
that drives the column's ``body``: ``[limits.exciter]`` for the crank exciter, ``[limits.generator]`` for
the shaker (fed by the generator). The sweep itself follows a setpoint profile, which only the VFD exciter
takes: a column on the shaker is refused after the limits check (exit 4, nothing sent) — the shaker sweeps
at constant volts, so its displacement follows its sensitivity table, not a constant amplitude.

Truth: the ``sweep`` event (commanded profile in rig time, amplitude, axis, marker ids) and the polled
actual frequencies as ``exciter`` events. The cameras record the whole sweep.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from drivers.exciter.sweep import LogSweep, PointsSweep, SweepProfile
from procedures._acquire import Acquirer, ReduceOptions
from procedures._common import drive_of, mount, poll_event, require_target, run_alone, stop_polled
from rig.procedure import ParameterError, param

NAME = "sweep"
DESCRIPTION = "Constant amplitude, frequency rising monotonically to 30 Hz (Fig. 17): error vs frequency."
FIG17 = ((0.0, 0.0), (0.25, 0.10), (0.5, 0.35), (0.75, 0.65), (1.0, 1.0))  # (t/T, (f − f0)/(f1 − f0))


@dataclass(frozen=True)
class Parameters:
    start_hz: float = field(default=1.0, metadata=param(lo=0.1, hi=1000.0, doc="first frequency, Hz"))
    max_hz: float = field(default=30.0, metadata=param(lo=0.1, hi=1000.0, doc="peak frequency, Hz"))
    duration_s: float = field(default=24.0, metadata=param(lo=0.5, hi=3600.0, doc="rise time, s"))
    hold_s: float = field(default=1.0, metadata=param(lo=0.0, hi=600.0, doc="hold at the peak, s"))
    shape: str = field(default="fig17", metadata=param(choices=("fig17", "linear", "log"),
                                                       doc="profile of the rise"))
    update_interval_s: float = field(default=0.5, metadata=param(lo=0.05, hi=10.0,
                                                                 doc="setpoint update interval, s"))

    def __post_init__(self) -> None:
        if self.max_hz <= self.start_hz:
            raise ValueError(f"max_hz={self.max_hz:g} must exceed start_hz={self.start_hz:g} "
                             "(a rising sweep)")


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


def check_plan(ctx: Any, params: Parameters) -> SweepProfile:
    """Limits of every profile point and of the steepest slope, before anything moves, for the device
    that drives ``targets.sweep_column.body`` (LimitError, exit 3); a shaker column is then refused
    (ParameterError, exit 4: the profile sweep needs the VFD exciter)."""
    column = require_target(ctx, "sweep_column")
    drive = drive_of(ctx, column)
    profile = profile_of(params)
    points = profile.points(params.update_interval_s)
    if column.body == "shaker":
        # no fixed amplitude: frequency and slope against [limits.generator] (the shaker's limits)
        for t_s, f_hz in points:
            drive.limits.check_frequency(f_hz, f"shaker sweep at t = {t_s:g} s")
        drive.limits.check_ramp_rate(profile.max_slope_hz_per_s(), "shaker sweep slope")
        raise ParameterError("targets.sweep_column.body", "the sweep procedure follows a frequency "
                             "profile at the crank's constant amplitude, which only body = \"exciter\" "
                             "takes; the shaker (body = \"shaker\") is not supported here")
    for t_s, f_hz in points:
        drive.check_frequency(f_hz, f"{column.body} sweep at t = {t_s:g} s")
    drive.limits.check_ramp_rate(profile.max_slope_hz_per_s(), f"{column.body} sweep slope")
    return profile


def run_step(ctx: Any, params: Parameters, *, step_name: str = "sweep") -> None:
    """Carry the sweep out as step ``step_name`` (skipped on --resume when done)."""
    with ctx.step(step_name) as step:
        if step.skipped:
            return
        profile = check_plan(ctx, params)
        column = require_target(ctx, "sweep_column")
        exciter = drive_of(ctx, column)
        mount(ctx, "sweep_column")
        ctx.progress(None, f"sweep: exciter to {profile.start_hz:g} Hz")
        poll_event(ctx, "exciter", exciter.set_frequency(profile.start_hz, wait=True))

        def on_sample(sample: Any) -> None:
            poll_event(ctx, "exciter", sample)
            ctx.progress(min(1.0, sample.frequency_hz / profile.stop_hz),
                         f"sweep: {sample.frequency_hz:.2f} Hz")

        with Acquirer(ctx, ReduceOptions(mode="track", window_px=51)) as acq:
            rec = acq.record(step_name, lambda: exciter.sweep(
                profile, update_interval_s=params.update_interval_s, on_sample=on_sample))
        result = rec.result
        ctx.event("sweep", {"t_start_s": result.t_start_s, "t_stop_s": result.t_stop_s,
                            "amplitude_mm": exciter.amplitude_mm, "axis": list(column.axis),
                            "marker_ids": [f"col{k}" for k in range(column.count)],
                            "profile": [list(p) for p in result.profile], "segment": step_name,
                            "recording": [rec.t_start_s, rec.t_stop_s]})
        stop_polled(ctx, exciter, "exciter")


def run(ctx: Any, params: Parameters) -> dict[str, Any]:
    return run_alone(ctx, params, check_plan, run_step)[1]
