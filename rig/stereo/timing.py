"""``estimate_offset``: the camera timing (model and record in :mod:`rig.stereo.timing_model`) from a marker.

Two estimators (``estimate_offset(method=...)``):

- ``"rotor"`` — the paper's: a marker rotating at constant angular velocity; per camera the projected circle
  is fitted, the angle unwrapped, and the delay taken from the phase difference at the closest frames
  (:mod:`rig.stereo.timing_rotor`). It ignores the rolling shutter (once-per-revolution ripple, bias
  (v_B − v_A)·line time).
- ``"joint"`` — ours: offset, rolling-shutter line time and clock drift jointly, from any moving marker,
  minimising epipolar (Sampson) residuals with band-limited interpolation over a continuous offset: a coarse
  search over the offset range, then local least squares; covariance from the Jacobian
  (:mod:`rig.stereo.timing_joint`).
"""

from __future__ import annotations

from typing import Any

from rig.stereo.errors import InputArrayError
from rig.stereo.normalize import Camera
from rig.stereo.timing_joint import estimate_joint
from rig.stereo.timing_model import TimingResult, corrected_times
from rig.stereo.timing_rotor import estimate_rotor

__all__ = ["METHODS", "TimingResult", "corrected_times", "estimate_offset"]

METHODS = ("joint", "rotor")


def estimate_offset(
    camera_a: Camera,
    camera_b: Camera,
    observations_a: object,
    observations_b: object,
    *,
    method: str = "joint",
    names: tuple[str, str] = ("a", "b"),
    **kwargs: Any,
) -> TimingResult:
    """Estimate camera B's timing relative to camera A (the reference) from a moving marker seen by both.

    ``camera_a``/``camera_b``: 3×4 projection matrices or objects with ``.P``. ``observations_a``/``_b``:
    a pair ``(timestamp_s (N,), uv_px (N, 2))`` of one marker track — frame time stamps on the camera's own
    clock (s, strictly increasing) and marker centres (px, lens distortion removed) — or, for several
    markers, a list of such pairs in the same order for both cameras. With lens distortion, give the joint
    method triples ``(timestamp_s, uv_px, rows_px)`` where ``rows_px`` (N,) are the *observed* image rows:
    the sensor row sets the rolling-shutter instant, and the undistorted v differs from it.
    ``method="joint"`` → :func:`rig.stereo.timing_joint.estimate_joint` (keyword options documented there);
    ``method="rotor"`` → :func:`rig.stereo.timing_rotor.estimate_rotor` (needs ``rotor_centre_mm`` and
    ``rotor_axis``).
    """
    if method == "joint":
        return estimate_joint(camera_a, camera_b, observations_a, observations_b, names=names, **kwargs)
    if method == "rotor":
        return estimate_rotor(camera_a, camera_b, observations_a, observations_b, names=names, **kwargs)
    raise InputArrayError(f"method must be one of {METHODS}, got {method!r}")
