"""``[report]``: what a report computes beyond the certificate (comparison analyses, figures).

Neither changes a criterion of the certificate: every criterion is decided on the primary sync method's
analysis (``[analysis] sync``); a comparison method only adds its own rows to the fit and sweep tables and its
column to the band table, and the figures only draw the tables.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from rig.config.analysis import SYNC_METHODS
from rig.config.schema import ConfigError, spec


def _check_methods(methods: tuple[str, ...], path: str) -> None:
    """Each method one of :data:`SYNC_METHODS`, none twice."""
    allowed = ", ".join(repr(m) for m in SYNC_METHODS)
    for i, method in enumerate(methods):
        if method not in SYNC_METHODS:
            raise ConfigError(f"{path}[{i}]", f"{method!r} is not allowed; allowed: {allowed} (or an empty "
                                              "array: no comparison)")
        if method in methods[:i]:
            raise ConfigError(f"{path}[{i}]", f"{method!r} is listed twice; allowed: each of {allowed} once")


@dataclass(frozen=True)
class ReportConfig:
    """What a report computes beyond the certificate. ``comparison``: sync methods analysed beside the
    primary one (each a whole second analysis of the run; ``[]``: none); ``figures``: draw the PNG figures
    (report.html then says they were not drawn)."""

    comparison: tuple[str, ...] = field(default=("linear",), metadata=spec(
        length=(0, len(SYNC_METHODS)), check=_check_methods,
        doc=f"sync methods analysed beside the primary one, each of {', '.join(SYNC_METHODS)} ([]: none; "
            "'linear' is the paper's)"))
    figures: bool = field(default=True, metadata=spec(doc="draw the report's PNG figures"))
