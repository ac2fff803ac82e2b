"""The calibrate procedure's name, description and parameters, apart from its machinery
(:mod:`procedures.calibrate`): ``rig list`` reads them without importing numpy."""

from __future__ import annotations

from dataclasses import dataclass, field

from rig.deploy.choices import DISTORTION_MODELS
from rig.run.procedure import param

NAME = "calibrate"
DESCRIPTION = "Slide the calibration plate to known positions with the arm; one DLT per camera."


@dataclass(frozen=True)
class Parameters:
    frames_per_position: int = field(default=8, metadata=param(lo=1, hi=600, doc="still frames averaged "
                                                                               "per plate position"))
    settle_s: float = field(default=0.2, metadata=param(lo=0.0, hi=60.0, doc="wait after each move, s"))
    speed_mm_s: float | None = field(default=None, metadata=param(lo=0.0, lo_open=True, hi=5000.0,
                                                                  doc="arm speed (default: the limit)"))
    slide_positions_mm: tuple[float, ...] = field(default=(), metadata=param(
        length=(0, 100), lo=-2000.0, hi=2000.0, doc="slides along the plate normal, mm (empty: the rig's "
                                                     "targets.calibration_plate.slide_positions_mm)"))
    refine: bool = field(default=True, metadata=param(doc="refine P on the reprojection error"))
    distortion: str = field(default="k1", metadata=param(choices=tuple(DISTORTION_MODELS),
                                                         doc="lens distortion terms fitted"))
