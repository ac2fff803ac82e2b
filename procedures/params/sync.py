"""The sync procedure's name, description and parameters, apart from its machinery
(:mod:`procedures.sync`): ``rig list`` reads them without importing numpy."""

from __future__ import annotations

from dataclasses import dataclass, field

from rig.run.procedure import param

NAME = "sync"
DESCRIPTION = "Spin the rotor at 10 Hz; estimate camera offset, line time and drift → timing.json."


@dataclass(frozen=True)
class Parameters:
    rotation_hz: float = field(default=10.0, metadata=param(lo=0.1, hi=100.0, doc="rotor speed, rev/s"))
    record_s: float = field(default=3.0, metadata=param(lo=0.5, hi=600.0, doc="recording length, s"))
    poll_interval_s: float = field(default=0.25, metadata=param(lo=0.01, hi=10.0,
                                                                doc="rotor polls while recording, s"))
    search_frames: float = field(default=2.0, metadata=param(lo=0.5, hi=30.0,
                                                             doc="offset search half-width, frame periods"))
    attempts: int = field(default=3, metadata=param(lo=1, hi=10, doc="rotor recordings tried while frames "
                                                               "are lost (the n-th: n × record_s)"))
    compare_rotor_method: bool = field(default=True, metadata=param(doc="also run the paper's method"))
