"""Certify's band beyond the crank exciter's limit: the sweep column on the shaker, swept by the generator.

The crank exciter stops at its configured limit (32 Hz on the built-in rig), so the band above the crank
sweep (e.g. 30 → 50 Hz, up to the pair's combined Nyquist limit) is swept by the shaker: the sweep column
is re-mounted on the shaker's armature (scene ``band_column``; on a real bench the operator is asked, as
for every target) and the generator's own linear sweep moves it at ``amplitude_mm``.

The phase reference is the generator's own waveform. The sweep is armed with the output OFF (its phase
generator sweeps, nothing moves); the recording's timing fiducial (the LED on the generator's *other*
channel, ``[fiducial]``) issues ``PHASe:SYNChronize``, which restarts both channels at phase 0 on the
instrument's one timebase — the sweep starts again at ``start_hz`` — so channel 1's phase is
φ(t) = 2π∫f dt from that instant with the sweep's exact law, and the LED's edges that date the cameras are
referred to the same instant: an error in the controller's estimate of it (the command's bracket) shifts
both alike. Then the output is connected with the amplitude ramped up, held to the sweep's end, ramped
down. Without a running fiducial the step issues ``PHASe:SYNChronize`` itself and the phase origin is the
command's bracket (stated in the event).

Truth: a :class:`rig.record.events.BandSweepEvent` (stream ``band_sweep``) with the exact law from the
phase origin, the steady window (after the amplitude ramp) as ``t_start_s`` … ``t_stop_s``, the volts and
how the origin is known; the generator's state polled as ``generator`` events. Every limit (frequency,
displacement, acceleration, velocity, slope, volts, a flat sensitivity table over the band) is checked in
the plan before any byte (:func:`own_plan`, via :mod:`procedures.sweep`'s shaker checks).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from procedures import sweep
from procedures._common import mount, poll_event, required
from procedures._shaker import phase_origin
from rig.config.rig_config import RigConfig
from rig.record.events import BandSweepEvent
from rig.run.acquire import Acquirer, ReduceOptions
from rig.run.plan import Plan, PlanStep
from rig.run.procedure import Context

STEP = "band"
POLL_INTERVAL_S = 0.5


@dataclass(frozen=True)
class BandParameters:
    """The shaker's sweep over the extended band: ``start_hz`` → ``max_hz`` in ``duration_s`` at
    ``amplitude_mm``; ``enabled`` False leaves the step out (stated in the plan)."""

    enabled: bool = True
    start_hz: float = 27.0  # below the crank sweep's top: the amplitude's ramp-up (≈ 1.6 s) ends near 30 Hz
    max_hz: float = 50.0
    duration_s: float = 9.0
    amplitude_mm: float = 2.0

    def __post_init__(self) -> None:
        if self.max_hz <= self.start_hz:
            raise ValueError(f"max_hz={self.max_hz:g} must exceed start_hz={self.start_hz:g} "
                             "(a rising sweep)")
        if not self.duration_s > 0 or not self.amplitude_mm > 0:
            raise ValueError(f"duration_s={self.duration_s!r} and amplitude_mm={self.amplitude_mm!r} "
                             "must be > 0")

    def as_sweep(self) -> sweep.Parameters:
        """The same motion as the sweep procedure's shaker parameters (its limit checks apply)."""
        return sweep.Parameters(start_hz=self.start_hz, max_hz=self.max_hz, duration_s=self.duration_s,
                                hold_s=0.0, shape="linear", update_interval_s=POLL_INTERVAL_S,
                                shaker_amplitude_mm=self.amplitude_mm)


def band_criteria_set(config: RigConfig) -> tuple[str, ...]:
    """The band's ``[criteria]`` fields that ``config`` sets (required: only this step evaluates them)."""
    criteria = config.criteria
    limits = {"band_amplitude_error_pct": criteria.band_amplitude_error_pct,
              "band_phase_deg": criteria.band_phase_deg, "band_min_hz": criteria.band_min_hz}
    return tuple(name for name, limit in limits.items() if limit is not None)


