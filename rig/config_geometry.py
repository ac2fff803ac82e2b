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


@dataclass(frozen=True)
class CalibrationPlateTarget(_Directions):
    """Plate of ``rows × cols`` markers at ``pitch_mm``, carried by the arm and slid along ``normal``.

    ``start_pose`` is the arm pose (x, y, z mm; rx, ry, rz deg) of the first position; position ``i`` is
    ``start_pose`` moved by ``slide_positions_mm[i]`` along ``normal`` (base frame). ``offset_mm`` is the
    plate centre in the flange frame; the markers lie in the flange x–y plane around it, row-major from
    (-x, +y).
    """

    rows: int = field(metadata=_COUNT)
    cols: int = field(metadata=_COUNT)
    pitch_mm: float = field(metadata=_POS)
    marker_diameter_mm: float = field(metadata=_POS)
    start_pose: tuple[float, ...] = field(metadata=spec(length=6))
    slide_positions_mm: tuple[float, ...] = field(metadata=spec(length=(2, 100), lo=-2000.0, hi=2000.0))
    normal: tuple[float, ...] = _dir_field((0.0, -1.0, 0.0))
    offset_mm: tuple[float, ...] = field(default=(0.0, 0.0, 0.0), metadata=_VEC3)
    _DIRECTIONS = ("normal",)


@dataclass(frozen=True)
class SingleMarkerTarget:
    """One marker carried by the arm; ``offset_mm`` is its centre in the flange frame."""

    marker_diameter_mm: float = field(metadata=_POS)
    offset_mm: tuple[float, ...] = field(default=(0.0, 0.0, 0.0), metadata=_VEC3)


@dataclass(frozen=True)
class MarkerFrameTarget:
    """A rigid frame of markers carried by the arm; ``markers_mm`` in the flange frame (≥ 3 markers)."""

    marker_diameter_mm: float = field(metadata=_POS)
    markers_mm: tuple[tuple[float, ...], ...] = field(metadata=spec(length=(3, 200), lo=-1e4, hi=1e4))


@dataclass(frozen=True)
class SweepColumnTarget(_Directions):
    """A column of ``n_markers`` on the exciter's arm: first marker at ``base_mm`` (at rest), the others
    at ``pitch_mm`` along ``direction``; the column vibrates along ``axis`` (amplitude: crank radius)."""

    n_markers: int = field(metadata=_COUNT)
    pitch_mm: float = field(metadata=_POS)
    marker_diameter_mm: float = field(metadata=_POS)
    base_mm: tuple[float, ...] = field(metadata=_VEC3)
    direction: tuple[float, ...] = _dir_field((0.0, 0.0, 1.0))
    axis: tuple[float, ...] = _dir_field((1.0, 0.0, 0.0))
    _DIRECTIONS = ("direction", "axis")


@dataclass(frozen=True)
class PlateTarget(_Directions):
    """The oscillating plate: ``rows × cols`` markers at ``pitch_mm``, centred at ``centre_mm`` (at rest) in
    the plane spanned by ``row_direction`` and ``col_direction``; it oscillates along ``axis``."""

    rows: int = field(metadata=_COUNT)
    cols: int = field(metadata=_COUNT)
    pitch_mm: float = field(metadata=_POS)
    marker_diameter_mm: float = field(metadata=_POS)
    centre_mm: tuple[float, ...] = field(metadata=_VEC3)
    row_direction: tuple[float, ...] = _dir_field((1.0, 0.0, 0.0))
    col_direction: tuple[float, ...] = _dir_field((0.0, 0.0, -1.0))
    axis: tuple[float, ...] = _dir_field((0.0, 1.0, 0.0))
    _DIRECTIONS = ("row_direction", "col_direction", "axis")


