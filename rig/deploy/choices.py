"""The choices of ``rig calibrate`` and ``rig measure`` (light: the command line parser imports this, not the
measurement)."""

from __future__ import annotations

from rig.config.analysis import SYNC_METHODS

__all__ = ["DEFAULT_CLOCK_AGREEMENT_S", "DISTORTION_MODELS", "MEASURE_SYNC"]

#: ``--sync``: how the 3-D tracks are timed. The interpolation methods of :mod:`rig.analysis.sync_tracks`, or
#: ``rotor``: the timing from the paper's rotating-marker phase method (row-corrected; a marker turning at
#: constant speed in view), 3-D by the trajectory method.
MEASURE_SYNC = (*SYNC_METHODS, "rotor")

#: ``--distortion``: the lens distortion terms fitted → :func:`rig.stereo.calibrate_dlt`'s ``distortion``.
DISTORTION_MODELS: dict[str, bool | str] = {"none": False, "k1": "k1", "k1k2": "k1k2", "full": True}

#: ``--clock-agreement-s``: how far two cameras' clocks set by hand, or by a phone, may disagree (s).
DEFAULT_CLOCK_AGREEMENT_S = 2.0
