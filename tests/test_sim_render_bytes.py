"""The twin's frames are pinned byte for byte: every tolerance of the suite was set against these bytes.

The digests were recorded from the renderer before the per-frame cost was cut (draw13, base 00638ab); a
faster renderer must draw exactly the same frames. A change that is meant to move bytes re-records them
here, and says so.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
from sim_scenes import HOME, SCENE_NAMES, scene

FRAMES = (0, 7, 13, 21, 30, 41)  # plate: at rest, moving, turning, arriving; sweep/rotor/led: phases
DIGESTS = {
    "plate": "24ee44eb2936aeb6d0e88fc1f649865293e57f98f9137759a4f8d8046e3ea10b",
    "sweep": "ebcd3cc503a2a32527d8d5dcf42fa6fcfb1a7d5301698ecfa8b7f30978f4cce2",
    "rotor": "66d65399e2521c4b0e909c1cc3cb6224a2b03586d860db506d57585c4596cac3",
    "led": "0b3182e3f3030cdb4f1c5981d8b69e6bc21f3b7e67342fccafce0b0c00e74124",
}


def _digest(name: str) -> str:
    (left, right), indices = scene(name)
    sha = hashlib.sha256()
    for k in FRAMES:
        for cam in (left, right):
            sha.update(cam.render(indices[k]).tobytes())
    return sha.hexdigest()


@pytest.mark.parametrize("name", SCENE_NAMES)
def test_rendered_frames_keep_their_recorded_bytes(name: str) -> None:
    assert _digest(name) == DIGESTS[name]


def test_a_still_frame_after_a_late_command_is_drawn_from_the_new_plan() -> None:
    """A camera reuses a still frame's marker patches for the next still frame; a move commanded afterwards
    for an earlier time (the plate rests elsewhere by then) must not leave it drawing the old pose."""
    (cam, _), indices = scene("sweep")  # a world whose arm has no move yet
    cam.world.set_scene("calibration_plate", 0.0)
    early, late = indices[40], indices[41]
    before = cam.render(early)
    cam.world.robot.move(0.05, (HOME[0] + 40.0, *HOME[1:]), 300.0, 2000.0)  # at rest again by 0.4 s
    fresh, _ = scene("sweep")
    fresh[0].world.set_scene("calibration_plate", 0.0)
    fresh[0].world.robot.move(0.05, (HOME[0] + 40.0, *HOME[1:]), 300.0, 2000.0)
    assert not np.array_equal(before, fresh[0].render(early))  # the plate did move
    assert np.array_equal(cam.render(late), fresh[0].render(late))
