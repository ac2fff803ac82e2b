"""``rig preview``: the cameras' live view alone, for aiming and focusing, on the dashboard's page.

Every ``interval_s`` each configured camera records a few frames (``FrameSource.start``/``stop``; on the
simulated rig the twin's cameras), the last frame of each is searched for markers
(:func:`rig.stereo.detect_markers`) and offered to the page (:mod:`rig.run.frame_tap`), and the findings
become
hints (:func:`preview_hints`):

- **saturated** markers (a clipped pixel: :data:`rig.stereo.FLAG_SATURATED`) — lower the exposure or gain;
- **too few pixels** per marker (equivalent diameter below ``min_diameter_px``) — closer, or a longer lens;
- **blur**: the median edge width (10–90 % rise, estimated as the marker's contrast over the steepest grey
  gradient around it, px) above ``max_edge_px`` — focus;
- the **marker count** differing between the cameras — a marker out of one camera's view or hidden;
- with a calibration (``calibration.json``): the **epipolar check** — each marker of the first camera
  against the nearest epipolar line of the second's markers (symmetric distance, px); a median above
  ``max_epipolar_px`` says the cameras moved since the calibration (or it is another setup's).

Nothing is recorded and no device other than the cameras is commanded. Ctrl-C (or the page's Abort button)
stops it.
"""

from __future__ import annotations

import logging
import math
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rig.dashboard.server import DashboardServer
from rig.dashboard.state import DashboardState
from rig.run.frame_tap import FRAMES
from rig.stereo import FLAG_SATURATED, detect_markers, epipolar_distance_px, fundamental_from_projections

__all__ = ["CameraView", "HintLimits", "edge_width_px", "preview_hints", "run_preview", "view_of"]

log = logging.getLogger("rig.preview")


@dataclass(frozen=True)
class HintLimits:
    """When a finding becomes a warning: ``min_diameter_px`` (marker equivalent diameter, px),
    ``max_edge_px`` (median edge width, px), ``max_epipolar_px`` (median epipolar distance, px)."""

    min_diameter_px: float = 6.0
    max_edge_px: float = 3.0
    max_epipolar_px: float = 2.0


@dataclass(frozen=True)
class CameraView:
    """One camera's findings on one frame: markers' centres ``uv_px`` (n × 2), equivalent diameters
    ``diameter_px`` (n), how many are ``saturated``, and the median ``edge_px`` (NaN without markers)."""

    name: str
    uv_px: np.ndarray
    diameter_px: np.ndarray
    saturated: int
    edge_px: float


