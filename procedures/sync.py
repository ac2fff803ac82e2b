"""Synchronize the cameras: the rotor spins its marker at 10 Hz; offset, line time and drift → timing.json.

The rotor marker crosses the epipolar lines fast (≈ 3.8 m/s at 60 mm and 10 Hz), so the offset between
the two unsynchronized cameras shows clearly. The primary estimate is the joint method (offset, rolling
shutter line time and clock drift together, :func:`rig.stereo.estimate_offset` ``method="joint"``); the
paper's rotating-marker method (``method="rotor"``) is computed beside it for comparison and stored under
``comparison`` in ``timing.json``. The search starts from the offset implied by the recording's ``camera``
start events, ± ``search_frames`` frame periods: the difference of the cameras' clock mappings when both
stamp their own frames and map their clocks onto the host's (their lowest arrival latencies: exact to the
difference of the cameras' latencies, whatever frames either skipped), else of their first frames (both
started at the same rig instant: good to about a frame, unless frames were skipped at the start).
When the joint method finds too little motion to use and the cameras lost frames in the recording (the
joint method bridges gaps of up to 3 frames of a track but leaves out the instants near longer ones — steady
random loss of 20 % is bridged; heavier loss, or bursts, are not), the error names each camera's frames
missing, their share and the gaps (:class:`LostFramesError`), not only the overlap left; the step then
records again, up to ``attempts`` recordings (segments ``sync``, ``sync-2``, …: each a spin-up, the
recording and the stop at the planned speed; recording n lasts n × ``record_s``, as a longer recording keeps
longer stretches between a host's skipped bursts), and raises the last error.

Truth events: ``rotor`` (polled actual frequency) and ``rotation`` (the steady rotation recorded, for the
radius and frequency checks of the report). Needs ``calibration.json`` (the calibrate step) first.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.exciter.sweep import FrequencySample
from procedures._common import (
    amplitude_of,
    fastest_fps,
    hold_polling,
    load_calibration,
    mount,
    read_run_json,
    required,
    run_at,
    stop_polled,
    vfd_config,
)
from procedures.params.sync import DESCRIPTION, NAME, Parameters  # noqa: F401 (its declaration)
from rig.config.rig_config import RigConfig
from rig.config.targets import RotorTarget
from rig.record.events import RotationEvent
from rig.run.acquire import Acquirer, Recording, ReduceOptions
from rig.run.plan import Plan, PlanStep, Vibration
from rig.run.procedure import Context
from rig.stereo.errors import NoCommonMotionError, NonUniformSamplingError, TimingError, TooFewSamplesError

# pandas, OpenCV (the video files' gaps) and the stereo core's estimators are imported where they are used: a
# dry run loads this module without them (tests/test_cli_start.py)
if TYPE_CHECKING:
    import pandas as pd


def _static_tracks(obs: pd.DataFrame, n_frames: int, still_px: float = 1.5) -> np.ndarray:
    """Image positions (K, 2) of markers that stay put (references): present in ≥ 80 % of the frames."""
    rounded = obs.assign(ku=(obs["u_px"] / still_px).round(), kv=(obs["v_px"] / still_px).round())
    g = rounded.groupby(["ku", "kv"]).agg(u=("u_px", "mean"), v=("v_px", "mean"), n=("u_px", "size"))
    cand = g[g["n"] >= 0.4 * n_frames][["u", "v"]].to_numpy(float)
    keep: list[np.ndarray] = []
    for p in cand:  # merge cells split by the rounding
        if not any(np.hypot(*(p - q)) < 2 * still_px for q in keep):
            keep.append(p)
    return np.array(keep).reshape(-1, 2)


def moving_marker(obs: pd.DataFrame, still_px: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """Time stamps (N,) and image positions (N, 2) of the one moving marker of a recording: per frame the
    single observation farther than ``still_px`` from every static marker (frames with none or several
    are left out)."""
    frames = obs["frame_index"].nunique()
    static = _static_tracks(obs, frames)
    uv = obs[["u_px", "v_px"]].to_numpy(float)
    if len(static):
        d = np.linalg.norm(uv[:, None, :] - static[None, :, :], axis=2).min(axis=1)
        moving = obs[d > still_px]
    else:
        moving = obs
    counts = moving.groupby("frame_index")["u_px"].transform("size")
    one = moving[counts == 1].sort_values("frame_index")
    return one["timestamp_s"].to_numpy(float), one[["u_px", "v_px"]].to_numpy(float)


def _mapped(event: dict[str, Any]) -> bool:
    return isinstance(event.get("host_minus_camera_s"), int | float)


def offset_guess_s(events: list[dict[str, Any]], reference: str, other: str) -> float:
    """Offset of ``other``'s clock onto ``reference``'s implied by one recording's ``camera`` start events:
    the difference of their clock mappings (``host_minus_camera_s``) when both carry one, else of their
    first frames' stamps (both cameras started at the same rig instant; good to about one frame period)."""
    start = {e["camera"]: e for e in events if e["action"] == "start"}
    ref, oth = start[reference], start[other]
    if _mapped(ref) and _mapped(oth):
        return float(oth["host_minus_camera_s"] - ref["host_minus_camera_s"])
    return float(ref["first_timestamp_s"] - oth["first_timestamp_s"])


