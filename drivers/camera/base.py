"""What every camera device delivers: frames with the camera's own time stamps.

Implemented by the OpenCV devices and video files of ``drivers/camera/`` and by the simulated cameras
(:class:`drivers.sim.source.SimFrameSource`). Time stamps are the camera's clock, never the rig's.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Protocol, TypedDict, runtime_checkable

import numpy as np
from numpy.typing import NDArray

__all__ = ["ClockMapping", "Frame", "FrameGap", "FrameSource"]


class FrameGap(TypedDict):
    """A gap between consecutive time stamps longer than the tolerance: ``missing_frames`` =
    ``round(gap_s / period) − 1`` (at least 1) frames were not delivered after frame ``after_index``."""

    after_index: int
    gap_s: float
    missing_frames: int


@dataclass(frozen=True)
class ClockMapping:
    """How a camera that stamps its own frames had its clock mapped onto the host's when a recording began:
    host time = camera time + ``host_minus_camera_s``, the lowest arrival latency (arrival − stamp, s) over
    the last ``window_frames`` frames. The mapping is late by the camera's own lowest latency (readout,
    encoding, transport: ≥ 0, which the stream does not reveal) — the same for two like cameras, so the
    difference of two cameras' mappings relates their clocks whatever frames either skipped.
    ``lag_spread_s``: median − lowest latency of that window (≥ 0: how far frames queued on the way; a
    catch-up burst raises it, never the mapping). ``start_camera_s``: the recording's start instant on the
    camera's clock by this mapping (early by that same lowest latency; None when the recording began with
    the connection's first frame): what the first frame's stamp is to be compared with — a sub-frame dating
    of the start, where the first frame dates it only to a frame, or later by the frames skipped."""

    host_minus_camera_s: float
    lag_spread_s: float
    window_frames: int
    start_camera_s: float | None = None


@dataclass(frozen=True)
class Frame:
    """One delivered frame.

    ``index``: running index in the camera's stream (0-based; a duplicated frame takes two indices);
    ``timestamp_s``: the camera's own time stamp in seconds; ``image``: 2-D uint8 (height, width);
    ``exposure_s``: exposure time if the device reports it (None otherwise).
    """

    index: int
    timestamp_s: float
    image: NDArray[np.uint8]
    exposure_s: float | None = None

    def __post_init__(self) -> None:
        if self.image.ndim != 2 or self.image.dtype != np.uint8:
            raise ValueError(f"Frame.image must be a 2-D uint8 array, got shape {self.image.shape} "
                             f"dtype {self.image.dtype}")


@runtime_checkable
class FrameSource(Protocol):
    """A camera that records between :meth:`start` and :meth:`stop` and yields what it recorded."""

    name: str
    width_px: int
    height_px: int
    fps: float

    def start(self) -> None:
        """Begin recording."""
        ...

    def stop(self) -> None:
        """End recording."""
        ...

    def frames(self) -> Iterator[Frame]:
        """The recorded frames in order (may be called once recording has stopped)."""
        ...
