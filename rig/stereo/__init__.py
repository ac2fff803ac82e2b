"""Stereo measurement core: pure functions on numpy arrays, no I/O (DESIGN.md, layer "math")."""

from rig.stereo.dlt import DLTCamera, calibrate_dlt
from rig.stereo.dlt11 import P_from_dlt11, dlt11_from_P, solve_dlt11
from rig.stereo.epipolar import (
    Matches,
    epipolar_distance_px,
    fundamental_from_projections,
    match_epipolar,
)
from rig.stereo.errors import (
    CalibrationFormatError,
    DegenerateCalibrationError,
    DegenerateGeometryError,
    DegenerateReferenceError,
    DistortionError,
    InputArrayError,
    NoMarkersError,
    StereoError,
    TimingError,
)
from rig.stereo.markers import (
    FLAG_BORDER,
    FLAG_LOST,
    FLAG_OCCLUDED,
    FLAG_SATURATED,
    MARKER_DTYPE,
    detect_markers,
    track_markers,
)
from rig.stereo.reference import RigidTransform, Stabilized, rigid_transform, stabilize
from rig.stereo.triangulate import Triangulation, triangulate

__all__ = [
    "FLAG_BORDER",
    "FLAG_LOST",
    "FLAG_OCCLUDED",
    "FLAG_SATURATED",
    "MARKER_DTYPE",
    "CalibrationFormatError",
    "DLTCamera",
    "DegenerateCalibrationError",
    "DegenerateGeometryError",
    "DegenerateReferenceError",
    "DistortionError",
    "InputArrayError",
    "Matches",
    "NoMarkersError",
    "P_from_dlt11",
    "RigidTransform",
    "Stabilized",
    "StereoError",
    "TimingError",
    "Triangulation",
    "calibrate_dlt",
    "detect_markers",
    "dlt11_from_P",
    "epipolar_distance_px",
    "fundamental_from_projections",
    "match_epipolar",
    "rigid_transform",
    "solve_dlt11",
    "stabilize",
    "track_markers",
    "triangulate",
]
