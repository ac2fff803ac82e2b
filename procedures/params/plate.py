"""The plate procedure's name, description and parameters, apart from its machinery
(:mod:`procedures.plate`): ``rig list`` reads them without importing numpy."""

from __future__ import annotations

from dataclasses import dataclass, field

from rig.run.procedure import param

NAME = "plate"
DESCRIPTION = "Oscillating plate at about 3.5 Hz: trajectories of every marker (Figs. 4-8)."


@dataclass(frozen=True)
class Parameters:
    frequency_hz: float = field(default=3.5, metadata=param(lo=0.1, hi=1000.0,
                                                            doc="oscillation frequency, Hz"))
    record_s: float = field(default=6.0, metadata=param(lo=0.5, hi=3600.0, doc="recording length, s"))
    poll_interval_s: float = field(default=0.25, metadata=param(lo=0.01, hi=10.0, doc="exciter polls, s"))
    shaker_amplitude_mm: float = field(default=2.0, metadata=param(
        lo=0.001, hi=50.0, doc="tip displacement with body = \"shaker\", mm (the exciter's: its crank)"))
