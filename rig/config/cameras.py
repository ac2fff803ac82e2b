"""``[cameras.<name>]``: driver, frame rate, resolution and source of each camera."""

from __future__ import annotations

from dataclasses import dataclass, field

from rig.config.schema import spec


@dataclass(frozen=True)
class CameraConfig:
    driver: str = field(metadata=spec(choices=("sim", "opencv", "file")))
    fps: float = field(default=60.0, metadata=spec(lo=1.0, hi=1000.0))
    resolution_px: tuple[int, ...] = field(default=(1920, 1080), metadata=spec(length=2, lo=16, hi=16384))
    exposure_s: float = field(default=1 / 6000, metadata=spec(lo=0.0, lo_open=True, hi=1.0))
    source: str = ""
