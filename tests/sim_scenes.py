"""The suite's typical twin scenes at 1080p (the default camera pair), for the render pin test and benchmark.

* ``plate``: the calibration plate (35 markers + 4 references) on the arm, slid 60 mm and turned 10° about
  base x from t = 0.1 s, at rest again before 0.6 s;
* ``sweep``: the sweep column (5 markers + references) on the crank at 5 Hz, 4 mm;
* ``rotor``: the rotor marker (+ references) turning at 10 Hz;
* ``led``: the fiducial LED bar of ``rig/data/sim.toml`` blinking at 10.27 Hz over the sweep column.
Each ``scene(name)`` returns the two cameras and the frame indices to render (world 0 … ``DURATION_S``).
"""

from __future__ import annotations

from drivers.sim.camera import SimCamera
from drivers.sim.clock import VirtualClock
from drivers.sim.fiducial import SyncLed
from drivers.sim.stereo_rig import default_stereo_pair
from drivers.sim.world import World, WorldLayout

SCENE_NAMES = ("plate", "sweep", "rotor", "led")
DURATION_S = 0.8
HOME = (350.0, 0.0, 300.0, 90.0, 0.0, 90.0)


def _world(name: str) -> World:
    initial = {"plate": "calibration_plate", "sweep": "sweep_column", "rotor": "rotor", "led": "sweep_column"}
    layout = WorldLayout(initial_scene=initial[name], crank_radius_mm=4.0)
    world = World(VirtualClock(), seed=7, layout=layout)
    if name == "plate":
        world.robot.move(0.1, (HOME[0] + 60.0, HOME[1], HOME[2], HOME[3] + 10.0, *HOME[4:]), 300.0, 2000.0)
    elif name == "rotor":
        world.rotor.set_frequency(-10.0, 10.0)
    else:
        world.exciter.set_frequency(-10.0, 5.0)
    if name == "led":
        led = world.add_led(SyncLed("fiducial", (300.0, -420.0, 150.0), (0.0, 5.0, 0.0), (0.0, 0.0, 75.0)))
        led.waveform.set_frequency(-10.0, 10.27)
        led.set_enabled(0.05, True)
    return world


def scene(name: str) -> tuple[tuple[SimCamera, SimCamera], range]:
    """The default 1080p pair filming scene ``name`` and the indices of its frames within 0 … DURATION_S."""
    cameras = default_stereo_pair(_world(name))
    return cameras, cameras[0].frame_indices_between(0.0, DURATION_S)
