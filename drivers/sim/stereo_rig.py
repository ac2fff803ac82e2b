"""The default camera pair of the simulated rig: two unsynchronized 60 FPS rolling-shutter cameras.

Cameras about 1.5 m in front of the measurement volume (x ≈ 1900 mm in the base frame), 0.6 m apart,
slightly above it and convergent on it; each with its own lens distortion, clock error and start offset.
All numbers are constructor data so a station can build the twin from its rig configuration.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from drivers.sim.camera import SimCamera, look_at
from drivers.sim.render import NoiseModel
from drivers.sim.world import World

__all__ = ["CameraSpec", "default_camera_specs", "default_stereo_pair", "make_camera"]


@dataclass(frozen=True)
class CameraSpec:
    """Placement, optics and timing of one simulated camera (mm, px, s, ppm)."""

    name: str
    eye_mm: tuple[float, float, float]
    target_mm: tuple[float, float, float] = (420.0, 0.0, 300.0)
    fx_px: float = 2400.0
    fy_px: float = 2400.0
    cx_px: float = 959.5
    cy_px: float = 539.5
    distortion: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    fps: float = 60.0
    clock_ppm: float = 0.0
    start_offset_s: float = 0.0
    timestamp_origin_s: float = 0.0
    line_time_s: float | None = None
    exposure_s: float = 1 / 6000
    psf_sigma_px: float = 0.6
    noise: NoiseModel = field(default_factory=NoiseModel)
    drop_probability: float = 0.0  # share of sensor frames lost (SimCamera's drop_probability) ...
    drop_window_s: tuple[float, float] | None = None  # ... in this world-time window only (None: always)


def default_camera_specs() -> tuple[CameraSpec, CameraSpec]:
    left = CameraSpec("left", eye_mm=(1900.0, -300.0, 420.0), fx_px=2400.0, fy_px=2401.2, cx_px=963.2,
                      cy_px=535.8, distortion=(-0.081, 0.062, 0.0004, -0.0003), clock_ppm=-12.0,
                      start_offset_s=0.0, timestamp_origin_s=12.345)
    right = CameraSpec("right", eye_mm=(1900.0, 300.0, 420.0), fx_px=2385.0, fy_px=2385.0, cx_px=955.1,
                       cy_px=544.0, distortion=(-0.072, 0.041, -0.0002, 0.0005), clock_ppm=35.0,
                       start_offset_s=0.0123, timestamp_origin_s=803.1)
    return left, right


def make_camera(spec: CameraSpec, world: World, **overrides: object) -> SimCamera:
    """A :class:`SimCamera` from a spec; keyword ``overrides`` go to the camera (e.g. dropped_frames)."""
    rvec, tvec = look_at(spec.eye_mm, spec.target_mm)
    kwargs: dict[str, object] = dict(
        fx_px=spec.fx_px, fy_px=spec.fy_px, cx_px=spec.cx_px, cy_px=spec.cy_px, distortion=spec.distortion,
        rvec=rvec, tvec=tvec, fps=spec.fps, clock_ppm=spec.clock_ppm, start_offset_s=spec.start_offset_s,
        timestamp_origin_s=spec.timestamp_origin_s, line_time_s=spec.line_time_s, exposure_s=spec.exposure_s,
        psf_sigma_px=spec.psf_sigma_px, noise=spec.noise,
        drop_probability=spec.drop_probability, drop_window_s=spec.drop_window_s)
    kwargs.update(overrides)
    return SimCamera(spec.name, world, **kwargs)  # type: ignore[arg-type]


def default_stereo_pair(world: World, **overrides: object) -> tuple[SimCamera, SimCamera]:
    """The two default cameras ("left", "right") filming ``world``."""
    left, right = default_camera_specs()
    return make_camera(left, world, **overrides), make_camera(right, world, **overrides)
