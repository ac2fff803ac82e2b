"""``[cameras.<name>]``: driver, frame rate, resolution and source of each camera, and (``opencv``) whose
clock stamps its frames: ``timestamps = "stream"`` (the source's own stamps: the camera's clock, e.g. a
Matroska or RTSP stream), ``"host"`` (the host's clock on arrival: an MJPEG camera, whose frames carry none)
or ``"auto"`` (default: the stream's stamps for a network source that has them, else the host's)."""

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
    timestamps: str = field(default="auto", metadata=spec(choices=("auto", "stream", "host")))
