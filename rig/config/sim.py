"""``[sim]``: the twin's hidden truth (camera intrinsics, poses, clock errors, noise, seed)."""

from __future__ import annotations

from dataclasses import dataclass, field

from rig.config.fiducial import SimFiducialConfig
from rig.config.schema import ConfigError, spec
from rig.config.targets import VEC3_MM


@dataclass(frozen=True)
class SimNoise:
    """Sensor levels and noise of a simulated camera, in 8-bit digital numbers (DN)."""

    background_level_dn: float = field(default=30.0, metadata=spec(lo=0.0, hi=255.0))
    marker_level_dn: float = field(default=220.0, metadata=spec(lo=0.0, hi=255.0))
    read_noise_dn: float = field(default=2.0, metadata=spec(lo=0.0, hi=100.0))
    shot_noise_dn2_per_dn: float = field(default=0.05, metadata=spec(lo=0.0, hi=10.0))


def _check_window(value: tuple[float, ...], path: str) -> None:
    if value[0] >= value[1]:
        raise ConfigError(path, f"{list(value)}; allowed: [start_s, stop_s] with start_s < stop_s")


@dataclass(frozen=True)
class SimCameraConfig:
    """A simulated camera's hidden truth (the twin's ``CameraSpec`` field for field): camera centre
    ``eye_mm`` looking at ``target_mm``, pinhole intrinsics (px), distortion (k1, k2, p1, p2), clock error
    (ppm), start offset and timestamp origin (s), rolling-shutter line time (s; absent = 90 % of the frame
    period over the rows), blur, noise and the share of sensor frames lost (``drop_probability``: a camera
    or a loaded host skipping frames, drawn per frame from the seed; only those starting within
    ``drop_window_s`` = [start, stop] world s when given). fps, exposure and resolution come from
    ``[cameras.<name>]``."""

    eye_mm: tuple[float, ...] = field(metadata=VEC3_MM)
    target_mm: tuple[float, ...] = field(default=(420.0, 0.0, 300.0), metadata=VEC3_MM)
    fx_px: float = field(default=2400.0, metadata=spec(lo=10.0, hi=1e5))
    fy_px: float = field(default=2400.0, metadata=spec(lo=10.0, hi=1e5))
    cx_px: float = field(default=959.5, metadata=spec(lo=-1e4, hi=1e5))
    cy_px: float = field(default=539.5, metadata=spec(lo=-1e4, hi=1e5))
    distortion: tuple[float, ...] = field(default=(0.0, 0.0, 0.0, 0.0),
                                          metadata=spec(length=4, lo=-1.0, hi=1.0))
    clock_ppm: float = field(default=0.0, metadata=spec(lo=-1000.0, hi=1000.0))
    start_offset_s: float = field(default=0.0, metadata=spec(lo=-10.0, hi=10.0))
    timestamp_origin_s: float = field(default=0.0, metadata=spec(lo=-1e9, hi=1e9))
    line_time_s: float | None = field(default=None, metadata=spec(lo=0.0, hi=1e-3))
    psf_sigma_px: float = field(default=0.6, metadata=spec(lo=0.0, hi=5.0))
    noise: SimNoise = field(default_factory=SimNoise)
    drop_probability: float = field(default=0.0, metadata=spec(lo=0.0, hi=0.45))
    drop_window_s: tuple[float, ...] | None = field(default=None, metadata=spec(
        length=2, lo=0.0, hi=1e9, check=_check_window))


def _check_lab_url(value: str, path: str) -> None:
    """``http://127.0.0.1:PORT`` (a loopback address: the lab is a mock, never on the network)."""
    from urllib.parse import urlsplit

    from drivers.mock._serve import require_loopback

    parts = urlsplit(value)
    try:
        host = require_loopback(parts.hostname or "")
        ok = parts.scheme == "http" and parts.port is not None and bool(host)
    except ValueError:
        ok = False
    if not ok:
        raise ConfigError(path, f"{value!r}; allowed: http://127.0.0.1:PORT (the control endpoint `rig mock "
                                "lab` prints, on a loopback address)")


@dataclass(frozen=True)
class SimConfig:
    """The twin: ``seed`` for all noise, the virtual clock (``rate`` None = instant, else virtual s per
    wall s), the arm's orientation speed/acceleration, the scene mounted at start, and one
    :class:`SimCameraConfig` per simulated camera. (Robot home pose and crank radius come from
    ``[devices.robot]`` / ``[devices.exciter]``; targets from ``[targets]``.)"""

    seed: int = field(default=0, metadata=spec(lo=0, hi=2**63 - 1))
    rate: float | None = field(default=None, metadata=spec(lo=0.0, lo_open=True, hi=1e6))
    robot_rot_speed_deg_s: float = field(default=120.0, metadata=spec(lo=0.0, lo_open=True, hi=1e4))
    robot_rot_accel_deg_s2: float = field(default=480.0, metadata=spec(lo=0.0, lo_open=True, hi=1e5))
    initial_scene: str = field(default="calibration_plate", metadata=spec(choices=(
        "calibration_plate", "single_marker", "marker_frame", "plate", "rotor", "sweep_column", "none")))
    cameras: dict[str, SimCameraConfig] = field(default_factory=dict)
    fiducial: SimFiducialConfig | None = None
    lab_url: str | None = field(default=None, metadata=spec(check=_check_lab_url, doc=(
        "the `rig mock lab` whose world the cameras film (its control endpoint): the station mounts each "
        "target there as well as on its own twin")))