@dataclass(frozen=True)
class RotorTarget(_Directions):
    """A marker at ``radius_mm`` from ``centre_mm`` on a rotor turning about ``axis``."""

    radius_mm: float = field(metadata=_POS)
    marker_diameter_mm: float = field(metadata=_POS)
    centre_mm: tuple[float, ...] = field(metadata=_VEC3)
    axis: tuple[float, ...] = _dir_field((0.0, -1.0, 0.0))
    _DIRECTIONS = ("axis",)


@dataclass(frozen=True)
class ReferenceMarkers:
    """Fixed reference markers (always in view), base frame."""

    marker_diameter_mm: float = field(metadata=_POS)
    positions_mm: tuple[tuple[float, ...], ...] = field(metadata=spec(length=(1, 100), lo=-1e5, hi=1e5))


@dataclass(frozen=True)
class MeasurementVolume:
    """The box the accuracy procedure fills with poses: ``centre_mm`` and edge lengths ``size_mm``."""

    centre_mm: tuple[float, ...] = field(metadata=_VEC3)
    size_mm: tuple[float, ...] = field(metadata=spec(length=3, lo=1.0, hi=1e4))


@dataclass(frozen=True)
class TargetsConfig:
    calibration_plate: CalibrationPlateTarget | None = None
    single_marker: SingleMarkerTarget | None = None
    marker_frame: MarkerFrameTarget | None = None
    sweep_column: SweepColumnTarget | None = None
    plate: PlateTarget | None = None
    rotor: RotorTarget | None = None
    reference: ReferenceMarkers | None = None
    volume: MeasurementVolume | None = None

    def __post_init__(self) -> None:
        for name in ("marker_frame", "reference"):
            target = getattr(self, name)
            if target is None:
                continue
            points = target.markers_mm if name == "marker_frame" else target.positions_mm
            for i, p in enumerate(points):
                if len(p) != 3:
                    key = "markers_mm" if name == "marker_frame" else "positions_mm"
                    raise ConfigError(f"targets.{name}.{key}[{i}]", f"{list(p)} has {len(p)} elements; "
                                                                   "allowed: exactly 3 (x, y, z mm)")


@dataclass(frozen=True)
class SimCameraConfig(_Directions):
    """A simulated camera's hidden truth: pinhole intrinsics, distortion (k1, k2, p1, p2), pose (camera
    centre ``position_mm`` looking at ``look_at_mm`` with ``up``), clock error, rolling shutter, noise."""

    focal_px: float = field(metadata=spec(lo=10.0, hi=1e5))
    principal_point_px: tuple[float, ...] = field(metadata=spec(length=2, lo=-1e4, hi=1e5))
    position_mm: tuple[float, ...] = field(metadata=_VEC3)
    look_at_mm: tuple[float, ...] = field(metadata=_VEC3)
    up: tuple[float, ...] = _dir_field((0.0, 0.0, 1.0))
    distortion: tuple[float, ...] = field(default=(0.0, 0.0, 0.0, 0.0),
                                          metadata=spec(length=4, lo=-1.0, hi=1.0))
    clock_ppm: float = field(default=0.0, metadata=spec(lo=-1000.0, hi=1000.0))
    start_offset_s: float = field(default=0.0, metadata=spec(lo=-10.0, hi=10.0))
    line_time_s: float = field(default=0.0, metadata=spec(lo=0.0, hi=1e-3))
    noise_grey: float = field(default=0.0, metadata=spec(lo=0.0, hi=100.0))
    _DIRECTIONS = ("up",)


@dataclass(frozen=True)
class SimConfig:
    """The twin: ``seed`` for all noise, the virtual clock (``rate`` None = instant, else virtual s per
    wall s), and one :class:`SimCameraConfig` per simulated camera."""

    seed: int = field(default=0, metadata=spec(lo=0, hi=2**63 - 1))
    rate: float | None = field(default=None, metadata=spec(lo=0.0, lo_open=True, hi=1e6))
    cameras: dict[str, SimCameraConfig] = field(default_factory=dict)
