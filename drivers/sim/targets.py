"""Geometry of the marker targets of the rig, in millimetres (constructor data with sensible defaults).

Frames: the robot **base** frame (origin at the robot base, x forward towards the cameras, z up) and the
**tool** frame of the flange (Denso convention). At the default home orientation rx, ry, rz = 90, 0, 90 deg
the tool axes are x_tool = +y_base, y_tool = +z_base (up), z_tool = +x_base (towards the cameras).
Targets carried by the arm give their markers in the tool frame; the others in the base frame.

Marker ids: ``cal_r{row}c{col}`` (calibration plate, row 0 on top), ``arm``, ``frame{k}``, ``col{k}``
(sweep column, 0 at the bottom), ``plate_r{row}c{col}`` (oscillating plate, col 0 nearest the clamp),
``rotor``, ``ref{k}``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "CalibrationPlate", "MarkerFrame", "OscillatingPlate", "ReferenceMarkers", "RotorTarget", "SingleMarker",
    "SweepColumn", "TargetSet", "cantilever_shape", "unit",
]


def unit(v: tuple[float, float, float] | NDArray[np.float64], name: str = "vector") -> NDArray[np.float64]:
    """``v`` normalised to length 1; ValueError naming ``name`` if it is zero or not 3 finite numbers."""
    a = np.asarray(v, dtype=float)
    n = float(np.linalg.norm(a)) if a.shape == (3,) else 0.0
    if a.shape != (3,) or not np.all(np.isfinite(a)) or n < 1e-12:
        raise ValueError(f"{name} must be 3 finite numbers with non-zero length, got {v!r}")
    return a / n


def _check_positive(**values: float) -> None:
    for name, v in values.items():
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a finite number > 0, got {v!r}")


@dataclass(frozen=True)
class CalibrationPlate:
    """Grid of circular markers on a plate held by the flange and slid along its normal (tool z)."""

    cols: int = 7
    rows: int = 5
    pitch_mm: float = 40.0
    marker_diameter_mm: float = 12.0
    standoff_mm: float = 30.0  # plate surface in front of the flange, along tool z

    def __post_init__(self) -> None:
        if self.cols < 2 or self.rows < 2:
            raise ValueError(f"cols and rows must be ≥ 2, got cols={self.cols}, rows={self.rows}")
        _check_positive(pitch_mm=self.pitch_mm, marker_diameter_mm=self.marker_diameter_mm)
        if self.marker_diameter_mm >= self.pitch_mm:
            raise ValueError(f"marker_diameter_mm={self.marker_diameter_mm} must be < "
                             f"pitch_mm={self.pitch_mm}")

    def offsets_tool_mm(self) -> dict[str, NDArray[np.float64]]:
        out = {}
        for r in range(self.rows):
            for c in range(self.cols):
                x = (c - (self.cols - 1) / 2) * self.pitch_mm
                y = ((self.rows - 1) / 2 - r) * self.pitch_mm
                out[f"cal_r{r}c{c}"] = np.array([x, y, self.standoff_mm])
        return out


@dataclass(frozen=True)
class SingleMarker:
    """One marker on the flange (the paper's accuracy check)."""

    marker_diameter_mm: float = 16.0
    offset_tool_mm: tuple[float, float, float] = (0.0, 0.0, 30.0)

    def offsets_tool_mm(self) -> dict[str, NDArray[np.float64]]:
        return {"arm": np.array(self.offset_tool_mm, dtype=float)}


@dataclass(frozen=True)
class MarkerFrame:
    """A rigid frame on the flange carrying markers at known, non-coplanar offsets (tool frame)."""

    marker_diameter_mm: float = 12.0
    offsets_mm: tuple[tuple[float, float, float], ...] = (
        (-100.0, 75.0, 30.0), (0.0, 75.0, 70.0), (100.0, 75.0, 30.0), (-100.0, -75.0, 70.0),
        (0.0, -75.0, 30.0), (100.0, -75.0, 70.0), (-50.0, 0.0, 110.0), (50.0, 0.0, 50.0),
    )

    def offsets_tool_mm(self) -> dict[str, NDArray[np.float64]]:
        if len(self.offsets_mm) < 4:
            raise ValueError(f"a marker frame needs ≥ 4 markers, got {len(self.offsets_mm)}")
        return {f"frame{k}": np.array(o, dtype=float) for k, o in enumerate(self.offsets_mm)}


@dataclass(frozen=True)
class SweepColumn:
    """One column of markers on a plate on the rigid vibrating arm; every marker moves by body displacement
    along ``axis`` (the crank exciter by default, amplitude = crank radius)."""

    body: str = "exciter"
    centre_mm: tuple[float, float, float] = (420.0, 0.0, 300.0)  # middle of the column at rest, base frame
    column_direction: tuple[float, float, float] = (0.0, 0.0, 1.0)
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)  # displacement direction
    normal: tuple[float, float, float] = (1.0, 0.0, 0.0)
    count: int = 5
    pitch_mm: float = 35.0
    marker_diameter_mm: float = 12.0

    def rest_positions_mm(self) -> dict[str, NDArray[np.float64]]:
        d = unit(self.column_direction, "column_direction")
        c = np.asarray(self.centre_mm, float)
        return {f"col{k}": c + (k - (self.count - 1) / 2) * self.pitch_mm * d for k in range(self.count)}


