"""The rotation procedure's name, description and parameters, apart from its machinery
(:mod:`procedures.rotation`): ``rig list`` reads them without importing numpy."""

from __future__ import annotations

from dataclasses import dataclass, field

from rig.run.procedure import param

NAME = "rotation"
DESCRIPTION = "Marker on the rotor at 10 Hz: trajectory, radius and frequency (Figs. 10-15)."


@dataclass(frozen=True)
class Parameters:
    rotation_hz: float = field(default=10.0, metadata=param(lo=0.1, hi=100.0, doc="rotor speed, rev/s"))
    record_s: float = field(default=4.0, metadata=param(lo=0.5, hi=3600.0, doc="recording length, s"))
    poll_interval_s: float = field(default=0.25, metadata=param(lo=0.01, hi=10.0, doc="rotor polls, s"))
