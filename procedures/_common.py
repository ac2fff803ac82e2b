"""Shared pieces of the procedures: target mounting, truth geometry from the configuration, moves.

Truth is what the procedures command, computed from the rig configuration (``ctx.config.targets``) and
the commanded arm pose, never read from the twin: a marker carried by the flange at tool offset ``o`` is
at ``p + R(rx, ry, rz)·o`` in the base frame (mm; Denso angles, R = Rz·Ry·Rx).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Protocol, TypeVar

import numpy as np

from drivers.denso.arm import DensoArm, MoveResult
from drivers.denso.pose import rotation_matrix
from drivers.exciter.axis import VfdAxis
from rig.config.devices import VfdConfig
from rig.config.rig_config import RigConfig
from rig.config.targets import CalibrationPlateTarget
from rig.record.events import ArmEvent
from rig.run.acquire import Acquirer, Recording
from rig.run.plan import ArmMoves, PlanStep
from rig.run.procedure import Context, ParameterError

__all__ = ["Polled", "amplitude_of", "arm_marker_positions", "arm_step", "fastest_fps",
           "hold_polling", "load_calibration", "mount", "move_arm", "plate_offsets_tool_mm", "poll_event",
           "read_run_json", "record_still", "required", "run_at", "speed_from", "stop_polled",
           "vfd_config"]

T = TypeVar("T")
S = TypeVar("S", bound="Polled")
Vector = Sequence[float] | np.ndarray


class Polled(Protocol):
    """A polled device sample (:class:`drivers.exciter.sweep.FrequencySample`,
    :class:`drivers.exciter.shaker.GeneratorSample`)."""

    def as_event(self) -> dict[str, Any]: ...


def required(section: T | None, name: str) -> T:
    """The configuration section ``[name]`` (e.g. ``config.targets.rotor``, ``"targets.rotor"``), or
    ParameterError naming it (exit 4)."""
    if section is None:
        raise ParameterError(name, f"the procedure needs [{name}] in the rig configuration, which has none")
    return section


def vfd_config(config: RigConfig, device: str) -> VfdConfig:
    """``[devices.exciter]`` / ``[devices.rotor]``, or ParameterError naming it (exit 4)."""
    if device not in ("exciter", "rotor"):
        raise ValueError(f"{device!r} is no VFD-driven device; allowed: exciter, rotor")
    dev = config.devices.exciter if device == "exciter" else config.devices.rotor
    if dev is None:
        raise ParameterError(f"devices.{device}", f"the procedure needs [devices.{device}], which this rig "
                                                  "configuration lacks")
    return dev


def amplitude_of(config: RigConfig, device: str) -> tuple[float, str]:
    """Peak displacement (mm) of a VFD-driven body, as the station gives it to the driver, and its field:
    the exciter's crank radius, the rotor marker's radius."""
    if device == "exciter":
        crank_mm = vfd_config(config, "exciter").crank_radius_mm
        assert crank_mm is not None, "the configuration check requires the exciter's crank radius"
        return crank_mm, f"devices.exciter.crank_radius_mm = {crank_mm:g} mm"
    vfd_config(config, "rotor")
    rotor = config.targets.rotor
    radius = rotor.radius_mm if rotor is not None else 0.0
    return radius, f"targets.rotor.radius_mm = {radius:g} mm"


def speed_from(procedure: str, speed_mm_s: float | None) -> str:
    """What an arm speed parameter says, for the plan's checks."""
    if speed_mm_s is None:
        return f"{procedure}.speed_mm_s unset (the limit)"
    return f"{procedure}.speed_mm_s = {speed_mm_s:g} mm/s"


def arm_step(name: str, moves: ArmMoves, config: RigConfig) -> PlanStep:
    """A step of arm moves with its duration estimate: the straight path from the home pose (else the
    first pose) through every pose at the planned speed, plus the hold at each."""
    robot, lim = config.devices.robot, config.limits.robot
    speed = moves.speed_mm_s or (lim.max_speed_mm_s if lim is not None else 1.0)
    start: Sequence[float] = robot.home_pose if robot is not None and robot.home_pose is not None else \
        (moves.poses[0] if moves.poses else (0.0, 0.0, 0.0))
    path = np.asarray([start[:3], *(p[:3] for p in moves.poses)], float)
    travel_mm = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
    return PlanStep(name, travel_mm / speed + moves.hold_s * len(moves.poses), arm=moves)


def fastest_fps(config: RigConfig) -> float:
    """The highest frame rate (frames/s) of the configured cameras."""
    return max(c.fps for c in config.cameras.values())


