"""``[analysis]``: how observations become tracks (the synchronization method)."""

from __future__ import annotations

from dataclasses import dataclass, field

from rig.config.schema import spec


@dataclass(frozen=True)
class AnalysisConfig:
    """How observations become tracks (``rig.analysis.analyse``): the synchronization method (``linear`` is
    the
    paper's interpolation of camera B to camera A's instants; the others are ours)."""

    sync: str = field(default="trajectory", metadata=spec(choices=("trajectory", "bandlimited", "cubic",
                                                                    "linear")))
