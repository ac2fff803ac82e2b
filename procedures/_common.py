"""Shared pieces of the procedures: target mounting, truth geometry from the configuration, moves.

Truth is what the procedures command, computed from the rig configuration (``ctx.config.targets``) and
the commanded arm pose, never read from the twin: a marker carried by the flange at tool offset ``o`` is
at ``p + R(rx, ry, rz)·o`` in the base frame (mm; Denso angles, R = Rz·Ry·Rx).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from drivers.denso.pose import rotation_matrix
from rig.procedure import ParameterError

__all__ = ["arm_marker_positions", "load_calibration", "mount", "move_arm", "plate_offsets_tool_mm",
           "poll_event", "require_target"]


def require_target(ctx: Any, name: str) -> Any:
    """The ``[targets.<name>]`` section, or ParameterError naming it (exit 4)."""
    target = getattr(ctx.config.targets, name, None)
    if target is None:
        raise ParameterError(f"targets.{name}", f"the procedure needs [targets.{name}] in the rig "
                                                "configuration, which has none")
    return target


def mount(ctx: Any, scene: str) -> None:
    """Mount a target: the twin switches its scene; on a real bench the operator is asked (terminal only)."""
    station = ctx.station
    if getattr(station, "world", None) is not None:
        station.mount(scene)
        ctx.log.info("mounted target %s", scene)
        return
    if not sys.stdin.isatty():
        raise ParameterError("mount", f"mount the {scene!r} target, then run again with a terminal to "
                                      "confirm "
                                      "(no operator terminal: stdin is not a terminal)")
    input(f"rig: mount the {scene!r} target and press Enter ")
    ctx.checkpoint()


def arm_marker_positions(pose: Sequence[float],
                         offsets_tool_mm: dict[str, Sequence[float]]) -> dict[str, list]:
    """Base-frame positions (mm) of markers at tool-frame ``offsets_tool_mm`` for flange ``pose``."""
    p = np.asarray(pose, dtype=float)
    R = rotation_matrix(*p[3:6])
    return {k: (p[:3] + R @ np.asarray(o, dtype=float)).tolist() for k, o in offsets_tool_mm.items()}


def plate_offsets_tool_mm(plate: Any) -> dict[str, list[float]]:
    """Tool-frame offsets of the calibration plate's markers ``cal_r{row}c{col}`` (row 0 on top, +tool y)."""
    out = {}
    for r in range(plate.rows):
        for c in range(plate.cols):
            out[f"cal_r{r}c{c}"] = [(c - (plate.cols - 1) / 2) * plate.pitch_mm,
                                    ((plate.rows - 1) / 2 - r) * plate.pitch_mm, plate.standoff_mm]
    return out


def move_arm(ctx: Any, arm: Any, pose: Sequence[float], speed_mm_s: float | None = None) -> Any:
    """Move the arm (limits checked by the driver before sending), record the ``arm`` event, checkpoint."""
    ctx.checkpoint()
    result = arm.move_to(list(pose), speed_mm_s)
    ctx.event("arm", {"commanded_pose": result.commanded_pose, "reported_pose": result.reported_pose,
                      "t_start_s": result.t_start_s, "t_end_s": result.t_end_s,
                      "position_error_mm": result.position_error_mm})
    ctx.checkpoint()
    return result


def check_poses(arm: Any, poses: Sequence[Sequence[float]]) -> None:
    """Check every pose against the envelope before the first motion (LimitError names the axis)."""
    for pose in poses:
        arm.check_pose(list(pose))


def poll_event(ctx: Any, stream: str, sample: Any) -> None:
    """Record one polled frequency sample of the exciter or rotor and checkpoint (abort point)."""
    ctx.event(stream, sample.as_event())
    ctx.checkpoint()


def load_calibration(ctx: Any) -> dict[str, Any]:
    """The run's ``calibration.json`` (written by the calibrate step of this run)."""
    path = ctx.path("calibration.json")
    if not path.is_file():
        raise ParameterError("calibration.json", f"{path} is missing: run the calibrate step first "
                                                 "(rig certify runs it)")
    return json.loads(path.read_text(encoding="utf-8"))