def mount(ctx: Context, scene: str) -> None:
    """Mount a target: the twin switches its scene; on a real bench the operator is asked (terminal only)."""
    if ctx.station.simulated:
        ctx.station.mount(scene)
        ctx.log.info("mounted target %s", scene)
        return
    if not sys.stdin.isatty():
        raise ParameterError("mount", f"mount the {scene!r} target, then run again with a terminal to "
                                      "confirm "
                                      "(no operator terminal: stdin is not a terminal)")
    input(f"rig: mount the {scene!r} target and press Enter ")
    ctx.checkpoint()


def arm_marker_positions(pose: Vector, offsets_tool_mm: Mapping[str, Vector]) -> dict[str, list[float]]:
    """Base-frame positions (mm) of markers at tool-frame ``offsets_tool_mm`` for flange ``pose``."""
    p = np.asarray(pose, dtype=float)
    R = rotation_matrix(*p[3:6])
    return {k: (p[:3] + R @ np.asarray(o, dtype=float)).tolist() for k, o in offsets_tool_mm.items()}


def plate_offsets_tool_mm(plate: CalibrationPlateTarget) -> dict[str, list[float]]:
    """Tool-frame offsets of the calibration plate's markers ``cal_r{row}c{col}`` (row 0 on top, +tool y)."""
    out = {}
    for r in range(plate.rows):
        for c in range(plate.cols):
            out[f"cal_r{r}c{c}"] = [(c - (plate.cols - 1) / 2) * plate.pitch_mm,
                                    ((plate.rows - 1) / 2 - r) * plate.pitch_mm, plate.standoff_mm]
    return out


def move_arm(ctx: Context, arm: DensoArm, pose: Sequence[float],
             speed_mm_s: float | None = None) -> MoveResult:
    """Move the arm (limits checked by the driver before sending), record the ``arm`` event, checkpoint."""
    ctx.checkpoint()
    result = arm.move_to(list(pose), speed_mm_s)
    ctx.event("arm", ArmEvent(
        commanded_pose=list(result.commanded_pose), reported_pose=list(result.reported_pose),
        t_start_s=result.t_start_s, t_end_s=result.t_end_s, position_error_mm=result.position_error_mm))
    ctx.checkpoint()
    return result


def poll_event(ctx: Context, stream: str, sample: Polled) -> None:
    """Record one polled frequency sample of the exciter or rotor and checkpoint (abort point)."""
    ctx.event(stream, sample.as_event())
    ctx.checkpoint()


def run_at(ctx: Context, axis: VfdAxis, stream: str, frequency_hz: float) -> None:
    """Run ``axis`` at ``frequency_hz`` (mechanical Hz), wait until it is reached and record that sample
    as a ``stream`` event (checkpoint)."""
    axis.set_frequency(frequency_hz, wait=False)
    poll_event(ctx, stream, axis.wait_until_reached(frequency_hz))


def hold_polling(ctx: Context, poll: Callable[[], S], stream: str, *, record_s: float,
                 poll_interval_s: float) -> list[S]:
    """Hold for ``record_s`` s of rig time, calling ``poll()`` (a VFD axis's ``read_sample``, the shaker's
    ``read_state``) every ``poll_interval_s`` s (one ``stream`` event per sample, the first at once, the
    last at the end); return the samples."""
    samples: list[S] = []
    end = ctx.clock.now_s() + record_s
    while True:
        samples.append(poll())
        poll_event(ctx, stream, samples[-1])
        remaining = end - ctx.clock.now_s()
        if remaining <= 0:
            return samples
        ctx.sleep_s(min(poll_interval_s, remaining))


def stop_polled(ctx: Context, device: VfdAxis, stream: str) -> None:
    """Stop ``device`` (waiting for standstill); record the sample it returns, if any, as ``stream``."""
    stopped = device.stop(wait=True)
    if stopped is not None:
        poll_event(ctx, stream, stopped)


def record_still(ctx: Context, acq: Acquirer, arm: DensoArm, pose: Sequence[float], segment: str, *,
                 frames: int, settle_s: float, speed_mm_s: float | None) -> Recording[None]:
    """Move the arm to ``pose``, wait ``settle_s`` s, record ``frames`` still frames (plus 1.5 frame periods
    of margin at the fastest camera's rate) as ``segment``; return the recording."""
    move_arm(ctx, arm, pose, speed_mm_s)
    ctx.sleep_s(settle_s)
    return acq.record(segment, (frames + 1.5) / fastest_fps(ctx.config))


def read_run_json(ctx: Context, name: str) -> Any:
    """A JSON file of the run folder (written by an earlier step of this run)."""
    return json.loads(ctx.path(name).read_text(encoding="utf-8"))


def load_calibration(ctx: Context) -> dict[str, Any]:
    """The run's ``calibration.json`` (written by the calibrate step of this run)."""
    path = ctx.path("calibration.json")
    if not path.is_file():
        raise ParameterError("calibration.json", f"{path} is missing: run the calibrate step first "
                                                 "(rig certify runs it)")
    calibration: dict[str, Any] = read_run_json(ctx, "calibration.json")
    return calibration
