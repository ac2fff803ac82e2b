"""A simulated camera as a camera device: :class:`SimFrameSource` implements ``FrameSource`` for a SimCamera.

``start()`` and ``stop()`` remember the world (virtual) time; ``frames()`` then renders, lazily and in
order, every frame whose whole exposure (all rows) lies in that interval. Called while still recording,
``frames()`` covers the interval up to the current virtual time.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from drivers.camera.base import Frame
from drivers.roles import Camera
from drivers.sim.camera import SimCamera

__all__ = ["RecordingStateError", "SimFrameSource"]


class RecordingStateError(RuntimeError):
    """start/stop/frames called in the wrong order."""


class SimFrameSource(Camera):
    """``FrameSource`` over a :class:`SimCamera` (name, size and fps are the camera's)."""

    def __init__(self, camera: SimCamera) -> None:
        self.camera = camera
        self.name = camera.name
        self.width_px, self.height_px, self.fps = camera.width_px, camera.height_px, camera.fps
        self._t_start_s: float | None = None
        self._t_stop_s: float | None = None

    @property
    def interval_s(self) -> tuple[float | None, float | None]:
        """World times of the last start and stop (None where not yet called)."""
        return self._t_start_s, self._t_stop_s

    def start(self) -> None:
        if self._t_start_s is not None and self._t_stop_s is None:
            raise RecordingStateError(f"camera {self.name!r} is already recording (call stop first)")
        self._t_start_s = self.camera.world.clock.now_s()
        self._t_stop_s = None

    def stop(self) -> None:
        if self._t_start_s is None or self._t_stop_s is not None:
            raise RecordingStateError(f"camera {self.name!r} is not recording (call start first)")
        self._t_stop_s = self.camera.world.clock.now_s()

    @property
    def recording(self) -> bool:
        return self._t_start_s is not None and self._t_stop_s is None

    def safe_state(self) -> None:
        """Stop a recording in progress (the runner's make-safe; nothing to do otherwise)."""
        if self.recording:
            self.stop()

    def read_back(self) -> dict[str, Any]:
        return {"recording": self.recording}

    def heartbeat(self, *, wait: bool = False) -> bool:
        return True  # rendered from the twin: cannot be lost

    def snapshot(self) -> dict[str, Any]:
        return {"driver": "sim", "fps": self.fps, "resolution_px": [self.width_px, self.height_px]}

    def frame_indices(self) -> range:
        """Indices of the frames :meth:`frames` yields."""
        if self._t_start_s is None:
            raise RecordingStateError(f"camera {self.name!r} has not recorded anything (call start first)")
        stop = self._t_stop_s if self._t_stop_s is not None else self.camera.world.clock.now_s()
        return self.camera.frame_indices_between(self._t_start_s, stop)

    def frames(self) -> Iterator[Frame]:
        cam = self.camera
        for i in self.frame_indices():
            yield Frame(index=i, timestamp_s=cam.frame_timestamp_s(i), image=cam.render(i),
                        exposure_s=cam.exposure_s)
