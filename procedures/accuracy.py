"""Static accuracy: known marker positions over the measurement volume (error versus position).

Three steps, each a list of arm poses with the cameras recording ``frames_per_pose`` still frames at each:

1. ``accuracy_grid`` — the single marker visits a ``grid_points``³ grid filling ``grid_fraction`` of
   ``targets.volume`` (error versus position);
2. ``accuracy_iso9283`` — ISO 9283-style repeated cycles over five poses: P1 at the centre, P2–P5 on a
   diagonal plane at 10 % of the diagonal from the corners of the cube (``grid_fraction`` sets that
   share), visited in the standard order P1 → P5 → P4 → P3 → P2 for ``cycles`` cycles (repeatability);
3. ``accuracy_frame`` — the marker frame (several markers at known offsets) at ``frame_poses`` known
   positions (length errors, VDI/VDE 2634-1 style).

Truth: one ``accuracy_pose`` event per visit with the commanded marker positions (from the commanded
pose and the target geometry of the configuration) and the still window; an ``arm`` event per move.
Every pose and the speed are checked before any device is connected (a violation: exit 4).
Marker orientation: the robot's home orientation (``devices.robot.home_pose``), printed faces towards the
cameras.
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np

from procedures._alone import alone_plan, run_alone
from procedures._common import (
    arm_marker_positions,
    arm_step,
    fastest_fps,
    mount,
    record_still,
    required,
    speed_from,
)
from procedures.params.accuracy import DESCRIPTION, NAME, Parameters  # noqa: F401 (its declaration)
from rig.config.rig_config import RigConfig
from rig.config.targets import MeasurementVolume, TargetsConfig
from rig.record.events import AccuracyPoseEvent
from rig.run.acquire import Acquirer, ReduceOptions
from rig.run.plan import ArmMoves, Plan
from rig.run.procedure import Context

ISO_ORDER = ("P1", "P5", "P4", "P3", "P2")
ISO_CORNERS = {"P2": (1, 1, 1), "P3": (1, -1, 1), "P4": (-1, -1, -1), "P5": (-1, 1, -1)}
SCENES = {"accuracy_grid": "single_marker", "accuracy_iso9283": "single_marker",
          "accuracy_frame": "marker_frame"}  # step -> target mounted (and whose markers are recorded)


def _orientation(config: RigConfig) -> np.ndarray:
    robot = config.devices.robot
    if robot is not None and robot.home_pose is not None:
        return np.asarray(robot.home_pose[3:], dtype=float)
    plate = config.targets.calibration_plate
    return np.asarray(plate.start_pose[3:] if plate is not None else (90.0, 0.0, 90.0), dtype=float)


def flange_pose_for(marker_mm: np.ndarray, offset_tool_mm: np.ndarray,
                    orientation_deg: np.ndarray) -> list[float]:
    """Flange pose putting a tool-frame ``offset_tool_mm`` at base-frame ``marker_mm`` (orientation fixed)."""
    o = np.asarray(arm_marker_positions(np.r_[0.0, 0.0, 0.0, orientation_deg], {"m": offset_tool_mm})["m"])
    return [*(np.asarray(marker_mm, float) - o).tolist(), *orientation_deg.tolist()]


def grid_targets(volume: MeasurementVolume, points: int, fraction: float) -> list[np.ndarray]:
    """``points``³ marker positions (mm) spanning ``fraction`` of the volume, x fastest."""
    if points == 0:
        return []
    c, h = np.asarray(volume.centre_mm, float), 0.5 * fraction * np.asarray(volume.size_mm, float)
    axes = [np.array([0.0]) if points == 1 else np.linspace(-1, 1, points)] * 3
    return [c + h * np.array([x, y, z]) for z, y, x in itertools.product(*axes[::-1])]


def iso_targets(volume: MeasurementVolume, fraction: float) -> dict[str, np.ndarray]:
    """ISO 9283 poses P1–P5 (mm): P1 the centre, P2–P5 on a diagonal plane at ``fraction`` of the
    half-diagonal (0.8 = 10 % of the diagonal from the corners)."""
    c, h = np.asarray(volume.centre_mm, float), 0.5 * fraction * np.asarray(volume.size_mm, float)
    out = {"P1": c}
    out.update({k: c + h * np.asarray(s, float) for k, s in ISO_CORNERS.items()})
    return out


def frame_flange_poses(volume: MeasurementVolume, offsets: np.ndarray, orientation: np.ndarray,
                       n: int) -> list[list[float]]:
    """``n`` flange poses of the marker frame, its centroid at the volume centre then at ± a quarter of
    the volume along alternating diagonals."""
    c, q = np.asarray(volume.centre_mm, float), 0.25 * np.asarray(volume.size_mm, float)
    shifts = [np.zeros(3)] + [q * np.asarray(s, float) for s in itertools.product((1, -1), repeat=3)]
    centroid = offsets.mean(axis=0)
    return [flange_pose_for(c + shifts[k % len(shifts)], centroid, orientation) for k in range(n)]


def visits(params: Parameters, config: RigConfig) -> dict[str, list[tuple[list[float], str, int]]]:
    """Every pose of the three steps as (flange pose, target name, cycle)."""
    volume = required(config.targets.volume, "targets.volume")
    orient = _orientation(config)
    out: dict[str, list[tuple[list[float], str, int]]] = {step: [] for step in SCENES}
    if params.grid_points or params.cycles:
        single = np.asarray(required(config.targets.single_marker, "targets.single_marker").offset_tool_mm,
                            float)
        for k, m in enumerate(grid_targets(volume, params.grid_points, params.grid_fraction)):
            out["accuracy_grid"].append((flange_pose_for(m, single, orient), f"G{k:03d}", 0))
        iso = iso_targets(volume, params.grid_fraction)
        for cycle in range(params.cycles):
            for name in ISO_ORDER:
                out["accuracy_iso9283"].append((flange_pose_for(iso[name], single, orient), name, cycle))
    if params.frame_poses:
        frame = required(config.targets.marker_frame, "targets.marker_frame")
        offsets = np.asarray(frame.offsets_mm, float)
        for k, pose in enumerate(frame_flange_poses(volume, offsets, orient, params.frame_poses)):
            out["accuracy_frame"].append((pose, f"F{k}", 0))
    return out


POSES_FROM = {"accuracy_grid": "accuracy.grid_points = {p.grid_points}, accuracy.grid_fraction = "
                               "{p.grid_fraction:g} of targets.volume",
              "accuracy_iso9283": "accuracy.grid_fraction = {p.grid_fraction:g} of targets.volume (ISO 9283 "
                                  "P1–P5, {p.cycles} cycles)",
              "accuracy_frame": "accuracy.frame_poses = {p.frame_poses} in targets.volume with "
                                "targets.marker_frame"}


def own_plan(params: Parameters, config: RigConfig) -> Plan:
    """The three accuracy steps (those with poses): every flange pose and the arm speed."""
    hold_s = params.settle_s + (params.frames_per_pose + 1.5) / fastest_fps(config)
    steps = []
    for step_name, planned in visits(params, config).items():
        if planned:
            moves = ArmMoves(tuple(tuple(p) for p, _, _ in planned), POSES_FROM[step_name].format(p=params),
                             params.speed_mm_s, speed_from(NAME, params.speed_mm_s), hold_s)
            steps.append(arm_step(step_name, moves, config))
    return Plan(NAME, tuple(steps))


def plan(params: Parameters, config: RigConfig) -> Plan:
    """calibrate, sync, then the accuracy steps; nothing is connected."""
    return alone_plan(NAME, own_plan(params, config), config)


def _marker_offsets(targets: TargetsConfig) -> dict[str, dict[str, list[float]]]:
    """Per mounted target, its markers' tool-frame offsets (mm) by marker id (none if not configured)."""
    single, frame = targets.single_marker, targets.marker_frame
    return {"single_marker": {"arm": list(single.offset_tool_mm)} if single is not None else {},
            "marker_frame": {f"frame{k}": list(o) for k, o in enumerate(frame.offsets_mm)}
            if frame is not None else {}}


