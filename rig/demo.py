"""``rig demo DIR``: sample stereo videos from the digital twin, to try ``rig calibrate`` and ``rig measure``
without a rig.

The twin (``drivers/sim``) films two scenes with the simulated rig's unsynchronized rolling-shutter camera
pair, at half the full resolution (960 × 540) to keep the files small and the first minute short:

* ``plate/left.mp4``, ``plate/right.mp4`` — the calibration plate (5 × 7 markers) slid by the arm along its
  normal and held still at :data:`PLATE_SLIDES_MM`, :data:`PLATE_HOLD_S` at each position;
* ``target.toml`` — the plate's marker coordinates (mm, robot base frame) at each position: what a
  surveyor hands over with a real plate;
* ``column/left.mp4``, ``column/right.mp4`` — a column of markers shaken by the crank exciter at
  :data:`COLUMN_FREQUENCY_HZ` with the crank radius as amplitude, already vibrating when the cameras
  start (as a structure is), and four fixed reference markers;
* ``TRUTH.txt`` — what the videos show, to compare ``rig measure``'s result with.

The right camera starts :data:`RIGHT_START_DELAY_S` after the left one (plus the twin's own sub-frame
start offsets and clock-rate errors), as two independent cameras do.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from drivers.sim.camera import SimCamera
from drivers.sim.clock import VirtualClock
from drivers.sim.stereo_rig import CameraSpec, default_camera_specs, make_camera
from drivers.sim.world import World, WorldLayout

SCALE = 0.5  # of the full 1920 × 1080 sensor and its optics
PLATE_ROWS, PLATE_COLS = 5, 7
PLATE_SLIDES_MM = (0.0, 60.0, 120.0)
PLATE_HOLD_S = 1.0  # 60 frames still per position: well above rig calibrate's --min-still-frames
SLIDE_SPEED_MM_S = 300.0
SLIDE_ACCEL_MM_S2 = 2000.0
COLUMN_FREQUENCY_HZ = 5.0
COLUMN_SPINUP_S = 3.0  # the exciter runs this long before the cameras start: steady from the first frame
COLUMN_DURATION_S = 4.0
RIGHT_START_DELAY_S = 0.15
SEED = 7


@dataclass(frozen=True)
class DemoFiles:
    """What :func:`write_demo` wrote (paths) and the truth the column video shows."""

    plate: tuple[Path, Path]
    target_toml: Path
    column: tuple[Path, Path]
    truth_txt: Path
    column_amplitude_mm: float
    column_frequency_hz: float


def _scaled(spec: CameraSpec) -> CameraSpec:
    """The camera with its sensor scaled by :data:`SCALE` (focal lengths and principal point with it)."""
    return replace(spec, fx_px=spec.fx_px * SCALE, fy_px=spec.fy_px * SCALE,
                   cx_px=(spec.cx_px + 0.5) * SCALE - 0.5, cy_px=(spec.cy_px + 0.5) * SCALE - 0.5)


def camera_pair(world: World) -> tuple[SimCamera, SimCamera]:
    size = {"width_px": round(1920 * SCALE), "height_px": round(1080 * SCALE)}
    left, right = (make_camera(_scaled(spec), world, **size) for spec in default_camera_specs())
    return left, right


def _write_pair(world: World, folder: Path, t_start_s: float, t_stop_s: float) -> tuple[Path, Path]:
    folder.mkdir(parents=True, exist_ok=True)
    left, right = camera_pair(world)
    paths = folder / "left.mp4", folder / "right.mp4"
    left.write_video(paths[0], t_start_s, t_stop_s)
    right.write_video(paths[1], t_start_s + RIGHT_START_DELAY_S, t_stop_s + RIGHT_START_DELAY_S)
    return paths


def _plate_scene(folder: Path) -> tuple[tuple[Path, Path], list[np.ndarray]]:
    """The slid plate's videos and its marker positions (mm) at each still position."""
    world = World(VirtualClock(), seed=SEED, layout=WorldLayout(initial_scene="calibration_plate"))
    home = world.layout.robot_home_pose
    ids = [f"cal_r{r}c{c}" for r in range(PLATE_ROWS) for c in range(PLATE_COLS)]
    positions, t_s = [], 0.0
    for k, slide_mm in enumerate(PLATE_SLIDES_MM):
        if k:
            pose = (home[0] + slide_mm, *home[1:])
            t_s = world.robot.move(t_s, pose, SLIDE_SPEED_MM_S, SLIDE_ACCEL_MM_S2, True)
        held = world.markers(t_s + 0.5 * PLATE_HOLD_S)
        positions.append(np.array([held[m] for m in ids]))
        t_s += PLATE_HOLD_S
    return _write_pair(world, folder, 0.0, t_s), positions


