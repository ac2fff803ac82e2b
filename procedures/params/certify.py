"""The certify procedure's name, description and parameters, apart from its machinery
(:mod:`procedures.certify`): ``rig list`` reads them without importing numpy."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from rig.run.procedure import param

NAME = "certify"
DESCRIPTION = ("The whole certification: calibrate, sync, accuracy, sweep, the shaker's band beyond it, "
               "report, certificate.")
PRESETS: dict[str, dict[str, Any]] = {
    "full": {
        "calibrate": {},
        "sync": {},
        "accuracy": {},
        "sweep": {},
        "band": {},
    },
    "fast": {
        "calibrate": {"frames_per_position": 4},
        "sync": {"record_s": 2.0},
        "accuracy": {"grid_points": 2, "cycles": 3, "frame_poses": 2, "frames_per_pose": 8},
        "sweep": {"start_hz": 2.0, "max_hz": 12.0, "duration_s": 8.0, "hold_s": 0.5},
        "band": {"enabled": False},  # a short check of the chain: the band beyond 30 Hz is the full preset's
    },
}


@dataclass(frozen=True)
class Parameters:
    preset: str = field(default="full", metadata=param(choices=tuple(PRESETS), doc="scope of the run"))
    sweep_start_hz: float | None = field(default=None, metadata=param(lo=0.1, hi=1000.0,
                                                                      doc="sweep: first frequency, Hz"))
    sweep_max_hz: float | None = field(default=None, metadata=param(lo=0.1, hi=1000.0,
                                                                    doc="sweep: peak frequency, Hz"))
    sweep_duration_s: float | None = field(default=None, metadata=param(lo=0.5, hi=3600.0,
                                                                        doc="sweep: rise time, s"))
    band_max_hz: float | None = field(default=None, metadata=param(
        lo=0.1, hi=1000.0, doc="band: the shaker sweep's top frequency, Hz (the full preset: 50)"))
    band_duration_s: float | None = field(default=None, metadata=param(
        lo=0.5, hi=3600.0, doc="band: the shaker sweep's time, s"))
    band: bool | None = field(default=None, metadata=param(
        doc="run the shaker's band beyond the crank sweep (default: full yes, fast no)"))
    accuracy_grid_points: int | None = field(default=None, metadata=param(
        lo=0, hi=12, doc="accuracy: grid nodes per axis"))
    accuracy_cycles: int | None = field(default=None, metadata=param(lo=0, hi=100,
                                                                     doc="accuracy: ISO 9283 cycles"))
    calibrate_slide_positions_mm: tuple[float, ...] = field(default=(), metadata=param(
        length=(0, 100), lo=-2000.0, hi=2000.0, doc="calibrate: plate slides, mm (empty: the rig's)"))
    figures: bool | None = field(default=None, metadata=param(
        doc="draw the report's figures (default: the rig's [report] figures)"))
    compare_paper_sync: bool | None = field(default=None, metadata=param(
        doc="analyse with the paper's linear interpolation beside ours (default: full the rig's [report] "
            "comparison, fast no)"))
