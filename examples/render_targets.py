"""Render a few frames of every target of the simulated rig to PNG files under examples/out/.

    .venv/bin/python examples/render_targets.py [OUT_DIR]

For each scene: the full left-camera frame (markers moving as the procedures move them) and a zoomed
crop around the mounted target. Extra files show the rolling shutter (a large disc on the 10 Hz rotor,
rolling vs near-global shutter: the rolling one is sheared) and exposure blur (1/250 s vs 1/6000 s).
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

from drivers.sim.stereo_rig import default_camera_specs, make_camera
from drivers.sim.targets import RotorTarget, TargetSet
from drivers.sim.world import World, WorldLayout

OUT = Path(__file__).resolve().parent / "out"


def _crop(img: np.ndarray, centre_uv: np.ndarray, half_px: int, zoom: int) -> np.ndarray:
    u, v = (round(float(x)) for x in centre_uv)
    h, w = img.shape
    y0, x0 = max(0, v - half_px), max(0, u - half_px)
    patch = img[y0 : min(h, v + half_px), x0 : min(w, u + half_px)]
    return cv2.resize(patch, None, fx=zoom, fy=zoom, interpolation=cv2.INTER_NEAREST)


def _save(out: Path, name: str, img: np.ndarray) -> None:
    out.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out / f"{name}.png"), img):
        raise OSError(f"could not write {out / name}.png")
    print(f"wrote {out / name}.png")


def _world() -> World:
    world = World(seed=1)
    world.robot.move(0.0, (300.0, 0.0, 300.0, 90.0, 0.0, 90.0), 100.0, 500.0)  # plate slides along its normal
    world.set_scene("single_marker", 2.0)
    world.robot.move(2.0, (380.0, 150.0, 360.0, 90.0, 0.0, 90.0), 400.0, 2000.0)  # fast diagonal move
    world.set_scene("marker_frame", 4.0)
    world.robot.move(4.0, (380.0, -80.0, 250.0, 80.0, 10.0, 100.0), 250.0, 1500.0)
    world.set_scene("sweep_column", 6.0)
    world.exciter.sweep(6.0, 5.0, 30.0, 2.0, "linear")
    world.set_scene("plate", 8.0)
    world.exciter.set_frequency(8.0, 3.5)
    world.set_scene("rotor", 10.0)
    world.rotor.set_frequency(0.0, 10.0)
    return world


def main(out: Path = OUT) -> None:
    world = _world()
    spec = default_camera_specs()[0]
    cam = make_camera(spec, world)
    shots = {"calibration_plate": 0.5, "single_marker": 2.3, "marker_frame": 4.3, "sweep_column": 7.6,
             "plate": 9.05, "rotor": 10.5}
    for scene, t in shots.items():
        for n in range(2):
            i = cam.first_frame_index_at_or_after(t) + n
            img = cam.render(i)
            _save(out, f"{scene}_frame{n}", img)
            ids = world.marker_ids_at(cam.frame_start_true_s(i))
            target = [m for m in ids if not m.startswith("ref")]
            uv = cam.project(world.positions(target, [cam.row_time_true_s(i, 540)])[:, 0])
            _save(out, f"{scene}_frame{n}_zoom", _crop(img, uv.mean(axis=0), 200 if len(target) > 1 else 60,
                                                  2 if len(target) > 1 else 6))
    # rolling shutter: a large (50 mm) disc on the rotor at 10 Hz, rows read over 90 % of the frame period
    # (default) vs an (almost) global shutter: the rolling-shutter disc is sheared, as in the paper's Fig. 1
    big = World(seed=1, layout=WorldLayout(targets=TargetSet(rotor=RotorTarget(marker_diameter_mm=50.0)),
                                           initial_scene="rotor"))
    big.rotor.set_frequency(0.0, 10.0)
    for label, overrides in (("global_like", {"line_time_s": 1e-9}), ("rolling", {})):
        c = make_camera(spec, big, **overrides)
        i = c.first_frame_index_at_or_after(0.5)
        img = c.render(i)
        uv = c.project(big.positions(["rotor"], [c.row_time_true_s(i, 540)])[:, 0])[0]
        _save(out, f"rotor_big_disc_{label}_zoom", _crop(img, uv, 60, 6))
    # exposure blur: the 10 Hz rotor marker at 1/250 s (an arc) vs the default 1/6000 s
    for label, exposure_s in (("1_250s", 1 / 250), ("1_6000s", 1 / 6000)):
        c = make_camera(spec, world, exposure_s=exposure_s)
        i = c.first_frame_index_at_or_after(10.5)
        centre = c.project(np.array([[420.0, 0.0, 300.0]]))[0]
        _save(out, f"rotor_exposure_{label}_zoom", _crop(c.render(i), centre, 130, 3))


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else OUT)
