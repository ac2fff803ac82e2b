"""Stereo measurement core: pure functions on numpy arrays, no I/O (DESIGN.md, layer "math").

The public names below are loaded on first use (PEP 562): importing one submodule (``rig.stereo.errors``,
``rig.stereo.fiducial``) does not load the whole core (SciPy, OpenCV, ≈ 30 modules), which a ``rig`` process
that stops before any stereo work (a dry run, a refused parameter) does without."""

from __future__ import annotations

import importlib
import sys
import types
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from rig.stereo.dlt import DLTCamera, calibrate_dlt
    from rig.stereo.dlt11 import P_from_dlt11, dlt11_from_P, solve_dlt11
    from rig.stereo.epipolar import (
        Matches,
        epipolar_distance_px,
        fundamental_from_projections,
        match_epipolar,
    )
    from rig.stereo.errors import (
        AmbiguousFrequencyError,
        AmbiguousOffsetError,
        CalibrationFormatError,
        DegenerateCalibrationError,
        DegenerateGeometryError,
        DegenerateReferenceError,
        DelayOutOfRangeError,
        DistortionError,
        InputArrayError,
        LineTimeNotObservableError,
        NoCommonMotionError,
        NoMarkersError,
        NonMonotonicTimestampsError,
        NonUniformSamplingError,
        NotRotatingError,
        StereoError,
        TimingError,
        TooFewSamplesError,
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
    from rig.stereo.resample import resample
    from rig.stereo.sinefit import SineFit, SlidingSineFit, fit_sine, sliding_sine_fit
    from rig.stereo.spectrum import Spectrogram, Spectrum, spectrum, stft
    from rig.stereo.timing import TimingResult, corrected_times, estimate_offset
    from rig.stereo.trajectory import (
        SineBasis,
        SplineBasis,
        Trajectory,
        fit_sine_trajectory,
        fit_spline_trajectory,
        fit_trajectory,
    )
    from rig.stereo.trajectory_sweep import SweepTrack, sliding_sine_trajectory
    from rig.stereo.triangulate import Triangulation, triangulate

__all__ = [
    "FLAG_BORDER",
    "FLAG_LOST",
    "FLAG_OCCLUDED",
    "FLAG_SATURATED",
    "MARKER_DTYPE",
    "AmbiguousFrequencyError",
    "AmbiguousOffsetError",
    "CalibrationFormatError",
    "DLTCamera",
    "DegenerateCalibrationError",
    "DegenerateGeometryError",
    "DegenerateReferenceError",
    "DelayOutOfRangeError",
    "DistortionError",
    "InputArrayError",
    "LineTimeNotObservableError",
    "Matches",
    "NoCommonMotionError",
    "NoMarkersError",
    "NonMonotonicTimestampsError",
    "NonUniformSamplingError",
    "NotRotatingError",
    "P_from_dlt11",
    "RigidTransform",
    "SineBasis",
    "SineFit",
    "SlidingSineFit",
    "Spectrogram",
    "Spectrum",
    "SplineBasis",
    "Stabilized",
    "StereoError",
    "SweepTrack",
    "TimingError",
    "TimingResult",
    "TooFewSamplesError",
    "Trajectory",
    "Triangulation",
    "calibrate_dlt",
    "corrected_times",
    "detect_markers",
    "dlt11_from_P",
    "epipolar_distance_px",
    "estimate_offset",
    "fit_sine",
    "fit_sine_trajectory",
    "fit_spline_trajectory",
    "fit_trajectory",
    "fundamental_from_projections",
    "match_epipolar",
    "resample",
    "rigid_transform",
    "sliding_sine_fit",
    "sliding_sine_trajectory",
    "solve_dlt11",
    "spectrum",
    "stabilize",
    "stft",
    "track_markers",
    "triangulate",
]

# the submodule of rig.stereo defining each public name
_SUBMODULE = {
    "DLTCamera": "dlt",
    "calibrate_dlt": "dlt",
    "P_from_dlt11": "dlt11",
    "dlt11_from_P": "dlt11",
    "solve_dlt11": "dlt11",
    "Matches": "epipolar",
    "epipolar_distance_px": "epipolar",
    "fundamental_from_projections": "epipolar",
    "match_epipolar": "epipolar",
    "AmbiguousFrequencyError": "errors",
    "AmbiguousOffsetError": "errors",
    "CalibrationFormatError": "errors",
    "DegenerateCalibrationError": "errors",
    "DegenerateGeometryError": "errors",
    "DegenerateReferenceError": "errors",
    "DelayOutOfRangeError": "errors",
    "DistortionError": "errors",
    "InputArrayError": "errors",
    "LineTimeNotObservableError": "errors",
    "NoCommonMotionError": "errors",
    "NoMarkersError": "errors",
    "NonMonotonicTimestampsError": "errors",
    "NonUniformSamplingError": "errors",
    "NotRotatingError": "errors",
    "StereoError": "errors",
    "TimingError": "errors",
    "TooFewSamplesError": "errors",
    "FLAG_BORDER": "markers",
    "FLAG_LOST": "markers",
    "FLAG_OCCLUDED": "markers",
    "FLAG_SATURATED": "markers",
    "MARKER_DTYPE": "markers",
    "detect_markers": "markers",
    "track_markers": "markers",
    "RigidTransform": "reference",
    "Stabilized": "reference",
    "rigid_transform": "reference",
    "stabilize": "reference",
    "resample": "resample",
    "SineFit": "sinefit",
    "SlidingSineFit": "sinefit",
    "fit_sine": "sinefit",
    "sliding_sine_fit": "sinefit",
    "Spectrogram": "spectrum",
    "Spectrum": "spectrum",
    "spectrum": "spectrum",
    "stft": "spectrum",
    "TimingResult": "timing",
    "corrected_times": "timing",
    "estimate_offset": "timing",
    "SineBasis": "trajectory",
    "SplineBasis": "trajectory",
    "Trajectory": "trajectory",
    "fit_sine_trajectory": "trajectory",
    "fit_spline_trajectory": "trajectory",
    "fit_trajectory": "trajectory",
    "SweepTrack": "trajectory_sweep",
    "sliding_sine_trajectory": "trajectory_sweep",
    "Triangulation": "triangulate",
    "triangulate": "triangulate",
}


class _Package(types.ModuleType):
    """This package's module type: a public name wins over the submodule of the same name (``resample``,
    ``spectrum``, ``triangulate``), which the import system binds on the package when the submodule is first
    loaded (by another submodule, before anyone asked for the function)."""

    def __setattr__(self, name: str, value: Any) -> None:
        if name in _SUBMODULE and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


def __getattr__(name: str) -> Any:
    """A public name, imported from its submodule on first use (then cached as a module attribute)."""
    submodule = _SUBMODULE.get(name)
    if submodule is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{submodule}"), name)
    globals()[name] = value
    return value


sys.modules[__name__].__class__ = _Package