def guess_source(events: list[dict[str, Any]], reference: str, other: str) -> dict[str, Any]:
    """How :func:`offset_guess_s` was formed, for ``timing.json``'s ``search``: the source, and with clock
    mappings each camera's latency spread (s: median − lowest arrival latency when its recording began)."""
    start = {e["camera"]: e for e in events if e["action"] == "start"}
    if _mapped(start[reference]) and _mapped(start[other]):
        return {"source": "camera start events: the cameras' clock mappings (lowest arrival latencies)",
                "lag_spread_s": {n: start[n].get("lag_spread_s") for n in (reference, other)}}
    return {"source": "camera start events: the cameras' first frames"}


def frame_loss(timestamps_s: np.ndarray, fps: float, duration_s: float) -> tuple[int, int, int, int]:
    """(frames delivered, frames missing between them, gaps, frames missing at the ends) of one recording of
    ``duration_s`` from its frames' stamps (s, camera clock; a gap is an interval longer than 1.5 nominal
    frame periods; at the ends: fewer frames than the recording's ``duration_s`` × ``fps`` − 1 — a stream
    that skipped ahead past the stop, or started late)."""
    from drivers.camera.video_file import find_gaps

    stamps = np.unique(np.asarray(timestamps_s, dtype=float))
    gaps = find_gaps(stamps, 1.0 / fps)
    inside = sum(gap["missing_frames"] for gap in gaps)
    ends = max(0, math.floor(duration_s * fps) - 1 - stamps.size - inside)
    return int(stamps.size), inside, len(gaps), ends


class LostFramesError(TooFewSamplesError):
    """The rotor recording lost frames and the joint method found too little left to use."""


def lost_frames_error(rec: Recording[Any], fps: float, cause: TimingError) -> LostFramesError | None:
    """The error naming each camera's lost frames when ``rec`` lost any (None when it lost none): the
    joint method cannot reconstruct a track across a gap longer than a few frames, so lost frames can leave it
    too little overlap."""
    duration_s = rec.t_stop_s - rec.t_start_s
    losses = {n: frame_loss(o["timestamp_s"].to_numpy(float), fps, duration_s)
              for n, o in rec.observations.items()}
    if not any(inside + ends for _, inside, _, ends in losses.values()):
        return None
    shares = "; ".join(f"camera {n!r}: {inside + ends} of {got + inside + ends} frames missing "
                       f"({(inside + ends) / max(got + inside + ends, 1):.0%}): {inside} in {gaps} gap(s), "
                       f"{ends} at the ends" for n, (got, inside, gaps, ends) in losses.items())
    return LostFramesError(
        f"the {duration_s:.1f}-s rotor recording lost frames ({shares}): the cameras (or a "
        f"host too loaded to read or render them) skipped frames, and the joint method leaves out every "
        f"instant near a gap it cannot bridge;"
        f" record again (sync.record_s longer) on a host that keeps up. ({cause})")