def left_out_note(params: BandParameters, config: RigConfig) -> str:
    """What leaving the step out costs the certificate ("" when the step runs or no band criterion is set):
    the band criteria stay NOT EVALUATED, so the certificate cannot PASS."""
    unevaluated = band_criteria_set(config) if not params.enabled else ()
    if not unevaluated:
        return ""
    names = ", ".join(f"criteria.{name}" for name in unevaluated)
    return (f"the band's criteria ({names}, set in {config.source}) stay NOT EVALUATED without the band "
            "step: the certificate will be INCOMPLETE (exit 1); --set band=true adds the step")


def own_plan(params: BandParameters, config: RigConfig) -> Plan:
    """Step ``band``: the shaker's linear sweep (checked as the sweep procedure checks a shaker sweep), or
    a step that states it was left out and what that costs the certificate."""
    if not params.enabled:
        what = "left out by this preset: the shaker's band beyond the crank sweep runs in the full preset"
        note = left_out_note(params, config)
        return Plan("certify", (PlanStep(STEP, 0.0, what=f"{what}; {note}" if note else what),))
    vibration = sweep.shaker_vibration(params.as_sweep(), config)
    names = {"sweep.shaker_amplitude_mm": "band.amplitude_mm",
             "sweep.shape = linear": "the generator's linear sweep", "sweep.": "band."}

    def own(text: str) -> str:  # the band's parameters, not the sweep procedure's
        for old, new in names.items():
            text = text.replace(old, new)
        return text

    vibration = dataclasses.replace(vibration, frequency_from=own(vibration.frequency_from),
                                    amplitude_from=own(vibration.amplitude_from),
                                    slope_from=own(vibration.slope_from))
    return Plan("certify", (PlanStep(STEP, vibration.duration_s + 2.0, vibration=vibration),))


def run_step(ctx: Context, params: BandParameters) -> None:
    """Carry the band sweep out as step ``band`` (skipped on --resume when done; empty when disabled)."""
    with ctx.step(STEP) as step:
        if step.skipped:
            return
        if not params.enabled:
            ctx.log.info("band: left out by this preset")
            return
        _run(ctx, params)


def _run(ctx: Context, params: BandParameters) -> None:
    column = required(ctx.config.targets.sweep_column, "targets.sweep_column")
    shaker = ctx.shaker()
    f0, f1, T = params.start_hz, params.max_hz, params.duration_s
    mount(ctx, "band_column")
    ctx.progress(None, f"band: shaker sweep {f0:g} → {f1:g} Hz in {T:g} s (phase from the generator)")
    vpp = shaker.arm_sweep(f0, f1, T, spacing="linear", amplitude_mm=params.amplitude_mm)

    def on_poll() -> None:
        poll_event(ctx, "generator", shaker.read_state())

    with Acquirer(ctx, ReduceOptions(mode="track", window_px=51)) as acq:
        fiducial = acq.fiducial

        def drive() -> tuple[float, float, tuple[float, float], str]:
            origin, how = phase_origin(ctx, shaker, fiducial)
            t_steady, t_end = shaker.drive_armed(vpp, 0.5 * (origin[0] + origin[1]) + T,
                                                 poll_interval_s=POLL_INTERVAL_S, on_poll=on_poll)
            return t_steady, t_end, origin, how

        rec = acq.record(STEP, drive)
    t_steady, t_end, origin, how = rec.result
    t_phase0 = 0.5 * (origin[0] + origin[1])
    ctx.event("band_sweep", BandSweepEvent(
        t_start_s=t_steady, t_stop_s=t_end, amplitude_mm=params.amplitude_mm, axis=list(column.axis),
        marker_ids=[f"bcol{k}" for k in range(column.count)], profile=[[t_phase0, f0], [t_phase0 + T, f1]],
        segment=STEP, recording=[rec.t_start_s, rec.t_stop_s], body="shaker", amplitude_vpp=vpp,
        spacing="linear", profile_source="commanded: the generator's built-in linear sweep from its phase "
                                         "restart (PHASe:SYNChronize) at the first profile time",
        phase_origin_s=list(origin), phase_origin=how))
    poll_event(ctx, "generator", shaker.read_state())  # after the stop: amplitude down, output OFF
