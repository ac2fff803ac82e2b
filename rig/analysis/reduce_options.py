"""How frames become marker rows: :class:`ReduceOptions`, checked where a procedure or a deployment sets them.

Apart from :mod:`rig.analysis.frame_reduction` (which re-exports it), so that stating the options — a
procedure's module, a dry run's plan — imports none of the reduction's SciPy, numba and OpenCV (≈ 1.3 CPU-s).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

__all__ = ["DETECT_ONLY_KEYS", "TRACK_KEYS", "ReduceOptions", "track_options"]

#: keyword options that both :func:`rig.stereo.detect_markers` and :func:`rig.stereo.track_markers` take
TRACK_KEYS = ("polarity", "min_area_px", "max_area_px", "min_roundness", "min_contrast", "centre",
              "max_skewness", "outline_check", "max_edge_rms_px")
#: keyword options of :func:`rig.stereo.detect_markers` only (whole-frame search); not passed to the tracker
DETECT_ONLY_KEYS = ("threshold", "roi", "downsample", "require")


def track_options(detect: dict[str, Any]) -> dict[str, Any]:
    """The part of ``detect`` (options of :func:`rig.stereo.detect_markers`) that
    :func:`rig.stereo.track_markers` accepts."""
    return {k: v for k, v in detect.items() if k in TRACK_KEYS}


@dataclass(frozen=True)
class ReduceOptions:
    """How frames become marker rows.

    mode: "track" (detect once, then track; re-detect on loss) or "detect" (whole frame every time).
    window_px: tracking window side (px, integer ≥ 7): twice the largest frame-to-frame motion plus a
    marker diameter. redetect_every: frames between whole-frame detections in "track" mode (integer ≥ 1).
    detect: keyword options of :func:`rig.stereo.detect_markers` (:data:`TRACK_KEYS` and
    :data:`DETECT_ONLY_KEYS`); the tracker gets only the :data:`TRACK_KEYS` among them. An unknown key
    raises ``ValueError`` here rather than ``TypeError`` at the first frame.
    """

    mode: str = "track"
    window_px: int = 51
    redetect_every: int = 30
    detect: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.mode not in ("track", "detect"):
            raise ValueError(f"mode={self.mode!r} not allowed; allowed: 'track' or 'detect'")
        if int(self.window_px) != self.window_px or self.window_px < 7:
            raise ValueError(f"window_px={self.window_px!r}: allowed: an integer ≥ 7")
        if int(self.redetect_every) != self.redetect_every or self.redetect_every < 1:
            raise ValueError(f"redetect_every={self.redetect_every!r}: allowed: an integer ≥ 1")
        unknown = sorted(set(self.detect) - set(TRACK_KEYS) - set(DETECT_ONLY_KEYS))
        if unknown:
            raise ValueError(f"detect options {unknown} not known; allowed: "
                             f"{', '.join(TRACK_KEYS + DETECT_ONLY_KEYS)}")
