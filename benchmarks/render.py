"""Frames per second of the simulated rolling-shutter camera (1920×1080, one core).

    .venv/bin/python benchmarks/render.py [--frames N]

Scenes: 12 markers (a column of 8 on the exciter at 20 Hz + 4 references) and 30 markers (a 2×13
cantilever plate at 3.5 Hz + 4 references); rolling shutter on (line time 0.9·T/1080), exposure 1/6000 s
and 1/250 s, read + shot noise on. Baseline measured in the same run: a naive full-frame render — fill the
background, draw every marker with ``cv2.circle(LINE_AA)`` at its projected centre (no rolling shutter,
no exposure integration, no perspective) and add fresh Gaussian noise to the whole frame.
Target (issue 3): ≥ 400 frames/s with 12 markers at 1/6000 s.
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np

from drivers.sim.stereo_rig import default_stereo_pair
from drivers.sim.targets import OscillatingPlate, SweepColumn, TargetSet
from drivers.sim.world import World, WorldLayout


def _world(n_markers: int) -> World:
    if n_markers == 12:
        layout = WorldLayout(initial_scene="sweep_column",
                             targets=TargetSet(sweep_column=SweepColumn(count=8, pitch_mm=25.0)))
    else:
        layout = WorldLayout(initial_scene="plate",
                             targets=TargetSet(plate=OscillatingPlate(cols=13, rows=2, pitch_mm=24.0)))
    world = World(seed=0, layout=layout)
    world.exciter.set_frequency(0.0, 20.0 if n_markers == 12 else 3.5)
    assert len(world.marker_ids) == n_markers
    return world


def _naive(cam, world: World, index: int, rng: np.random.Generator) -> np.ndarray:
    noise = cam.noise
    t = cam.frame_start_true_s(index) + cam.readout_s / 2
    uv = cam.project(world.positions(world.marker_ids, [t])[:, 0])
    frame = np.full((cam.height_px, cam.width_px), noise.background_level_dn, np.float32)
    for (u, v), mid in zip(uv, world.marker_ids, strict=True):
        r = world.marker_diameter_mm(mid) / 2 * cam.camera_matrix[0, 0] / 1500.0
        cv2.circle(frame, (round(u * 16), round(v * 16)), round(r * 16), noise.marker_level_dn, -1,
                   cv2.LINE_AA, shift=4)
    frame += rng.normal(0.0, float(noise.sigma_dn(noise.background_level_dn)), frame.shape).astype(np.float32)
    return np.clip(frame + 0.5, 0, 255).astype(np.uint8)


def _fps(fn, n: int) -> tuple[float, float]:
    """(frames per wall second, frames per CPU second of this process); the CPU figure is the one-core
    cost even when other processes share the machine."""
    fn(0)  # warm-up (noise pool, caches)
    w0, c0 = time.perf_counter(), time.process_time()
    for i in range(1, n + 1):
        fn(i)
    return n / (time.perf_counter() - w0), n / (time.process_time() - c0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=300)
    n = ap.parse_args().frames
    cv2.setNumThreads(1)  # one core
    print("frames/s on one core (wall clock | CPU time of this process); ratio on CPU time")
    print(f"{'markers':>7} {'exposure':>9} {'twin fps':>15} {'naive fps':>15} {'ratio':>6}")
    for n_markers in (12, 30):
        world = _world(n_markers)
        rng = np.random.default_rng(0)
        naive_cam = default_stereo_pair(world)[0]
        naive = _fps(lambda i, c=naive_cam, w=world, g=rng: _naive(c, w, i, g), max(20, n // 5))
        for exposure_s, label in ((1 / 6000, "1/6000"), (1 / 250, "1/250")):
            cam = default_stereo_pair(world, exposure_s=exposure_s)[0]
            fps = _fps(cam.render, n)
            print(f"{n_markers:>7} {label:>9} {fps[0]:>7.0f} | {fps[1]:>5.0f} "
                  f"{naive[0]:>7.0f} | {naive[1]:>5.0f} {fps[1] / naive[1]:>6.1f}")


if __name__ == "__main__":
    main()
