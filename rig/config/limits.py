"""``[limits.*]``: the robot's envelope and speed, the vibration sources' frequency, displacement,
acceleration and ramp limits."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from rig.config.schema import ConfigError, spec, to_dict

if TYPE_CHECKING:
    from drivers.denso.arm import BoxEnvelope


@dataclass(frozen=True)
class RobotLimits:
    envelope_x_mm: tuple[float, ...] = field(metadata=spec(length=2))
    envelope_y_mm: tuple[float, ...] = field(metadata=spec(length=2))
    envelope_z_mm: tuple[float, ...] = field(metadata=spec(length=2))
    max_speed_mm_s: float = field(metadata=spec(lo=0.0, lo_open=True, hi=5000.0))
    max_accel_mm_s2: float = field(default=2000.0, metadata=spec(lo=0.0, lo_open=True, hi=50000.0))

    def __post_init__(self) -> None:
        for axis in "xyz":
            lo, hi = getattr(self, f"envelope_{axis}_mm")
            if not lo < hi:
                raise ConfigError(f"limits.robot.envelope_{axis}_mm",
                                  f"[{lo:g}, {hi:g}]: allowed: [min, max] with min < max")

    def envelope(self) -> BoxEnvelope:
        """The arm driver's :class:`drivers.denso.arm.BoxEnvelope` of these limits."""
        from drivers.denso.arm import BoxEnvelope

        x, y, z = self.envelope_x_mm, self.envelope_y_mm, self.envelope_z_mm
        return BoxEnvelope((x[0], x[1]), (y[0], y[1]), (z[0], z[1]))


@dataclass(frozen=True)
class VibrationLimits:
    max_frequency_hz: float = field(metadata=spec(lo=0.0, lo_open=True, hi=2000.0))
    max_displacement_mm: float = field(metadata=spec(lo=0.0, lo_open=True, hi=500.0))
    max_acceleration_m_s2: float = field(metadata=spec(lo=0.0, lo_open=True, hi=10000.0))
    max_ramp_rate_hz_per_s: float = field(metadata=spec(lo=0.0, lo_open=True, hi=1000.0))
    max_velocity_mm_s: float | None = field(default=None, metadata=spec(lo=0.0, lo_open=True))

    def motion_limits(self) -> Any:
        """These limits as the drivers' :class:`drivers.exciter.limits.MotionLimits`."""
        from drivers.exciter.limits import MotionLimits

        return MotionLimits(**to_dict(self))


@dataclass(frozen=True)
class LimitsConfig:
    robot: RobotLimits | None = None
    exciter: VibrationLimits | None = None
    rotor: VibrationLimits | None = None
    generator: VibrationLimits | None = None