def edge_width_px(image: np.ndarray, u_px: float, v_px: float, radius_px: float) -> float:
    """A marker's edge width (px): its contrast (max − min grey in a window of 2 × (radius + 4) px) over
    the steepest grey gradient in it (grey per px, Sobel / 8) — the rise distance of a linear edge ramp."""
    import cv2

    half = math.ceil(radius_px) + 4
    r0, c0 = max(0, int(v_px) - half), max(0, int(u_px) - half)
    window = image[r0:int(v_px) + half + 1, c0:int(u_px) + half + 1].astype(np.float32)
    if window.shape[0] < 3 or window.shape[1] < 3:
        return math.nan
    gx = cv2.Sobel(window, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(window, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    steepest = float(np.sqrt(gx * gx + gy * gy)[1:-1, 1:-1].max())
    contrast = float(window.max() - window.min())
    return contrast / steepest if steepest > 0 else math.nan


def view_of(name: str, image: np.ndarray,
            led_region_px: tuple[int, int, int, int] | None = None) -> CameraView:
    """Find the markers of one frame and measure what the hints need. Blobs centred in ``led_region_px``
    (x0, y0, x1, y1: the timing fiducial's LED, ``fiducial.regions_px``) are the LED, not markers: it blinks
    with the generator's sync output, so each camera may catch it lit or dark."""
    found = detect_markers(image)
    if led_region_px is not None:
        x0, y0, x1, y1 = led_region_px
        u, v = found["u_px"], found["v_px"]
        found = found[~((u >= x0) & (u < x1) & (v >= y0) & (v < y1))]
    diameter = 2.0 * np.sqrt(np.maximum(found["area_px"], 0.0) / math.pi)
    edges = [edge_width_px(image, u, v, d / 2) for u, v, d in zip(found["u_px"], found["v_px"], diameter,
                                                                   strict=True)]
    edge = float(np.nanmedian(edges)) if edges and np.isfinite(edges).any() else math.nan
    return CameraView(name, np.column_stack([found["u_px"], found["v_px"]]), diameter,
                      int(np.count_nonzero(found["flags"] & FLAG_SATURATED)), edge)


def _epipolar_px(views: list[CameraView], cameras: dict[str, Any]) -> np.ndarray | None:
    """Each marker of the first calibrated camera: its distance to the nearest match in the second."""
    pair = [v for v in views if v.name in cameras][:2]
    if len(pair) < 2 or not len(pair[0].uv_px) or not len(pair[1].uv_px):
        return None
    F = fundamental_from_projections(cameras[pair[0].name], cameras[pair[1].name])
    return epipolar_distance_px(F, pair[0].uv_px, pair[1].uv_px, pairwise=True).min(axis=1)


def preview_hints(views: list[CameraView], cameras: dict[str, Any] | None = None,
                  limits: HintLimits = HintLimits()) -> dict[str, Any]:
    """``{"cameras": {name: findings}, "epipolar_px": median | None, "items": [{"level", "text"}]}``;
    ``level`` is ``warn`` or ``ok``. ``cameras``: name → :class:`rig.stereo.DLTCamera` (or None)."""
    items: list[dict[str, str]] = []
    per_camera: dict[str, Any] = {}

    def say(level: str, text: str) -> None:
        items.append({"level": level, "text": text})

    for v in views:
        n = len(v.uv_px)
        median_d = float(np.median(v.diameter_px)) if n else math.nan
        per_camera[v.name] = {"markers": n, "saturated": v.saturated, "median_diameter_px": median_d,
                              "edge_px": v.edge_px}
        if n == 0:
            say("warn", f"{v.name}: no marker found — aim the camera at the target, check exposure and focus")
            continue
        if v.saturated:
            say("warn", f"{v.name}: {v.saturated} of {n} markers saturated — lower the exposure or gain")
        small = int(np.count_nonzero(v.diameter_px < limits.min_diameter_px))
        if small:
            say("warn", f"{v.name}: {small} of {n} markers smaller than {limits.min_diameter_px:g} px across "
                        f"(median {median_d:.1f} px) — move closer or use a longer lens")
        if math.isfinite(v.edge_px) and v.edge_px > limits.max_edge_px:
            say("warn", f"{v.name}: blurred — median edge width {v.edge_px:.1f} px (limit "
                        f"{limits.max_edge_px:g} px); focus")
        elif math.isfinite(v.edge_px):
            say("ok", f"{v.name}: {n} markers, median {median_d:.1f} px across, "
                      f"edge width {v.edge_px:.1f} px")
    counts = {v.name: len(v.uv_px) for v in views}
    if len(set(counts.values())) > 1:
        listed = ", ".join(f"{k} {n}" for k, n in counts.items())
        say("warn", f"marker count differs between the cameras: {listed} — a marker is out of view or hidden")
    epipolar = None
    if cameras:
        distances = _epipolar_px(views, cameras)
        if distances is not None:
            epipolar = float(np.median(distances))
            level = "warn" if epipolar > limits.max_epipolar_px else "ok"
            say(level, f"epipolar check: median distance {epipolar:.2f} px over {len(distances)} markers "
                       f"(limit {limits.max_epipolar_px:g} px)"
                + (" — the cameras moved since the calibration, or it is another setup's" if level == "warn"
                   else ""))
    return {"cameras": per_camera, "epipolar_px": epipolar, "items": items}


def _grab(cameras: dict[str, Any], clock: Any, grab_s: float) -> dict[str, np.ndarray]:
    """Record ``grab_s`` s on every camera; the last frame of each."""
    for cam in cameras.values():
        cam.start()
    try:
        clock.sleep_s(grab_s)
    finally:
        for cam in cameras.values():
            cam.stop()
    last: dict[str, np.ndarray] = {}
    for name, cam in cameras.items():
        for frame in cam.frames():
            last[name] = frame.image
    return last


def run_preview(config: Any, *, calibration: str | Path | None = None, host: str = "127.0.0.1", port: int = 0,
                allow_remote: bool = False, interval_s: float = 0.5, max_updates: int | None = None,
                limits: HintLimits = HintLimits(), stream: Any = None,
                stop: threading.Event | None = None) -> DashboardState:
    """Serve the live view until Ctrl-C, the page's Abort, ``stop`` set, or ``max_updates`` rounds; the
    final state (its ``hints``)."""
    from rig.run.clock import make_clock
    from rig.run.station import open_station

    cameras_cal = _load_calibration(calibration) if calibration is not None else None
    stop = stop or threading.Event()
    state = DashboardState("preview")
    server = DashboardServer(state, host=host, port=port, allow_remote=allow_remote,
                             on_abort=lambda reason: stop.set())
    clock = make_clock(config.station.clock == "virtual", rate=config.sim.rate if config.sim else None)
    FRAMES.reset()
    FRAMES.enabled = True
    try:
        with open_station(config, clock) as station, server:
            state.fields["simulated"] = bool(config.station.simulated)
            print(f"rig preview: live view at {server.url} (Ctrl-C stops it)", file=stream or sys.stderr,
                  flush=True)
            cams = dict(sorted(station.cameras.items()))
            grab_s = 3.0 / min(c.fps for c in config.cameras.values())
            led_regions = dict(config.fiducial.regions_px) if config.fiducial is not None else {}
            updates = 0
            while not stop.is_set() and (max_updates is None or updates < max_updates):
                started = time.monotonic()
                images = _grab(cams, clock, grab_s)
                views = [view_of(name, image, led_regions.get(name)) for name, image in images.items()]
                for name, image in images.items():
                    view = next(v for v in views if v.name == name)
                    FRAMES.offer(name, updates, image, view.uv_px, np.arange(len(view.uv_px)))
                state.set_hints(preview_hints(views, cameras_cal, limits))
                updates += 1
                stop.wait(max(0.0, interval_s - (time.monotonic() - started)))
    finally:
        FRAMES.enabled = False
    return state


def _load_calibration(path: str | Path) -> dict[str, Any]:
    import json

    from rig.analysis.analyse import load_cameras
    from rig.run.procedure import ParameterError

    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise ParameterError("--calibration", f"{path}: {exc}") from exc
    try:
        return load_cameras(data, path)
    except ValueError as exc:
        raise ParameterError("--calibration", str(exc)) from exc
