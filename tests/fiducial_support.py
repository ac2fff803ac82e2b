"""The timing fiducial's rows as a simulated camera films them (shared by the twin tests and
benchmarks/fiducial.py)."""

from __future__ import annotations

import numpy as np

from drivers.sim.camera import SimCamera
from drivers.sim.fiducial import SyncLed
from rig.stereo.fiducial import RowSamples, row_profile


def led_rows(cam: SimCamera, led: SyncLed, t0_s: float, t1_s: float) -> RowSamples:
    """The LED's rows in every frame (camera clock), from the rendered images: the configured image region
    is the projected bar, 3 px inside its outline."""
    uv = cam.project(led.corners_mm())
    x0, y0 = (np.floor(uv.min(axis=0)) + 3).astype(int)
    x1, y1 = (np.ceil(uv.max(axis=0)) - 3).astype(int)
    starts, brightness = [], []
    for i in cam.frame_indices_between(t0_s, t1_s):
        rows, mean = row_profile(cam.render(i), (x0, y0, x1, y1))
        starts.append(cam.frame_timestamp_s(i) + rows * cam.line_time_s)
        brightness.append(mean)
    return RowSamples(np.concatenate(starts), np.concatenate(brightness), cam.exposure_s)