def run_steps(ctx: Context, params: Parameters) -> int:
    """The three accuracy steps (each skipped on --resume when done); returns the number of visits."""
    arm = ctx.arm()
    steps = visits(params, ctx.config)  # the poses of own_plan, checked before the station was opened
    offsets = _marker_offsets(ctx.config.targets)
    total = sum(len(v) for v in steps.values())
    index = 0  # of the visit over all steps (done ones included)
    for step_name, planned in steps.items():
        if not planned:
            continue
        with ctx.step(step_name) as step:
            if step.skipped:
                index += len(planned)
                continue
            mount(ctx, SCENES[step_name])
            with Acquirer(ctx, ReduceOptions(mode="track", window_px=31)) as acq:
                for pose, target, cycle in planned:
                    ctx.progress(index / total, f"{step_name}: {target} (cycle {cycle})")
                    rec = record_still(ctx, acq, arm, pose, step_name, frames=params.frames_per_pose,
                                       settle_s=params.settle_s, speed_mm_s=params.speed_mm_s)
                    ctx.event("accuracy_pose", AccuracyPoseEvent(
                        index=index, cycle=cycle, target=target, t_start_s=rec.t_start_s,
                        t_stop_s=rec.t_stop_s, pose=list(pose), segment=step_name,
                        markers=arm_marker_positions(pose, offsets[SCENES[step_name]])))
                    index += 1
    return total


def run(ctx: Context, params: Parameters) -> dict[str, Any]:
    n, result = run_alone(ctx, params, run_steps)
    return {**result, "summary": f"{n} poses visited; {result['summary']}"}
