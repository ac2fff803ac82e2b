"""Exceptions of the stereo core. Each message says what to change; nothing here prints or exits."""

from __future__ import annotations


class StereoError(ValueError):
    """Base class of every error raised by :mod:`rig.stereo`."""


class InputArrayError(StereoError):
    """An input array is empty, of the wrong dtype or shape, or holds NaN/inf."""


class NoMarkersError(StereoError):
    """No marker passed the detection filters in a frame or region."""


class DegenerateCalibrationError(StereoError):
    """Calibration points cannot determine a camera (too few, coplanar, or collinear)."""


class DegenerateGeometryError(StereoError):
    """The cameras cannot triangulate (e.g. they share a centre) or a point is at infinity."""


class TimingError(StereoError):
    """Time stamps or motion do not allow a synchronization or spectral estimate."""


class CalibrationFormatError(StereoError):
    """A stored calibration (``calibration.json`` entry, DLT coefficient file) is malformed."""


class DistortionError(StereoError):
    """Distorted image points cannot be undistorted (outside the field where the lens model is invertible)."""


class DegenerateReferenceError(DegenerateGeometryError):
    """Reference markers cannot fix a rigid transform (fewer than 3 visible, or collinear)."""


# --- timing, resampling and spectral analysis (rig.stereo.timing*, resample, trajectory, spectrum) ---


class TooFewSamplesError(TimingError):
    """Too few frames/observations (or periods of motion) for the requested estimate."""


class NonMonotonicTimestampsError(TimingError):
    """Time stamps go backwards or repeat within one camera's record."""


class NotRotatingError(TimingError):
    """The rotor marker does not move on a circle at a steady, non-zero angular rate."""


class NoCommonMotionError(TimingError):
    """The cameras see no common motion that constrains the time offset (static, or motion only in the
    epipolar plane, or records that do not overlap in time)."""


class DelayOutOfRangeError(TimingError):
    """The best time offset lies at the edge of (or beyond) the search range."""


class LineTimeNotObservableError(TimingError):
    """The rolling-shutter line time cannot be estimated from this motion (the rows of the two cameras barely
    change relative to each other, e.g. markers moving along their rows, so the line time trades against the
    offset): the fit ran to its bound or its uncertainty exceeds every physical line time. Fix it instead
    (the cameras' known line time, 0 for a global shutter). Attributes: ``estimate_s``, ``uncertainty_s``,
    ``limit_s`` (the largest physical line time: frame period / largest row), ``at_bound``,
    ``row_difference_spread_px``."""

    def __init__(self, message: str, *, estimate_s: float, uncertainty_s: float, limit_s: float,
                 at_bound: bool, row_difference_spread_px: float) -> None:
        super().__init__(message)
        self.estimate_s, self.uncertainty_s, self.limit_s = estimate_s, uncertainty_s, limit_s
        self.at_bound, self.row_difference_spread_px = at_bound, row_difference_spread_px


class AmbiguousOffsetError(TimingError):
    """Several offsets (or frequencies) explain the data equally well, e.g. a periodic motion whose period is
    shorter than the search range, or an alias that the sampling instants cannot separate."""


class AmbiguousFrequencyError(TimingError):
    """Two frequencies (a tone and its alias) fit the observations equally well."""


class NonUniformSamplingError(TimingError):
    """A method that needs (nearly) uniform sampling got irregular time stamps."""