def _target_toml(path: Path, positions: list[np.ndarray]) -> Path:
    lines = ["# The demo plate: 5 × 7 markers, their coordinates (mm) at each still position.",
             "[plate]", f"rows = {PLATE_ROWS}", f"cols = {PLATE_COLS}", ""]
    for points in positions:
        markers = ", ".join(f"[{x:.6f}, {y:.6f}, {z:.6f}]" for x, y, z in points)
        lines += ["[[positions]]", f"markers_mm = [{markers}]", ""]
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


def _column_scene(folder: Path) -> tuple[tuple[Path, Path], float]:
    """The vibrating column's videos (filmed after the exciter reached speed) and its amplitude (mm)."""
    world = World(VirtualClock(), seed=SEED + 1, layout=WorldLayout(initial_scene="sweep_column"))
    world.exciter.set_frequency(0.0, COLUMN_FREQUENCY_HZ)
    paths = _write_pair(world, folder, COLUMN_SPINUP_S, COLUMN_SPINUP_S + COLUMN_DURATION_S)
    return paths, world.layout.crank_radius_mm


def write_demo(folder: Path) -> DemoFiles:
    """Write the demo videos, ``target.toml`` and ``TRUTH.txt`` into ``folder`` (created if needed)."""
    folder.mkdir(parents=True, exist_ok=True)
    plate, positions = _plate_scene(folder / "plate")
    target = _target_toml(folder / "target.toml", positions)
    column, amplitude_mm = _column_scene(folder / "column")
    truth = folder / "TRUTH.txt"
    truth.write_text(
        "What the demo videos show (the digital twin's truth):\n"
        f"- plate: {PLATE_ROWS} x {PLATE_COLS} markers held still at slides {PLATE_SLIDES_MM} mm along its "
        f"normal, {PLATE_HOLD_S} s each (target.toml has their coordinates)\n"
        f"- column: 5 markers vibrating together along the robot base z axis at {COLUMN_FREQUENCY_HZ} Hz, "
        f"amplitude {amplitude_mm} mm, steady from the first frame; 4 fixed reference markers\n"
        f"- cameras: 960 x 540, 60 FPS, rolling shutter; the right one starts {RIGHT_START_DELAY_S} s after "
        "the left (plus sub-frame offsets and clock-rate errors of a few ppm)\n",
        encoding="utf-8")
    return DemoFiles(plate=plate, target_toml=target, column=column, truth_txt=truth,
                     column_amplitude_mm=amplitude_mm, column_frequency_hz=COLUMN_FREQUENCY_HZ)


def next_commands(files: DemoFiles, folder: Path) -> list[str]:
    """The two commands that calibrate from the plate videos and measure the column videos."""
    calibration = folder / "calibration.json"
    return [
        f"rig calibrate {files.plate[0]} {files.plate[1]} --target {files.target_toml} --out {calibration}",
        f"rig measure {files.column[0]} {files.column[1]} --calibration {calibration} "
        f"--out {folder / 'measurement'}",
    ]
