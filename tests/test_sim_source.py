"""SimFrameSource: the simulated camera as a FrameSource over a recording interval in virtual time."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.camera.base import Frame, FrameSource
from drivers.sim.source import RecordingStateError, SimFrameSource
from drivers.sim.stereo_rig import default_stereo_pair
from drivers.sim.world import World


def test_records_every_frame_whose_exposure_lies_in_the_interval() -> None:
    world = World()
    world.clock.advance_to(10.0)
    left, right = (SimFrameSource(c) for c in default_stereo_pair(world))
    assert isinstance(left, FrameSource)
    left.start()
    right.start()
    world.clock.sleep_s(0.25)
    left.stop()
    right.stop()
    for src in (left, right):
        frames = list(src.frames())
        cam = src.camera
        assert all(isinstance(f, Frame) and f.image.shape == (1080, 1920) for f in frames)
        starts = np.array([cam.frame_start_true_s(f.index) for f in frames])
        assert starts[0] >= 10.0 and starts[0] - 10.0 < 1 / 60
        assert starts[-1] + cam.readout_s <= 10.25 < starts[-1] + 1 / 60 + cam.readout_s
        assert np.all(np.diff([f.timestamp_s for f in frames]) > 0)
        assert [f.index for f in frames] == list(range(frames[0].index, frames[-1].index + 1))
        assert frames[0].exposure_s == cam.exposure_s
    # the two cameras' clocks disagree: their time stamps are not the world time
    assert abs(next(left.frames()).timestamp_s - next(right.frames()).timestamp_s) > 1.0


def test_state_errors() -> None:
    src = SimFrameSource(default_stereo_pair(World())[0])
    with pytest.raises(RecordingStateError, match="not recorded"):
        list(src.frames())
    with pytest.raises(RecordingStateError, match="not recording"):
        src.stop()
    src.start()
    with pytest.raises(RecordingStateError, match="already recording"):
        src.start()
    src.camera.world.clock.sleep_s(0.1)
    assert len(list(src.frames())) >= 4  # while recording: up to now
