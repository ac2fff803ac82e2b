"""The geometry sections of ``rig.toml``: marker targets (``[targets.*]``) and the twin (``[sim]``).

All lengths in mm, in the robot's base frame unless the field says *flange frame* (targets carried by
the arm: their marker coordinates follow from the commanded pose, which the procedures record as truth).
Directions (``normal``, ``axis``, ``direction``, ``up``) are 3-vectors; they are normalised on load and
must not be zero.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from rig.config_schema import ConfigError, spec

_VEC3 = spec(length=3, lo=-1e5, hi=1e5)
_POS = spec(lo=0.0, lo_open=True, hi=1e4)
_COUNT = spec(lo=1, hi=1000)


def _non_zero(value: tuple[float, ...], where: str) -> None:
    if math.sqrt(sum(v * v for v in value)) < 1e-9:
        raise ConfigError(where, f"{list(value)} is a zero vector; allowed: any non-zero direction")


def _normalised(v: tuple[float, ...]) -> tuple[float, ...]:
    n = math.sqrt(sum(x * x for x in v))
    return tuple(x / n for x in v)


def _dir_field(default: tuple[float, ...]) -> tuple[float, ...]:
    return field(default=default, metadata=spec(length=3, lo=-1e5, hi=1e5, check=_non_zero))


class _Directions:
    """Mixin: normalise every direction field after construction."""

    _DIRECTIONS: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for name in self._DIRECTIONS:
            object.__setattr__(self, name, _normalised(getattr(self, name)))


_BODIES = spec(choices=("exciter", "rotor", "shaker"))


@dataclass(frozen=True)
class CalibrationPlateTarget(_Directions):
    """Grid of ``rows × cols`` markers at ``pitch_mm`` on a plate held by the flange, ``standoff_mm`` in
    front of it along tool z, and slid along its normal (tool z). Markers lie in the tool x–y plane,
    centred on the tool z axis, row 0 on top (+tool y).

    Procedure data: ``start_pose`` is the arm pose (x, y, z mm; rx, ry, rz deg) of the middle position;
    position ``i`` is ``start_pose`` moved by ``slide_positions_mm[i]`` along tool z (≥ 2 positions, so the
    control points are not coplanar).
    """

    cols: int = field(metadata=spec(lo=2, hi=1000))
    rows: int = field(metadata=spec(lo=2, hi=1000))
    pitch_mm: float = field(metadata=_POS)
    marker_diameter_mm: float = field(metadata=_POS)
    start_pose: tuple[float, ...] = field(metadata=spec(length=6))
    slide_positions_mm: tuple[float, ...] = field(metadata=spec(length=(2, 100), lo=-2000.0, hi=2000.0))
    standoff_mm: float = field(default=30.0, metadata=spec(lo=-1e4, hi=1e4))

    def __post_init__(self) -> None:
        if self.marker_diameter_mm >= self.pitch_mm:
            raise ConfigError("targets.calibration_plate.marker_diameter_mm",
                              f"{self.marker_diameter_mm:g} must be < pitch_mm = {self.pitch_mm:g}")
        if len(set(self.slide_positions_mm)) < 2:
            raise ConfigError("targets.calibration_plate.slide_positions_mm",
                              f"{list(self.slide_positions_mm)}: allowed: at least 2 distinct positions")


@dataclass(frozen=True)
class SingleMarkerTarget:
    """One marker carried by the arm; ``offset_tool_mm`` is its centre in the tool (flange) frame."""

    marker_diameter_mm: float = field(metadata=_POS)
    offset_tool_mm: tuple[float, ...] = field(default=(0.0, 0.0, 30.0), metadata=_VEC3)


@dataclass(frozen=True)
class MarkerFrameTarget:
    """A rigid frame of markers carried by the arm; ``offsets_mm`` in the tool frame (≥ 4, non-coplanar)."""

    marker_diameter_mm: float = field(metadata=_POS)
    offsets_mm: tuple[tuple[float, ...], ...] = field(metadata=spec(length=(4, 200), lo=-1e4, hi=1e4))


@dataclass(frozen=True)
class SweepColumnTarget(_Directions):
    """A column of ``count`` markers at ``pitch_mm`` along ``column_direction``, centred at ``centre_mm`` (at
    rest, base frame), moved by ``body`` along ``axis``; ``normal`` is the marker plate's normal."""

    centre_mm: tuple[float, ...] = field(metadata=_VEC3)
    count: int = field(metadata=_COUNT)
    pitch_mm: float = field(metadata=_POS)
    marker_diameter_mm: float = field(metadata=_POS)
    body: str = field(default="exciter", metadata=_BODIES)
    column_direction: tuple[float, ...] = _dir_field((0.0, 0.0, 1.0))
    axis: tuple[float, ...] = _dir_field((0.0, 0.0, 1.0))
    normal: tuple[float, ...] = _dir_field((1.0, 0.0, 0.0))
    _DIRECTIONS = ("column_direction", "axis", "normal")


