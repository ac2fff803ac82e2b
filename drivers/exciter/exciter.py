"""The crank-driven vibration exciter: a VFD turns a crank that shakes the marker arm.

Vibration frequency = drive output frequency / ``gear_ratio``; the displacement amplitude is constant
and equal to the crank radius (from the rig configuration), so the peak acceleration at frequency f is
(2πf)²·r. ``set_frequency``, ``sweep(profile)`` and ``stop`` come from
:class:`~drivers.exciter.axis.VfdAxis`; every one is limit-checked before any byte is sent.
"""

from __future__ import annotations

from typing import Unpack

from drivers.clock import Clock
from drivers.exciter.axis import AxisOptions, VfdAxis
from drivers.exciter.limits import MotionLimits
from drivers.exciter.vfd import VfdDriver

__all__ = ["Exciter"]


class Exciter(VfdAxis):
    """Vibration exciter on a VFD.

    crank_radius_mm: peak displacement of the vibration (mm, > 0), fixed by the mechanism.
    gear_ratio: drive Hz per vibration Hz. ramp_rate_hz_per_s: default vibration ramp rate (Hz/s).
    Other keywords: see :class:`~drivers.exciter.axis.VfdAxis`.
    """

    kind = "exciter"

    def __init__(self, vfd: VfdDriver, *, clock: Clock, limits: MotionLimits, crank_radius_mm: float,
                 gear_ratio: float = 1.0, ramp_rate_hz_per_s: float = 1.0,
                 **kwargs: Unpack[AxisOptions]) -> None:
        if not crank_radius_mm > 0:
            raise ValueError(f"crank_radius_mm={crank_radius_mm!r}: must be > 0 mm")
        super().__init__(vfd, clock=clock, limits=limits, gear_ratio=gear_ratio, amplitude_mm=crank_radius_mm,
                         ramp_rate_hz_per_s=ramp_rate_hz_per_s, **kwargs)

    @property
    def crank_radius_mm(self) -> float:
        """Peak displacement of the vibration, mm (the sweep's reference amplitude)."""
        return self.amplitude_mm

    def vibration_hz(self) -> float:
        """Actual vibration frequency (Hz) from the drive's output frequency."""
        return self.frequency_hz()
