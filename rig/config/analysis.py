"""``[analysis]``: how observations become tracks (the synchronization method)."""

from __future__ import annotations

from dataclasses import dataclass, field

from rig.config.schema import spec

SYNC_METHODS = ("trajectory", "bandlimited", "cubic", "linear")
"""How 3-D tracks are timed (:mod:`rig.analysis.sync_tracks`); ``linear`` is the paper's."""


@dataclass(frozen=True)
class AnalysisConfig:
    """How observations become tracks (``rig.analysis.analyse``): the synchronization method (``linear`` is
    the
    paper's interpolation of camera B to camera A's instants; the others are ours)."""

    sync: str = field(default="trajectory", metadata=spec(choices=SYNC_METHODS))
