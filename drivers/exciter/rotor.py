"""The rotor: a VFD spins a disc carrying a marker at a known radius (the paper's 10 Hz rotation).

Rotation rate (revolutions per second, Hz) = drive output frequency / ``gear_ratio``. The limits apply
with the marker radius as the displacement: centripetal acceleration (2πf)²·r and rim speed 2πf·r.
"""

from __future__ import annotations

from typing import Unpack

from drivers.clock import Clock
from drivers.exciter.axis import AxisOptions, VfdAxis
from drivers.exciter.limits import MotionLimits
from drivers.exciter.sweep import FrequencySample
from drivers.exciter.vfd import VfdDriver

__all__ = ["Rotor"]


class Rotor(VfdAxis):
    """Rotor on a VFD.

    marker_radius_mm: distance of the marker from the rotation axis (mm, >= 0).
    gear_ratio: drive Hz per revolution per second. direction: "forward" or "reverse".
    Other keywords: see :class:`~drivers.exciter.axis.VfdAxis`.
    """

    kind = "rotor"

    def __init__(self, vfd: VfdDriver, *, clock: Clock, limits: MotionLimits, marker_radius_mm: float,
                 gear_ratio: float = 1.0, ramp_rate_hz_per_s: float = 2.0,
                 **kwargs: Unpack[AxisOptions]) -> None:
        super().__init__(vfd, clock=clock, limits=limits, gear_ratio=gear_ratio,
                         amplitude_mm=marker_radius_mm, ramp_rate_hz_per_s=ramp_rate_hz_per_s, **kwargs)

    @property
    def marker_radius_mm(self) -> float:
        return self.amplitude_mm

    def rotation_hz(self) -> float:
        """Actual rotation rate (revolutions per second) from the drive's output frequency."""
        return self.frequency_hz()

    def set_rotation_hz(self, rotation_hz: float, *, wait: bool = True) -> FrequencySample | None:
        """Spin at ``rotation_hz`` revolutions per second (limits checked first)."""
        return self.set_frequency(rotation_hz, wait=wait)