def estimate_timing(calibration: dict[str, Any], rec: Recording[Any], camera_events: list[dict[str, Any]],
                    *, params: Parameters, rotor: RotorTarget, fps: float) -> dict[str, Any]:
    """timing.json content from the rotor recording (joint method; the rotor method for comparison)."""
    from rig.stereo.dlt import DLTCamera
    from rig.stereo.timing import estimate_offset

    names = list(calibration["cameras"])[:2]
    ref, other = names
    cams = {n: DLTCamera.from_dict(calibration["cameras"][n]) for n in names}
    series, rows = {}, {}  # undistorted centres for the geometry; observed rows for the rolling shutter
    for n in names:
        t, uv = moving_marker(rec.observations[n])
        if len(t) < 12:
            raise TimingError(f"camera {n!r}: the rotor marker was identified in only {len(t)} frames "
                              "(need ≥ 12); is the rotor target mounted and turning?")
        undistorted = cams[n].undistort_px(uv, strict=False)
        ok = np.all(np.isfinite(undistorted), axis=1)
        series[n] = (t[ok], undistorted[ok])
        rows[n] = uv[ok, 1]
    guess = offset_guess_s(camera_events, ref, other)
    half = params.search_frames / fps
    try:
        joint = estimate_offset(cams[ref], cams[other], (*series[ref], rows[ref]),
                                (*series[other], rows[other]), method="joint", names=(ref, other),
                                offset_guess_s=guess, search_half_width_s=half)
    except (NoCommonMotionError, TooFewSamplesError, NonUniformSamplingError) as exc:  # (the last: a fit on
        # the few instants left runs the line time to its bound, B's row-corrected instants off their grid)
        lost = lost_frames_error(rec, fps, exc)
        if lost is None:
            raise
        raise lost from exc
    timing = joint.to_dict()
    gaps = joint.details["gaps_b"]
    timing["search"] = {"offset_guess_s": guess, "half_width_s": half,
                        **guess_source(camera_events, ref, other),
                        "frame_gaps": (f"camera {other!r}: {gaps['gaps']} gap(s), {gaps['frames_missing']} "
                                       f"frame(s) missing; {gaps['bridged']} gap(s) bridged; instants of "
                                       f"{ref!r} left out: {gaps['left_out_near_unbridged_gaps']} near "
                                       f"longer gaps, {gaps['left_out_ill_conditioned']} where gaps cluster "
                                       "(details.gaps_b)")}
    if params.compare_rotor_method:
        try:
            paper = estimate_offset(cams[ref], cams[other], series[ref], series[other], method="rotor",
                                    names=(ref, other), offset_guess_s=guess,
                                    rotor_centre_mm=list(rotor.centre_mm), rotor_axis=list(rotor.axis))
            timing["comparison"] = {"rotor": paper.to_dict()}
        except TimingError as exc:
            timing["comparison"] = {"rotor": {"error": f"{type(exc).__name__}: {exc}"}}
    return timing


def rotor_step(name: str, config: RigConfig, *, rotation_hz: float, record_s: float,
               source: str) -> PlanStep:
    """The rotor spun at ``rotation_hz`` for ``record_s`` s (``source``: the parameter naming it), with the
    spin-up and stop at the drive's configured ramp in the duration."""
    required(config.targets.rotor, "targets.rotor")
    radius_mm, radius_from = amplitude_of(config, "rotor")
    ramp = vfd_config(config, "rotor").ramp_rate_hz_per_s
    vibration = Vibration("rotor", ((0.0, rotation_hz), (record_s, rotation_hz)), radius_mm,
                          f"{source} = {rotation_hz:g} Hz", radius_from, max_slope_hz_per_s=ramp,
                          slope_from=f"devices.rotor.ramp_rate_hz_per_s = {ramp:g} Hz/s")
    return PlanStep(name, record_s + 2 * rotation_hz / ramp, vibration=vibration)


def spin_and_record(ctx: Context, acq: Acquirer, segment: str, planned: Vibration, *,
                    poll_interval_s: float) -> tuple[Recording[list[FrequencySample]], list[dict[str, Any]]]:
    """Spin the rotor up to the ``planned`` frequency, record the planned time (polling it), record
    ``rotation`` truth, stop it."""
    rotor_cfg = required(ctx.config.targets.rotor, "targets.rotor")
    rotor = ctx.rotor()
    (_, rotation_hz), (record_s, _) = planned.profile[0], planned.profile[-1]
    mount(ctx, "rotor")
    run_at(ctx, rotor, "rotor", rotation_hz)
    rec = acq.record(segment, lambda: hold_polling(ctx, rotor.read_sample, "rotor", record_s=record_s,
                                                   poll_interval_s=poll_interval_s))
    freq = float(np.mean([s.frequency_hz for s in rec.result]))
    ctx.event("rotation", RotationEvent(
        t_start_s=rec.t_start_s, t_stop_s=rec.t_stop_s, frequency_hz=freq, setpoint_hz=rotation_hz,
        radius_mm=rotor_cfg.radius_mm, centre_mm=list(rotor_cfg.centre_mm), axis=list(rotor_cfg.axis),
        marker_ids=["rotor"], segment=segment))
    stop_polled(ctx, rotor, "rotor")
    events = [{"camera": n, "action": "start", "first_timestamp_s": float(o["timestamp_s"].min()),
               **({"host_minus_camera_s": rec.clock_mappings[n].host_minus_camera_s,
                   "lag_spread_s": rec.clock_mappings[n].lag_spread_s} if n in rec.clock_mappings else {})}
              for n, o in rec.observations.items() if len(o)]
    return rec, events


