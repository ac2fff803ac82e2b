"""Stereo measurement core: pure functions on numpy arrays, no I/O (DESIGN.md, layer "math")."""

from rig.stereo.errors import (
    DegenerateCalibrationError,
    DegenerateGeometryError,
    InputArrayError,
    NoMarkersError,
    StereoError,
    TimingError,
)

__all__ = [
    "DegenerateCalibrationError",
    "DegenerateGeometryError",
    "InputArrayError",
    "NoMarkersError",
    "StereoError",
    "TimingError",
]
