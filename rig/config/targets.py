"""The geometry sections of ``rig.toml``: marker targets (``[targets.*]``) and the twin (``[sim]``).

All lengths in mm, in the robot's base frame unless the field says *flange frame* (targets carried by
the arm: their marker coordinates follow from the commanded pose, which the procedures record as truth).
Directions (``normal``, ``axis``, ``direction``, ``up``) are 3-vectors; they are normalised on load and
must not be zero.
"""


from __future__ import annotations

import math
from dataclasses import dataclass, field

from rig.config.schema import ConfigError, spec

VEC3_MM = spec(length=3, lo=-1e5, hi=1e5)


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
    offset_tool_mm: tuple[float, ...] = field(default=(0.0, 0.0, 30.0), metadata=VEC3_MM)


@dataclass(frozen=True)
class MarkerFrameTarget:
    """A rigid frame of markers carried by the arm; ``offsets_mm`` in the tool frame (≥ 4, non-coplanar)."""

    marker_diameter_mm: float = field(metadata=_POS)
    offsets_mm: tuple[tuple[float, ...], ...] = field(metadata=spec(length=(4, 200), lo=-1e4, hi=1e4))


@dataclass(frozen=True)
class SweepColumnTarget(_Directions):
    """A column of ``count`` markers at ``pitch_mm`` along ``column_direction``, centred at ``centre_mm`` (at
    rest, base frame), moved by ``body`` along ``axis``; ``normal`` is the marker plate's normal."""

    centre_mm: tuple[float, ...] = field(metadata=VEC3_MM)
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

    root_mm: tuple[float, ...] = field(metadata=VEC3_MM)
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

    centre_mm: tuple[float, ...] = field(metadata=VEC3_MM)
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

    centre_mm: tuple[float, ...] = field(metadata=VEC3_MM)
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