@dataclass(frozen=True)
class PlateTarget(_Directions):
    """A plate clamped along its edge at ``root_mm`` (base frame), ``length_mm`` long along
    ``length_direction``, its free end driven by ``body`` along ``axis`` (absent: along ``normal``).
    ``rows × cols`` markers: column c at (c + 1)·``pitch_mm`` from the clamp, rows ``row_pitch_mm`` apart
    along ``width_direction``; a marker moves by the tip displacement × (3ξ² − ξ³)/2, ξ = s / length."""

    root_mm: tuple[float, ...] = field(metadata=_VEC3)
    length_mm: float = field(metadata=_POS)
    cols: int = field(metadata=_COUNT)
    rows: int = field(metadata=_COUNT)
    pitch_mm: float = field(metadata=_POS)
    row_pitch_mm: float = field(metadata=_POS)
    marker_diameter_mm: float = field(metadata=_POS)
    body: str = field(default="exciter", metadata=_BODIES)
    length_direction: tuple[float, ...] = _dir_field((0.0, 1.0, 0.0))
    width_direction: tuple[float, ...] = _dir_field((0.0, 0.0, 1.0))
    normal: tuple[float, ...] = _dir_field((1.0, 0.0, 0.0))
    axis: tuple[float, ...] | None = field(default=None, metadata=spec(length=3, check=_non_zero))
    _DIRECTIONS = ("length_direction", "width_direction", "normal")

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.cols * self.pitch_mm > self.length_mm:
            raise ConfigError("targets.plate.cols", f"{self.cols} columns at {self.pitch_mm:g} mm reach "
                                                    f"beyond length_mm = {self.length_mm:g}")


@dataclass(frozen=True)
class RotorTarget(_Directions):
    """A marker at ``radius_mm`` from ``centre_mm`` on a disc turning about ``axis``; at angle 0 it lies along
    ``zero_direction`` from the centre (positive angles right-handed about ``axis``)."""

    centre_mm: tuple[float, ...] = field(metadata=_VEC3)
    radius_mm: float = field(metadata=_POS)
    marker_diameter_mm: float = field(metadata=_POS)
    axis: tuple[float, ...] = _dir_field((1.0, 0.0, 0.0))
    zero_direction: tuple[float, ...] = _dir_field((0.0, 1.0, 0.0))
    _DIRECTIONS = ("axis",)


@dataclass(frozen=True)
class ReferenceMarkers(_Directions):
    """Fixed reference markers (base frame, ≥ 3, not collinear), always in view, facing ``normal``."""

    positions_mm: tuple[tuple[float, ...], ...] = field(metadata=spec(length=(3, 100), lo=-1e5, hi=1e5))
    marker_diameter_mm: float = field(metadata=_POS)
    normal: tuple[float, ...] = _dir_field((1.0, 0.0, 0.0))
    _DIRECTIONS = ("normal",)


@dataclass(frozen=True)
class MeasurementVolume:
    """The box the accuracy procedure fills with poses: ``centre_mm`` and edge lengths ``size_mm``."""

    centre_mm: tuple[float, ...] = field(metadata=_VEC3)
    size_mm: tuple[float, ...] = field(metadata=spec(length=3, lo=1.0, hi=1e4))


@dataclass(frozen=True)
class TargetsConfig:
    """Marker targets; field names and meanings match the twin's :mod:`drivers.sim.targets` one to one
    (plus the procedure-only ``start_pose``/``slide_positions_mm`` and ``volume``)."""

    calibration_plate: CalibrationPlateTarget | None = None
    single_marker: SingleMarkerTarget | None = None
    marker_frame: MarkerFrameTarget | None = None
    sweep_column: SweepColumnTarget | None = None
    plate: PlateTarget | None = None
    rotor: RotorTarget | None = None
    references: ReferenceMarkers | None = None
    volume: MeasurementVolume | None = None

    def __post_init__(self) -> None:
        for name, key in (("marker_frame", "offsets_mm"), ("references", "positions_mm")):
            target = getattr(self, name)
            if target is None:
                continue
            for i, p in enumerate(getattr(target, key)):
                if len(p) != 3:
                    raise ConfigError(f"targets.{name}.{key}[{i}]", f"{list(p)} has {len(p)} elements; "
                                                                   "allowed: exactly 3 (x, y, z mm)")


@dataclass(frozen=True)
class SimNoise:
    """Sensor levels and noise of a simulated camera, in 8-bit digital numbers (DN)."""

    background_level_dn: float = field(default=30.0, metadata=spec(lo=0.0, hi=255.0))
    marker_level_dn: float = field(default=220.0, metadata=spec(lo=0.0, hi=255.0))
    read_noise_dn: float = field(default=2.0, metadata=spec(lo=0.0, hi=100.0))
    shot_noise_dn2_per_dn: float = field(default=0.05, metadata=spec(lo=0.0, hi=10.0))


@dataclass(frozen=True)
class SimCameraConfig:
    """A simulated camera's hidden truth (the twin's ``CameraSpec`` field for field): camera centre
    ``eye_mm`` looking at ``target_mm``, pinhole intrinsics (px), distortion (k1, k2, p1, p2), clock error
    (ppm), start offset and timestamp origin (s), rolling-shutter line time (s; absent = 90 % of the frame
    period over the rows), blur and noise. fps, exposure and resolution come from ``[cameras.<name>]``."""

    eye_mm: tuple[float, ...] = field(metadata=_VEC3)
    target_mm: tuple[float, ...] = field(default=(420.0, 0.0, 300.0), metadata=_VEC3)
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
