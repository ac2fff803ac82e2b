"""``[station]``: the bench's name, simulated or real, runs folder, clock, heartbeat."""

from __future__ import annotations

from dataclasses import dataclass, field

from rig.config.schema import spec


@dataclass(frozen=True)
class StationConfig:
    name: str = field(metadata=spec(doc="Free text naming the bench."))
    simulated: bool = False
    runs_dir: str = "runs"
    clock: str = field(default="wall", metadata=spec(choices=("wall", "virtual")))
    heartbeat_timeout_s: float = field(default=2.0, metadata=spec(lo=0.5, hi=60.0, doc=(
        "Wall seconds without any reply from a device (b-CAP keep-alives count) before the watchdog trips "
        "the interlock (exit 3); an idle device is probed after a quarter of it. Above the b-CAP WDT "
        "(devices.robot.wdt_ms).")))
