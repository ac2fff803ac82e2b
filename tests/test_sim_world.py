"""The simulated world: target geometry, scene timeline and marker truth against independent formulas."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from drivers.sim.bodies import SimCommandError
from drivers.sim.targets import CalibrationPlate, OscillatingPlate, ReferenceMarkers, TargetSet
from drivers.sim.world import SCENES, World, WorldLayout


def test_default_layout_ids_and_geometry() -> None:
    world = World()
    assert world.scene == "calibration_plate"
    ids = world.marker_ids
    assert len([m for m in ids if m.startswith("cal_")]) == 35 and sum(m.startswith("ref") for m in ids) >= 3
    pts = world.markers(0.0)
    # plate: 40 mm pitch in a plane facing the cameras (+x), 30 mm in front of the flange at x = 350
    assert np.linalg.norm(pts["cal_r0c1"] - pts["cal_r0c0"]) == pytest.approx(40.0)
    assert np.linalg.norm(pts["cal_r1c0"] - pts["cal_r0c0"]) == pytest.approx(40.0)
    assert pts["cal_r0c0"][2] > pts["cal_r1c0"][2]  # row 0 on top
    assert all(p[0] == pytest.approx(380.0) for m, p in pts.items() if m.startswith("cal_"))
    np.testing.assert_allclose(world.marker_normal("cal_r2c3", 0.0), [1.0, 0.0, 0.0], atol=1e-12)
    refs = np.array([pts[m] for m in ids if m.startswith("ref")])
    assert np.linalg.matrix_rank(refs[1:] - refs[0], tol=1.0) >= 2  # not collinear
    for scene in SCENES:
        assert set(world.scene_marker_ids(scene)) >= {m for m in ids if m.startswith("ref")}


def test_flange_markers_follow_the_pose_transform() -> None:
    world = World()
    world.set_scene("marker_frame", 0.0)
    world.robot.move(0.0, (400.0, 80.0, 330.0, 75.0, 10.0, 100.0), 150.0, 600.0)
    offsets = dict(zip([f"frame{k}" for k in range(8)], TargetSet().marker_frame.offsets_mm, strict=True))
    t = np.array([0.0, 0.3, 0.55, 2.0])
    got = world.markers(t)
    poses = world.robot.pose_at(t)
    for mid, off in offsets.items():
        rot = Rotation.from_euler("xyz", poses[:, 3:], degrees=True)  # Denso: R = Rz·Ry·Rx
        np.testing.assert_allclose(got[mid], poses[:, :3] + rot.apply(off), atol=1e-9)
    np.testing.assert_allclose(world.positions(list(offsets), t)[:, 2], [got[m][2] for m in offsets])


def test_sweep_column_plate_and_rotor_motion() -> None:
    world = World(layout=WorldLayout(crank_radius_mm=4.0))
    world.exciter.set_frequency(0.0, 12.0)
    world.rotor.set_frequency(0.0, 10.0)
    t = np.linspace(0.0, 1.0, 1001)
    col = world.positions(["col0", "col4"], t)
    disp = 4.0 * np.sin(2 * math.pi * 12.0 * t)
    np.testing.assert_allclose(col[0, :, 2] - col[0, 0, 2], disp, atol=1e-9)  # vertical, rigid arm
    np.testing.assert_allclose(col[1] - col[0], np.tile([0.0, 0.0, 140.0], (t.size, 1)), atol=1e-9)
    plate = world.positions(["plate_r0c0", "plate_r0c5"], t)
    amp = np.ptp(plate[..., 0], axis=1) / 2  # bending along the plate normal (x)
    xi = np.array([50.0, 300.0]) / 320.0
    np.testing.assert_allclose(amp, 4.0 * 0.5 * (3 * xi**2 - xi**3), rtol=1e-3)
    assert amp[1] > 5 * amp[0]  # amplitude grows away from the clamp
    rot = world.positions(["rotor"], t)[0]
    radius = np.linalg.norm(rot - np.array([420.0, 0.0, 300.0]), axis=1)
    np.testing.assert_allclose(radius, 60.0, atol=1e-9)
    angle = np.unwrap(np.arctan2(rot[:, 2] - 300.0, rot[:, 1]))
    np.testing.assert_allclose(angle - angle[0], 2 * math.pi * 10.0 * t, atol=1e-9)


def test_scene_timeline_keeps_the_past() -> None:
    world = World()
    world.set_scene("rotor", 5.0)
    world.set_scene("sweep_column", 7.0)
    assert world.scene_at(4.99) == "calibration_plate"
    assert world.scene_at(6.0) == "rotor" and "rotor" in world.marker_ids_at(6.0)
    assert world.scene_at(7.0) == "sweep_column"
    with pytest.raises(SimCommandError, match="before the previous"):
        world.set_scene("plate", 6.0)
    with pytest.raises(ValueError, match="scene must be one of"):
        world.set_scene("teapot", 9.0)
    with pytest.raises(KeyError, match="unknown marker_id"):
        world.marker_diameter_mm("nope")


def test_geometry_is_validated() -> None:
    with pytest.raises(ValueError, match="pitch_mm"):
        CalibrationPlate(marker_diameter_mm=50.0)
    with pytest.raises(ValueError, match="≥ 3 reference markers"):
        World(layout=WorldLayout(targets=TargetSet(references=ReferenceMarkers(positions_mm=((0, 0, 0),)))))
    with pytest.raises(ValueError, match=r"plate\.body"):
        World(layout=WorldLayout(targets=TargetSet(plate=OscillatingPlate(body="fan"))))


def test_markers_are_deterministic() -> None:
    a, b = World(seed=3), World(seed=3)
    for w in (a, b):
        w.robot.move(0.0, (300.0, 20.0, 310.0, 90.0, 0.0, 90.0), 100.0, 400.0)
    t = np.linspace(0, 1, 7)
    for mid in a.marker_ids:
        np.testing.assert_array_equal(a.markers(t)[mid], b.markers(t)[mid])
