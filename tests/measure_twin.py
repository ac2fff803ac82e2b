"""Test support: videos of the simulated rig for ``rig calibrate`` and ``rig measure``, with their truth.

Half-size cameras (960 × 540, the default pair's optics scaled by ½) keep the tests fast; the benchmark
uses full 1080p. Calibration: the plate held still at ``SLIDES_MM`` along its normal (the arm slides it),
``HOLD_S`` per position. Measurement: the sweep column (5 markers moving together along base z with the
crank radius as amplitude) and the 4 fixed reference markers; the exciter starts at ``ONSET_S``.
"""

from __future__ import annotations

from dataclasses import replace
from itertools import pairwise
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


def write_pair(
    left: SimCamera,
    right: SimCamera,
    folder: Path,
    *,
    fourcc: str = "mp4v",
    ext: str = "mp4",
    t_left_s: tuple[float, float] = (0.0, 2.5),
    t_right_s: tuple[float, float] = (0.15, 2.65),
) -> tuple[Path, Path]:
    """Both cameras' videos of their intervals (world s); the right camera starts later, as on site."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = folder / f"left.{ext}", folder / f"right.{ext}"
    left.write_video(paths[0], *t_left_s, fourcc=fourcc)
    right.write_video(paths[1], *t_right_s, fourcc=fourcc)
    return paths


def truth_timing(left: SimCamera, right: SimCamera, t_left0_s: float, t_right0_s: float) -> dict:
    """timing.json of the twin's truth for videos starting at those world times: time stamps are the files'
    (first frame at 0), the left camera's clock is the reference (its rate error makes the drift)."""
    k0l = left.sensor_frame(left.first_frame_index_at_or_after(t_left0_s))
    k0r = right.sensor_frame(right.first_frame_index_at_or_after(t_right0_s))
    rate_l = 1.0 + left.clock_ppm * 1e-6
    rate_r = 1.0 + right.clock_ppm * 1e-6
    start_l = left.start_offset_s + k0l * left.frame_period_true_s
    start_r = right.start_offset_s + k0r * right.frame_period_true_s
    return {
        "reference_camera": "left",
        "offset_s": {"left": 0.0, "right": (start_r - start_l) * rate_l},
        "line_time_s": {"left": left.line_time_s * rate_l, "right": right.line_time_s * rate_l},
        "drift_ppm": {"left": 0.0, "right": (rate_l / rate_r - 1.0) * 1e6},
        "epoch_s": {"left": 0.0, "right": 0.0},
        "method": "twin truth",
        "uncertainty": {},
    }


def world_time(left: SimCamera, t_left0_s: float, t_ref_s: np.ndarray) -> np.ndarray:
    """World time of instants on the left video's clock (mid-exposure)."""
    k0l = left.sensor_frame(left.first_frame_index_at_or_after(t_left0_s))
    start_l = left.start_offset_s + k0l * left.frame_period_true_s
    return start_l + np.asarray(t_ref_s, float) / (1.0 + left.clock_ppm * 1e-6) + 0.5 * left.exposure_s


# ---------------------------------------------------------------- hard scenarios (issue 14): motion already
# running at the first frame, one column moving along one axis, a rotor, successive tones, a chirp, a larger
# start offset and a 100 ppm clock. Each builds its world; the cameras are the twin's (drivers.sim), whose
# camera model (OpenCV projection, its own rolling shutter and clocks) the measurement does not share.

STEADY_FROM_S = -10.0  # the motion started long before either video


def steady_world(frequency_hz: float = FREQUENCY_HZ, seed: int = 5) -> World:
    """The sweep column vibrating at ``frequency_hz`` since before the videos start."""
    return measurement_world(seed=seed, frequency_hz=frequency_hz, onset_s=STEADY_FROM_S)


def tones_world(tones: tuple[tuple[float, float], ...], seed: int = 5) -> World:
    """Successive tones ``(frequency_hz, until_s)`` (world s), the first running since before the videos."""
    world = measurement_world(seed=seed, frequency_hz=tones[0][0], onset_s=STEADY_FROM_S)
    for (_, until), (f_next, _) in pairwise(tones):
        world.exciter.set_frequency(until, f_next)
    return world


def chirp_world(start_hz: float, stop_hz: float, t0_s: float, t1_s: float, seed: int = 5) -> World:
    """A steady ``start_hz`` tone, then a linear chirp to ``stop_hz`` over ``t0_s`` … ``t1_s`` (world s)."""
    world = measurement_world(seed=seed, frequency_hz=start_hz, onset_s=STEADY_FROM_S)
    world.exciter.sweep(t0_s, start_hz, stop_hz, t1_s - t0_s)
    return world