def cantilever_shape(xi: float | NDArray[np.float64]) -> NDArray[np.float64]:
    """Static deflection of a clamped beam displaced at its tip, normalised to 1 at ξ = 1: (3ξ² − ξ³)/2."""
    x = np.asarray(xi, float)
    shape: NDArray[np.float64] = 0.5 * (3.0 * x * x - x**3)
    return shape


@dataclass(frozen=True)
class OscillatingPlate:
    """A plate clamped along one edge; its free end is driven by ``body`` with displacement along ``axis``
    (default: the plate normal, i.e. bending). A marker at distance s from the clamp moves by
    displacement × :func:`cantilever_shape` (s / length_mm), so the amplitude grows along the plate."""

    body: str = "exciter"
    root_mm: tuple[float, float, float] = (420.0, -160.0, 300.0)  # middle of the clamped edge, base frame
    length_direction: tuple[float, float, float] = (0.0, 1.0, 0.0)
    width_direction: tuple[float, float, float] = (0.0, 0.0, 1.0)
    normal: tuple[float, float, float] = (1.0, 0.0, 0.0)
    axis: tuple[float, float, float] | None = None  # None: along the normal
    length_mm: float = 320.0  # clamp to driven free end
    cols: int = 6
    rows: int = 2
    pitch_mm: float = 50.0  # along the length, first column one pitch from the clamp
    row_pitch_mm: float = 60.0
    marker_diameter_mm: float = 12.0

    def rest_positions_mm(self) -> dict[str, tuple[NDArray[np.float64], float]]:
        """id → (rest position, shape weight along the plate)."""
        _check_positive(length_mm=self.length_mm, pitch_mm=self.pitch_mm)
        lv = unit(self.length_direction, "length_direction")
        wv = unit(self.width_direction, "width_direction")
        root = np.asarray(self.root_mm, float)
        out = {}
        for r in range(self.rows):
            for c in range(self.cols):
                s = (c + 1) * self.pitch_mm
                if s > self.length_mm:
                    raise ValueError(f"column {c} at {s} mm lies beyond length_mm={self.length_mm}")
                w = ((self.rows - 1) / 2 - r) * self.row_pitch_mm
                out[f"plate_r{r}c{c}"] = (root + s * lv + w * wv, float(cantilever_shape(s / self.length_mm)))
        return out

    def displacement_axis(self) -> NDArray[np.float64]:
        return unit(self.axis if self.axis is not None else self.normal, "axis")


@dataclass(frozen=True)
class RotorTarget:
    """A marker at ``radius_mm`` on a disc turning about ``axis`` through ``centre_mm``; at angle 0 the
    marker lies along ``zero_direction`` from the centre; positive angles turn right-handed about ``axis``."""

    centre_mm: tuple[float, float, float] = (420.0, 0.0, 300.0)
    axis: tuple[float, float, float] = (1.0, 0.0, 0.0)
    zero_direction: tuple[float, float, float] = (0.0, 1.0, 0.0)
    radius_mm: float = 60.0
    marker_diameter_mm: float = 12.0

    def basis(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """(e0, e1, axis): marker at centre + r·(cos θ e0 + sin θ e1)."""
        a = unit(self.axis, "axis")
        z = np.asarray(self.zero_direction, float)
        e0 = unit(z - np.dot(z, a) * a, "zero_direction (perpendicular part)")
        return e0, np.cross(a, e0), a


@dataclass(frozen=True)
class ReferenceMarkers:
    """Fixed markers (base frame), always present; not collinear, so they can fix a rigid transform."""

    positions_mm: tuple[tuple[float, float, float], ...] = (
        (200.0, -230.0, 470.0), (220.0, 0.0, 530.0), (200.0, 230.0, 470.0), (180.0, 250.0, 110.0),
    )
    normal: tuple[float, float, float] = (1.0, 0.0, 0.0)
    marker_diameter_mm: float = 16.0

    def positions(self) -> dict[str, NDArray[np.float64]]:
        if len(self.positions_mm) < 3:
            raise ValueError(f"need ≥ 3 reference markers, got {len(self.positions_mm)}")
        return {f"ref{k}": np.array(p, dtype=float) for k, p in enumerate(self.positions_mm)}


@dataclass(frozen=True)
class TargetSet:
    """All targets of the rig (one of them mounted at a time, plus the references)."""

    calibration_plate: CalibrationPlate = field(default_factory=CalibrationPlate)
    single_marker: SingleMarker = field(default_factory=SingleMarker)
    marker_frame: MarkerFrame = field(default_factory=MarkerFrame)
    sweep_column: SweepColumn = field(default_factory=SweepColumn)
    plate: OscillatingPlate = field(default_factory=OscillatingPlate)
    rotor: RotorTarget = field(default_factory=RotorTarget)
    references: ReferenceMarkers = field(default_factory=ReferenceMarkers)
