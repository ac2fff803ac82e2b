"""The accuracy procedure's name, description and parameters, apart from its machinery
(:mod:`procedures.accuracy`): ``rig list`` reads them without importing numpy."""

from __future__ import annotations

from dataclasses import dataclass, field

from rig.run.procedure import param

NAME = "accuracy"
DESCRIPTION = "Known marker poses over the volume, ISO 9283 cycles, marker frame → error versus position."


@dataclass(frozen=True)
class Parameters:
    grid_points: int = field(default=3, metadata=param(lo=0, hi=12, doc="grid nodes per axis (0: no grid)"))
    grid_fraction: float = field(default=0.8, metadata=param(lo=0.05, hi=1.0,
                                                             doc="share of the volume's size spanned"))
    cycles: int = field(default=10, metadata=param(lo=0, hi=100, doc="ISO 9283 cycles over P1–P5 (0: none)"))
    frame_poses: int = field(default=4, metadata=param(lo=0, hi=20, doc="marker frame positions (0: none)"))
    frames_per_pose: int = field(default=10, metadata=param(lo=1, hi=600, doc="still frames per pose"))
    settle_s: float = field(default=0.2, metadata=param(lo=0.0, hi=60.0, doc="wait after each move, s"))
    speed_mm_s: float | None = field(default=None, metadata=param(lo=0.0, lo_open=True, hi=5000.0,
                                                                  doc="arm speed (default: the limit)"))
