"""A points profile (the paper's Fig. 17) on the shaker: timed, phase-continuous frequency steps.

The generator's built-in sweep is linear or log only. A piecewise-linear profile f(t) is approximated by
a staircase: every ``step_s`` seconds the CW frequency is set (a SCPI ``FREQ`` change on a running sine is
phase-continuous) to the profile's **mean** frequency over that step, so the phase at the end of every step
equals the profile's; the volts follow the sensitivity table so that the displacement stays
``amplitude_mm`` at every step. The staircase actually commanded (times at which each command was sent,
steps as two points at one time) is the truth the procedure records.

Phase: the first step is armed with the output OFF (:func:`arm_first_step`), so the recording's
``PHASe:SYNChronize`` (the timing fiducial on the generator's other channel, or the step's own command:
:func:`phase_origin`) restarts channel 1 at phase 0 at the first step's frequency; from that instant every
phase-continuous FREQ change makes the generator's phase φ(t) = 2π∫f dt of the staircase exact, up to the
instant of each change, which the controller brackets (``StaircaseRun.brackets``: sent, returned).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from drivers.exciter.shaker import Shaker
from rig.run.fiducial import FiducialRecording
from rig.run.procedure import Context

__all__ = ["StaircaseRun", "arm_first_step", "follow_staircase", "phase_origin", "staircase_plan"]


def _cycles(tp: np.ndarray, fp: np.ndarray, t: float) -> float:
    """∫ f dt (cycles) of the piecewise-linear profile from tp[0] to ``t`` (tp[0] ≤ t ≤ tp[-1])."""
    k = int(np.clip(np.searchsorted(tp, t, side="right") - 1, 0, len(tp) - 2))
    seg = 0.5 * (fp[1:] + fp[:-1]) * np.diff(tp)
    dt, width = t - tp[k], tp[k + 1] - tp[k]
    slope = (fp[k + 1] - fp[k]) / width if width > 0 else 0.0
    return float(seg[:k].sum() + fp[k] * dt + 0.5 * slope * dt * dt)


def staircase_plan(points: Sequence[tuple[float, float]], step_s: float) -> list[tuple[float, float]]:
    """``[(t_s from the start, f_hz), ...]``: one step every ``step_s`` s (the last may be shorter), each at
    the profile's mean frequency over the step. ``points``: (t_s, f_hz) with t_s rising from 0."""
    if not (math.isfinite(step_s) and step_s > 0):
        raise ValueError(f"step_s={step_s!r}: must be > 0 s")
    tp = np.array([p[0] for p in points], float)
    fp = np.array([p[1] for p in points], float)
    if len(tp) < 2 or np.any(np.diff(tp) < 0) or tp[0] != 0:
        raise ValueError("points: at least two (t_s, f_hz) with t_s rising from 0")
    total = float(tp[-1])
    n = max(1, math.ceil(total / step_s - 1e-9))
    out = []
    for k in range(n):
        a, b = k * step_s, min((k + 1) * step_s, total)
        out.append((a, (_cycles(tp, fp, b) - _cycles(tp, fp, a)) / (b - a)))
    return out


@dataclass(frozen=True)
class StaircaseRun:
    """What was commanded: rig-clock start/stop, the staircase ``profile`` [(t_s, f_hz)] (from the phase
    origin when one is given), volts [min, max], and each frequency change's bracket [sent, returned] (s)."""

    t_start_s: float
    t_stop_s: float
    profile: list[tuple[float, float]]
    amplitude_vpp: list[float]
    brackets: list[tuple[float, float]] = field(default_factory=list)


def arm_first_step(shaker: Shaker, frequency_hz: float, amplitude_mm: float) -> None:
    """Output OFF, channel 1 at the first step's frequency (its phase generator runs, nothing moves), so
    that a later ``PHASe:SYNChronize`` restarts it at phase 0 there; limits checked first."""
    shaker.check_point(frequency_hz, shaker.amplitude_vpp_for(frequency_hz, amplitude_mm))
    shaker.prepare()
    shaker.generator.set_frequency_hz(frequency_hz)


def phase_origin(ctx: Context, shaker: Shaker,
                 fiducial: FiducialRecording | None) -> tuple[tuple[float, float], str]:
    """The instant channel 1's phase restarted at 0, as a bracket (sent, confirmed) on the rig clock, and how
    it is known: the timing fiducial's ``PHASe:SYNChronize`` when it runs on the generator's other channel
    (the cameras are dated against the same instant, so the bracket's width cancels), else the command
    issued here (known to its bracket only)."""
    if fiducial is not None and fiducial.last_start is not None and fiducial.running \
            and fiducial.shaker_channel != fiducial.config.channel:
        return fiducial.last_start, (
            "PHASe:SYNChronize of the timing fiducial (the generator's other channel, one timebase): the "
            "cameras are dated against the same instant, so the bracket's width cancels; what remains is the "
            "fiducial's fit and the channels' alignment")
    t_sent = ctx.clock.now_s()
    shaker.generator.synchronize_phase()
    shaker.generator.wait_complete()
    return (t_sent, ctx.clock.now_s()), ("PHASe:SYNChronize issued by the step without a timing fiducial: "
                                         "the origin is known to the command's bracket only")


def follow_staircase(ctx: Context, shaker: Shaker, plan: Sequence[tuple[float, float]], *, total_s: float,
                     amplitude_mm: float, on_step: Callable[[], None] | None = None,
                     origin_s: float | None = None) -> StaircaseRun:
    """Start the shaker at the first step's frequency (amplitude ramped up), then retune at every step's
    time (rig clock, waiting through ``ctx.sleep_s``, an abort point), hold the last until ``total_s``,
    then ramp down and switch the output OFF. ``on_step()`` after every command (e.g. a generator poll).
    ``origin_s``: the rig time channel 1's phase restarted at the first step's frequency (the profile then
    starts there: its phase law holds from it); else the profile starts when the output was switched on."""
    vpps = [shaker.start(plan[0][1], amplitude_mm)]
    t0 = ctx.clock.now_s()
    profile = [(t0 if origin_s is None else origin_s, plan[0][1])]
    brackets: list[tuple[float, float]] = []
    sent: list[float] = []  # when each frequency command returned

    def frequency_set() -> None:
        sent.append(ctx.clock.now_s())

    if on_step is not None:
        on_step()
    for (t_rel, f_hz), (_, f_prev) in zip(plan[1:], plan[:-1], strict=True):
        if (wait := t0 + t_rel - ctx.clock.now_s()) > 0:
            ctx.sleep_s(wait)
        t_before = ctx.clock.now_s()
        sent.clear()
        vpps.append(shaker.retune(f_hz, amplitude_mm, frequency_set=frequency_set))
        bracket = (t_before, sent[0] if sent else ctx.clock.now_s())
        t_cmd = 0.5 * (bracket[0] + bracket[1])
        brackets.append(bracket)
        profile += [(t_cmd, f_prev), (t_cmd, f_hz)]
        if on_step is not None:
            on_step()
    if (wait := t0 + total_s - ctx.clock.now_s()) > 0:
        ctx.sleep_s(wait)
    t1 = ctx.clock.now_s()
    profile.append((t1, plan[-1][1]))
    shaker.stop()
    return StaircaseRun(t0, t1, profile, [min(vpps), max(vpps)], brackets)
