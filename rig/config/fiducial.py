"""``[fiducial]``: the timing fiducial — an LED in both cameras' view on the function generator's sync output.

The generator named by ``device`` blinks the LED from its Sync connector following channel ``channel``
(``OUTPut:SYNC:SOURce CH<channel>`` on a two-channel generator) with a square wave of ``frequency_hz``
started at phase 0 by ``PHASe:SYNChronize``. On the channel that drives the shaker
(``devices.generator.channel``) the fiducial runs only while the shaker is idle; on the other channel of a
two-channel generator (``devices.generator.channels = 2``) it runs also while the shaker moves, and
``PHASe:SYNChronize`` gives both channels one phase origin (the shaker's phase reference). Each camera's
clock is then dated against the controller's from the LED's rows (:mod:`rig.stereo.fiducial`).
``regions_px.<camera>`` is where the LED is in that camera's image: (x0, y0, x1, y1) px, half-open,
inside the LED's outline. ``rise_time_s`` is the LED's 10–90 % rise (datasheet). Without a ``[fiducial]``
table the start-event method relates the clocks (to ±½ frame). ``[sim.fiducial]`` places the twin's LED
(:class:`SimFiducialConfig`).

The frequency must let the pattern be told apart within the start events' ±½ frame (period > 1.02
frames of every camera) and let its edges walk through the frame (not commensurate with any camera's
frame rate: over 10 s the edges' positions within the frame leave no gap longer than 1 ms), else no
edge ever crosses the LED's rows; both are checked against ``[cameras]`` (:func:`check_fiducial`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rig.config.cameras import CameraConfig
from rig.config.schema import ConfigError, spec
from rig.config.targets import VEC3_MM

__all__ = ["FiducialConfig", "SimFiducialConfig", "check_fiducial"]

MAX_FRAME_GAP_S = 1e-3  # longest stretch of the frame that the edges may leave unvisited over 10 s
_WALK_S = 10.0


def _check_regions(regions: dict[str, tuple[int, ...]], path: str) -> None:
    if not regions:
        raise ConfigError(path, "{} is empty; allowed: one (x0, y0, x1, y1) region per camera")
    for name, region in regions.items():
        if len(region) != 4:
            raise ConfigError(f"{path}.{name}", f"{list(region)} has {len(region)} elements; allowed: "
                                                "exactly 4 (x0, y0, x1, y1 px)")
        x0, y0, x1, y1 = region
        if min(region) < 0 or x1 <= x0 or y1 <= y0:
            raise ConfigError(f"{path}.{name}", f"{list(region)}: allowed: 0 ≤ x0 < x1 and 0 ≤ y0 < y1 (px)")


@dataclass(frozen=True)
class FiducialConfig:
    """The timing fiducial (see the module docstring)."""

    regions_px: dict[str, tuple[int, ...]] = field(metadata=spec(check=_check_regions))
    device: str = field(default="generator", metadata=spec(choices=("generator",)))
    channel: int = field(default=1, metadata=spec(lo=1, hi=2))
    output: str = field(default="sync", metadata=spec(choices=("sync",)))
    frequency_hz: float = field(default=10.27, metadata=spec(lo=0.1, hi=1000.0))
    rise_time_s: float = field(default=1.1e-5, metadata=spec(lo=0.0, hi=1e-3))


@dataclass(frozen=True)
class SimFiducialConfig:
    """The twin's LED: a rectangle (centre and half-side vectors, mm, base frame) with a first-order light
    response of ``time_constant_s``, adding ``contrast_dn`` to a fully covered, fully lit pixel."""

    centre_mm: tuple[float, ...] = field(metadata=VEC3_MM)
    half_u_mm: tuple[float, ...] = field(default=(0.0, 5.0, 0.0), metadata=VEC3_MM)
    half_v_mm: tuple[float, ...] = field(default=(0.0, 0.0, 75.0), metadata=VEC3_MM)
    time_constant_s: float = field(default=5e-6, metadata=spec(lo=0.0, lo_open=True, hi=1e-3))
    contrast_dn: float = field(default=180.0, metadata=spec(lo=0.0, lo_open=True, hi=255.0))


def _largest_frame_gap_s(frequency_hz: float, fps: float) -> float:
    """Longest stretch of the frame period not visited by the edges' positions within it over 10 s."""
    edges = np.arange(int(2 * frequency_hz * _WALK_S) + 1) * (0.5 / frequency_hz)
    phase = np.sort(np.mod(edges, 1.0 / fps))
    gaps = np.diff(np.concatenate([phase, [phase[0] + 1.0 / fps]]))
    return float(gaps.max())


def check_fiducial(fiducial: FiducialConfig, cameras: dict[str, CameraConfig]) -> None:
    """Cross-checks against ``[cameras]``: a region for every camera, inside its image; a frequency that
    is unambiguous within ±½ frame and walks through the frame (module docstring). Raises ConfigError."""
    for name in cameras:
        if name not in fiducial.regions_px:
            raise ConfigError(f"fiducial.regions_px.{name}",
                              f"missing: the LED's region in every camera's image is needed (cameras: "
                              f"{', '.join(cameras)})")
    for name, region in fiducial.regions_px.items():
        if name not in cameras:
            raise ConfigError(f"fiducial.regions_px.{name}", f"no camera {name!r} in [cameras]; allowed: "
                                                              f"{', '.join(cameras)}")
        width, height = cameras[name].resolution_px
        if region[2] > width or region[3] > height:
            raise ConfigError(f"fiducial.regions_px.{name}", f"{list(region)} reaches outside the "
                                                              f"{width}×{height} image")
    for name, cam in cameras.items():
        period_s = 1.0 / fiducial.frequency_hz
        if period_s <= 1.02 / cam.fps:
            raise ConfigError("fiducial.frequency_hz",
                              f"{fiducial.frequency_hz:g}: its period must exceed 1.02 frames of camera "
                              f"{name!r} ({cam.fps:g} fps) so that the start events' ±½ frame tells its "
                              f"edges apart; allowed: < {cam.fps / 1.02:.4g} Hz")
        gap_s = _largest_frame_gap_s(fiducial.frequency_hz, cam.fps)
        if gap_s > MAX_FRAME_GAP_S:
            raise ConfigError("fiducial.frequency_hz",
                              f"{fiducial.frequency_hz:g}: nearly commensurate with camera {name!r}'s "
                              f"{cam.fps:g} fps, its edges leave {1e3 * gap_s:.2f} ms of the frame unvisited "
                              f"over {_WALK_S:g} s (allowed ≤ {1e3 * MAX_FRAME_GAP_S:g} ms); detune it, "
                              f"e.g. {fiducial.frequency_hz * 1.027:.4g} Hz")
