"""Device roles: what the runner needs of every device, and what each kind of device is for.

The runner's safety decisions (shutdown order, read-back, heartbeat) come from the **role** the station
declares for each device, never from its name or from probing its attributes:

- :class:`Device` — what the runner needs of any device: ``safe_state()`` (make safe), ``read_back()``
  (what the device itself now reports, over its own protocol), ``heartbeat()`` and ``snapshot()``;
- one protocol per role: :class:`VibrationSource` (the crank exciter, the rotor: VFD axes),
  :class:`Generator` (function generator + amplifier + shaker), :class:`Arm` (the robot), and
  :class:`Camera`.

Drivers implement these explicitly (they subclass the protocol), so a missing method is a type error,
not a silently skipped safety step. :data:`SHUTDOWN_ORDER` is the order the runner makes devices safe:
energy sources first (generator output, then the VFD axes: exciter, rotor), then the arm is halted,
then the cameras stop recording.
"""

from __future__ import annotations

import enum
from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    from drivers.camera.base import ClockMapping, Frame

__all__ = ["SHUTDOWN_ORDER", "Arm", "Assignment", "Camera", "Device", "Generator", "Role", "VibrationSource",
           "shutdown_rank"]


class Role(enum.Enum):
    """What a device is for; decides when the runner makes it safe (:data:`SHUTDOWN_ORDER`)."""

    GENERATOR = "generator"  # signal generator driving a shaker: output off first
    VIBRATION_SOURCE = "vibration_source"  # a motor on a VFD (exciter, rotor): stopped next
    ARM = "arm"  # halted once nothing shakes it or the target any more
    CAMERA = "camera"  # stops recording last (it may film the stop)


SHUTDOWN_ORDER: tuple[Role, ...] = (Role.GENERATOR, Role.VIBRATION_SOURCE, Role.ARM, Role.CAMERA)
"""Energy sources first, then the arm, then the cameras."""


def shutdown_rank(role: Role) -> int:
    """Position of ``role`` in :data:`SHUTDOWN_ORDER` (0 = made safe first)."""
    return SHUTDOWN_ORDER.index(role)


class Device(Protocol):
    """What the runner needs of any device. Every method may be called after a failure of the device or
    of another one; each must either do its job or raise (the runner records the error and carries on)."""

    def safe_state(self) -> None:
        """Bring the device to its safe state (output off, at rest, halted, not recording); raise if it
        cannot be confirmed."""
        ...

    def read_back(self) -> dict[str, Any]:
        """What the device itself reports now (asked over its protocol), JSON-ready; raises if it does
        not answer."""
        ...

    def heartbeat(self, *, wait: bool = False) -> bool:
        """Thread-safe liveness check that returns at once (``wait=True``: probe now in the caller's
        thread); raises or returns False when the device is lost."""
        ...

    def snapshot(self) -> dict[str, Any]:
        """Configuration and last state for the run record (no device I/O)."""
        ...


class VibrationSource(Device, Protocol):
    """A motor on a VFD (crank exciter, rotor). ``read_back`` gives ``frequency_hz`` (the drive's
    output, mechanical Hz), ``setpoint_hz`` and ``status``."""

    @property
    def setpoint_hz(self) -> float:
        """The last commanded mechanical frequency (Hz; 0 after a stop)."""
        ...

    def stop(self, *, wait: bool = True) -> object:
        """Command a stop (the drive decelerates on its ramp); with ``wait``, until at rest. The runner
        ignores what it returns."""
        ...


class Generator(Device, Protocol):
    """Function generator + amplifier + shaker. ``read_back`` gives ``output_on``."""

    def stop(self) -> None:
        """Ramp the amplitude down and switch the output off."""
        ...


class Arm(Device, Protocol):
    """The robot arm. ``read_back`` gives ``pose`` and ``moved_mm`` (motion over a short interval: 0 for
    a halted arm)."""

    def position(self) -> NDArray[np.float64]:
        """Current flange pose (6,): x, y, z mm; rx, ry, rz deg."""
        ...

    def halt(self) -> None:
        """Stop the arm now."""
        ...


class Camera(Device, Protocol):
    """A camera (``safe_state`` stops a recording in progress). ``read_back`` gives ``recording``."""

    name: str
    width_px: int
    height_px: int
    fps: float
    live: bool = False  # True: frames stream into a bounded queue during the recording and must be read then

    def start(self) -> None: ...

    def stop(self) -> None: ...

    def frames(self) -> Iterator[Frame]: ...

    def clock_mapping(self) -> ClockMapping | None:
        """How the last recording's camera clock was mapped onto the host's (a camera stamping its own
        frames on a kept connection); None when the frames carry no such mapping (the default)."""
        return None


@dataclass(frozen=True)
class Assignment:
    """One device of a station with the role the station declares for it."""

    name: str
    role: Role
    device: Device