def plan(params: Parameters, config: RigConfig) -> Plan:
    """Step ``sync``: the rotor at ``rotation_hz`` for ``record_s`` s (the duration: one recording), and
    when its frames are lost up to ``attempts`` recordings, the n-th n × ``record_s`` (the longest total
    stated); nothing is connected."""
    step = rotor_step("sync", config, rotation_hz=params.rotation_hz, record_s=params.record_s,
                      source="sync.rotation_hz")
    if params.attempts > 1:
        spin_s = step.duration_s - params.record_s  # the spin-up and the stop of every recording
        longest_s = sum(n * params.record_s + spin_s for n in range(1, params.attempts + 1))
        step = dataclasses.replace(step, may_repeat=(
            f"if the cameras lose frames: up to {params.attempts} recordings (sync.attempts; the n-th "
            f"n × {params.record_s:g} s), ≈ {longest_s:.0f} s at most"))
    return Plan(NAME, (step,))


def record_and_estimate(ctx: Context, params: Parameters, calibration: dict[str, Any], planned: Vibration,
                        fps: float) -> dict[str, Any]:
    """The rotor recorded and the timing estimated, recording again (segment ``sync-<n>``, n × the planned
    recording time) while the recording lost frames the estimate cannot do without, up to
    ``params.attempts`` recordings."""
    rotor = required(ctx.config.targets.rotor, "targets.rotor")
    with Acquirer(ctx, ReduceOptions(mode="detect")) as acq:
        (_, rotation_hz), (record_s, _) = planned.profile[0], planned.profile[-1]
        attempt = 1
        while True:
            longer = dataclasses.replace(planned, profile=((0.0, rotation_hz),
                                                           (attempt * record_s, rotation_hz)))
            rec, events = spin_and_record(ctx, acq, "sync" if attempt == 1 else f"sync-{attempt}", longer,
                                          poll_interval_s=params.poll_interval_s)
            try:
                timing = estimate_timing(calibration, rec, events, params=params, rotor=rotor, fps=fps)
            except LostFramesError as exc:
                if attempt >= params.attempts:
                    raise
                attempt += 1
                ctx.log.warning("sync: %s; recording again (%d of %d)", exc, attempt, params.attempts)
                continue
            timing["search"]["attempt"] = attempt
            return timing


def run_step(ctx: Context, params: Parameters) -> dict[str, Any]:
    """The ``sync`` step (skipped on --resume when done); returns the timing."""
    with ctx.step("sync") as step:
        if not step.skipped:
            calibration = load_calibration(ctx)
            fps = fastest_fps(ctx.config)
            planned = plan(params, ctx.config).vibration("sync")
            timing = record_and_estimate(ctx, params, calibration, planned, fps)
            step.output(ctx.write_json("timing.json", timing))
    recorded: dict[str, Any] = read_run_json(ctx, "timing.json")
    return recorded


def run(ctx: Context, params: Parameters) -> dict[str, Any]:
    from procedures import calibrate

    calibrate.run_step(ctx, calibrate.Parameters())
    timing = run_step(ctx, params)
    u = max((timing.get("uncertainty") or {}).get("offset_s", {}).values(), default=float("nan"))
    limit_ms = ctx.config.criteria.sync_uncertainty_ms
    offsets = ", ".join(f"{k} {1e3 * v:+.3f} ms" for k, v in timing["offset_s"].items())
    return {"passed": bool(1e3 * u <= limit_ms), "summary": f"offsets {offsets}; u(offset) {1e3 * u:.3f} ms "
                                                           f"(limit {limit_ms:g} ms)"}
