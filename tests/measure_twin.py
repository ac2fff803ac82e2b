"""Test support: videos of the simulated rig for ``rig calibrate`` and ``rig measure``, with their truth.

Half-size cameras (960 × 540, the default pair's optics scaled by ½) keep the tests fast; the benchmark
uses full 1080p. Calibration: the plate held still at ``SLIDES_MM`` along its normal (the arm slides it),
``HOLD_S`` per position. Measurement: the sweep column (5 markers moving together along base z with the
crank radius as amplitude) and the 4 fixed reference markers; the exciter starts at ``ONSET_S``.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from drivers.sim.camera import SimCamera
from drivers.sim.clock import VirtualClock
from drivers.sim.stereo_rig import CameraSpec, default_camera_specs, make_camera
from drivers.sim.world import World, WorldLayout

SLIDES_MM = (0.0, 60.0, 120.0)
HOLD_S = 0.5
HOME = (350.0, 0.0, 300.0, 90.0, 0.0, 90.0)
CRANK_MM = 4.0
FREQUENCY_HZ = 5.0
ONSET_S = 0.4


def half(spec: CameraSpec, scale: float = 0.5) -> CameraSpec:
    return replace(spec, fx_px=spec.fx_px * scale, fy_px=spec.fy_px * scale,
                   cx_px=(spec.cx_px + 0.5) * scale - 0.5, cy_px=(spec.cy_px + 0.5) * scale - 0.5)


def camera_pair(world: World, scale: float = 0.5, **overrides: object) -> tuple[SimCamera, SimCamera]:
    size = {"width_px": round(1920 * scale), "height_px": round(1080 * scale)}
    specs = [half(s, scale) for s in default_camera_specs()]
    extra = [dict(overrides.get(s.name, {})) for s in specs]  # type: ignore[call-overload]
    return (make_camera(specs[0], world, **size, **extra[0]),
            make_camera(specs[1], world, **size, **extra[1]))


def calibration_world(seed: int = 3) -> tuple[World, list[np.ndarray], float]:
    """World with the plate slid to SLIDES_MM; returns (world, plate truth per position, end time s)."""
    world = World(VirtualClock(), seed=seed, layout=WorldLayout(initial_scene="calibration_plate"))
    ids = [f"cal_r{r}c{c}" for r in range(5) for c in range(7)]
    truth, t = [], 0.0
    for k, slide in enumerate(SLIDES_MM):
        if k:
            pose = (HOME[0] + slide, *HOME[1:])
            t = world.robot.move(t, pose, 300.0, 2000.0, True)
        truth.append(world.positions(ids, t + 0.5 * HOLD_S)[:, 0, :] if False else
                     np.array([world.markers(t + 0.5 * HOLD_S)[m] for m in ids]))
        t += HOLD_S
    return world, truth, t


def write_target(path: Path, truth: list[np.ndarray]) -> Path:
    lines = ["[plate]", "rows = 5", "cols = 7", ""]
    for pts in truth:
        lines.append("[[positions]]")
        lines.append("markers_mm = [" + ", ".join(f"[{x:.6f}, {y:.6f}, {z:.6f}]" for x, y, z in pts) + "]")
        lines.append("")
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


def measurement_world(seed: int = 5, frequency_hz: float = FREQUENCY_HZ, onset_s: float = ONSET_S) -> World:
    world = World(VirtualClock(), seed=seed,
                  layout=WorldLayout(initial_scene="sweep_column", crank_radius_mm=CRANK_MM))
    world.exciter.set_frequency(onset_s, frequency_hz)
    return world


def truth_displacement_mm(world: World, t_world_s: np.ndarray) -> np.ndarray:
    """The column's displacement along base z (mm) at world times."""
    return np.asarray(world.exciter.displacement_mm(np.asarray(t_world_s, float)), float)