def rotor_world(rotation_hz: float = 10.0, seed: int = 5) -> World:
    """The rotor marker turning at a constant ``rotation_hz`` since before the videos start."""
    world = World(VirtualClock(), seed=seed, layout=WorldLayout(initial_scene="rotor"))
    world.rotor.set_frequency(STEADY_FROM_S, rotation_hz)
    return world


def rotor_radius_mm() -> float:
    from drivers.sim.targets import RotorTarget

    return RotorTarget().radius_mm


def calibrated_site(folder: Path) -> dict:
    """``rig calibrate`` on the twin's plate videos in ``folder``: {"folder", "calibration" (path),
    "scale_floor"} — the floor being the largest relative length error of the plate's points (> 100 mm
    apart) when their exact images are triangulated with the calibration."""
    import json

    from scipy.spatial.distance import pdist

    from rig.analysis.analyse import load_cameras
    from rig.cli import main
    from rig.stereo import triangulate

    world, truth, t_end = calibration_world()
    left, right = camera_pair(world)
    left.write_video(folder / "cal_left.mp4", 0.0, t_end, fourcc="mp4v")
    right.write_video(folder / "cal_right.mp4", 0.0, t_end, fourcc="mp4v")
    target = write_target(folder / "target.toml", truth)
    code = main(["calibrate", str(folder / "cal_left.mp4"), str(folder / "cal_right.mp4"), "--target",
                 str(target), "--out", str(folder / "calibration.json")])
    if code != 0:
        raise RuntimeError(f"rig calibrate on the twin's plate videos exited {code}")
    cams = load_cameras(json.loads((folder / "calibration.json").read_text()))
    pts = np.concatenate(truth)
    tri = triangulate([cams["left"], cams["right"]], [left.project(pts), right.project(pts)])
    d_true, d_meas = pdist(pts), pdist(tri.xyz_mm)
    long = d_true > 100.0
    scale = float(np.max(np.abs(d_meas[long] - d_true[long]) / d_true[long]))
    return {"folder": folder, "calibration": folder / "calibration.json", "scale_floor": scale}


def mjpg_site(folder: Path) -> dict:
    """A calibrated site of Motion-JPEG AVIs in ``folder``: the plate videos calibrated by ``rig calibrate``
    (``calibration.json``, ``target.toml``) and a 1.5 s measurement pair with its true ``timing.json``.
    Keys: folder, target, truth (plate points per position), left, right (measurement videos), paths
    (both), calibration, timing."""
    import json

    from rig.cli import main

    world, truth, t_end = calibration_world()
    left, right = camera_pair(world)
    left.write_video(folder / "cal_left.avi", 0.0, t_end, fourcc="MJPG")
    right.write_video(folder / "cal_right.avi", 0.0, t_end, fourcc="MJPG")
    target = write_target(folder / "target.toml", truth)
    code = main(["calibrate", str(folder / "cal_left.avi"), str(folder / "cal_right.avi"), "--target",
                 str(target), "--out", str(folder / "calibration.json")])
    if code != 0:
        raise RuntimeError(f"rig calibrate on the twin's plate videos exited {code}")
    left, right = camera_pair(measurement_world())
    paths = write_pair(left, right, folder, fourcc="MJPG", ext="avi", t_left_s=(0.0, 1.5),
                       t_right_s=(0.15, 1.65))
    (folder / "timing.json").write_text(json.dumps(truth_timing(left, right, 0.0, 0.15)))
    return {"folder": folder, "target": target, "truth": truth, "left": paths[0], "right": paths[1],
            "paths": paths, "calibration": folder / "calibration.json", "timing": folder / "timing.json"}


def first_frame_world_s(camera: SimCamera, t_world0_s: float) -> float:
    """World time at which the first frame of a video starting at ``t_world0_s`` begins its exposure."""
    k0 = camera.sensor_frame(camera.first_frame_index_at_or_after(t_world0_s))
    return camera.start_offset_s + k0 * camera.frame_period_true_s


def write_mkv_video(camera: SimCamera, path: Path, t_start_s: float, t_stop_s: float, *,
                    date_utc_ns: int | None) -> Path:
    """The camera's frames between two world times as Motion-JPEG in Matroska, each frame at its own time
    stamp (from the first frame's), with ``date_utc_ns`` as the container's Info/DateUTC (ns since
    2001-01-01 UTC), if given."""
    from camera_mkv import write_mkv

    indices = camera.frame_indices_between(t_start_s, t_stop_s)
    t0 = camera.frame_timestamp_s(indices[0])
    write_mkv(path, (camera.render(i) for i in indices), [camera.frame_timestamp_s(i) - t0 for i in indices],
              date_utc_ns=date_utc_ns)
    return path
