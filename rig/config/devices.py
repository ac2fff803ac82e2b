"""``[devices.*]``: the robot (b-CAP), the exciter and rotor drives (Modbus VFD), the generator (SCPI)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from rig.config.address import BUILTIN_REGISTER_MAPS, check_address, check_register_map
from rig.config.schema import ConfigError, spec


@dataclass(frozen=True)
class RobotConfig:
    driver: str = field(metadata=spec(choices=("denso-bcap",)))
    address: str = field(metadata=spec(check=check_address))
    controller: str = field(default="rc8", metadata=spec(choices=("rc8", "rc7m")))
    timeout_s: float = field(default=3.0, metadata=spec(lo=0.05, hi=120.0))
    home_pose: tuple[float, ...] | None = field(default=None, metadata=spec(length=6))
    full_speed_mm_s: float = field(default=1000.0, metadata=spec(lo=1.0, hi=10000.0))
    full_accel_mm_s2: float = field(default=5000.0, metadata=spec(lo=1.0, hi=100000.0, doc=(
        "what the controller's 100 % acceleration means (its manual / a measured move): the arm commands "
        "ExtSpeed accel = decel = 100 · limits.robot.max_accel_mm_s2 / this")))
    position_tolerance_mm: float = field(default=0.5, metadata=spec(lo=0.0, lo_open=True, hi=100.0))
    wait_mode: str | None = field(default=None, metadata=spec(choices=("next", "blocking"), doc="move end: "
                                  "NEXT + @BUSY_STATUS polls, halt works mid-move (rc8) or blocking (rc7m)"))
    busy_poll_interval_s: float = field(default=0.05, metadata=spec(lo=0.0, lo_open=True, hi=5.0))
    wdt_ms: int = field(default=400, metadata=spec(lo=80, hi=60000, doc=(
        "b-CAP watchdog (Service_Start WDT, ms): the controller sends keep-alives every wdt_ms during a "
        "blocking call; the stand-alone mock ends a session silent for 4 × wdt_ms (halt, motor off). Below "
        "station.heartbeat_timeout_s, and 1.5 × wdt_ms within timeout_s. Raise it on a host that may stall "
        "the controller for longer than 4 × wdt_ms")))


@dataclass(frozen=True)
class VfdConfig:
    driver: str = field(metadata=spec(choices=("modbus-vfd",)))
    address: str = field(metadata=spec(check=check_address))
    unit_id: int = field(default=1, metadata=spec(lo=1, hi=247))
    register_map: str = field(default="delta", metadata=spec(check=check_register_map))
    registers: dict[str, Any] | None = None
    gear_ratio: float = field(default=1.0, metadata=spec(lo=0.0, lo_open=True, hi=1000.0))
    crank_radius_mm: float | None = field(default=None, metadata=spec(lo=0.0, lo_open=True, hi=500.0))
    timeout_s: float = field(default=1.0, metadata=spec(lo=0.05, hi=60.0))
    max_output_hz: float = field(default=50.0, metadata=spec(lo=0.0, lo_open=True, hi=1000.0))
    ramp_rate_hz_per_s: float = field(default=1.0, metadata=spec(lo=0.0, lo_open=True, hi=1000.0))
    comm_timeout_s: float = field(default=2.0, metadata=spec(lo=0.1, hi=100.0, doc=(
        "the drive's own communication-loss stop (Delta 09-03): no valid request for this long → it faults "
        "and ramps to a stop by itself, so a controller killed without cleanup (SIGKILL, power loss) "
        "leaves the motor stopped within comm_timeout_s + frequency / deceleration rate; armed when the "
        "station connects (not on mock:// drives), disarmed on a clean close. Must exceed twice the "
        "heartbeat probe interval (station.heartbeat_timeout_s / 4)")))

    def resolved_register_map(self) -> Any:
        """The :class:`drivers.exciter.register_map.RegisterMap`: the named map, overridden by ``registers``
        and with ``unit_id``."""
        from drivers.exciter.register_map import DELTA_MAP, load_register_map, register_map_from_dict

        builtin = self.register_map in BUILTIN_REGISTER_MAPS
        base = DELTA_MAP if builtin else load_register_map(self.register_map)
        regs = register_map_from_dict(dict(self.registers), base) if self.registers else base
        return dataclasses.replace(regs, unit_id=self.unit_id)


@dataclass(frozen=True)
class GeneratorConfig:
    driver: str = field(metadata=spec(choices=("scpi-generator",)))
    address: str = field(metadata=spec(check=check_address))
    channel: int = field(default=1, metadata=spec(lo=1, hi=2, doc="the channel that feeds the shaker's "
                                                                   "amplifier"))
    channels: int = field(default=1, metadata=spec(lo=1, hi=2, doc=(
        "the instrument's output channels: 1 (e.g. Keysight 33521B) or 2 (33522B: channel 2 and the Sync "
        "connector's source are free for a timing fiducial while channel 1 drives the shaker)")))
    sensitivity_mm_per_v: tuple[tuple[float, ...], ...] = field(
        default=((1.0, 1.0), (100.0, 1.0)), metadata=spec(length=(1, 1000), lo=0.0, hi=1e6))
    max_amplitude_vpp: float = field(default=10.0, metadata=spec(lo=0.0, lo_open=True, hi=100.0))
    amplitude_step_vpp: float = field(default=0.5, metadata=spec(lo=0.0, lo_open=True, hi=100.0))
    step_interval_s: float = field(default=0.1, metadata=spec(lo=0.0, lo_open=True, hi=60.0))
    timeout_s: float = field(default=2.0, metadata=spec(lo=0.05, hi=60.0))

    def __post_init__(self) -> None:
        from drivers.exciter.shaker import SensitivityTable

        if self.channel > self.channels:
            raise ConfigError("devices.generator.channel", f"{self.channel}: devices.generator.channels = "
                                                           f"{self.channels}; allowed: 1..{self.channels}")
        try:
            SensitivityTable(self.sensitivity_mm_per_v)
        except ValueError as exc:
            raise ConfigError("devices.generator.sensitivity_mm_per_v", str(exc)) from exc


@dataclass(frozen=True)
class DevicesConfig:
    robot: RobotConfig | None = None
    exciter: VfdConfig | None = None
    rotor: VfdConfig | None = None
    generator: GeneratorConfig | None = None

    def configured(self) -> dict[str, RobotConfig | VfdConfig | GeneratorConfig]:
        """The configured devices by name (``[devices.<name>]``, in :data:`DEVICE_NAMES` order)."""
        named = {"robot": self.robot, "exciter": self.exciter, "rotor": self.rotor,
                 "generator": self.generator}
        return {name: device for name, device in named.items() if device is not None}


DEVICE_NAMES = ("robot", "exciter", "rotor", "generator")
