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
