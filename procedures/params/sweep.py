"""The sweep procedure's name, description and parameters, apart from its machinery
(:mod:`procedures.sweep`): ``rig list`` reads them without importing numpy."""

from __future__ import annotations

from dataclasses import dataclass, field

from rig.run.procedure import param

NAME = "sweep"
DESCRIPTION = "Constant amplitude, frequency rising monotonically to 30 Hz (Fig. 17): error vs frequency."


@dataclass(frozen=True)
class Parameters:
    start_hz: float = field(default=1.0, metadata=param(lo=0.1, hi=1000.0, doc="first frequency, Hz"))
    max_hz: float = field(default=30.0, metadata=param(lo=0.1, hi=1000.0, doc="peak frequency, Hz"))
    duration_s: float = field(default=24.0, metadata=param(lo=0.5, hi=3600.0, doc="rise time, s"))
    hold_s: float = field(default=1.0, metadata=param(lo=0.0, hi=600.0, doc="hold at the peak, s"))
    shape: str = field(default="fig17", metadata=param(choices=("fig17", "linear", "log"),
                                                       doc="profile of the rise"))
    update_interval_s: float = field(default=0.5, metadata=param(
        lo=0.05, hi=10.0, doc="setpoint update interval (shaker: fig17 step and generator poll interval), s"))
    shaker_amplitude_mm: float = field(default=2.0, metadata=param(
        lo=0.001, hi=50.0, doc="peak displacement with body = \"shaker\", mm (the exciter's: its crank)"))

    def __post_init__(self) -> None:
        if self.max_hz <= self.start_hz:
            raise ValueError(f"max_hz={self.max_hz:g} must exceed start_hz={self.start_hz:g} "
                             "(a rising sweep)")
