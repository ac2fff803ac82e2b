"""The other camera of a fiducial-dated segment dated by its own fiducial fit (analyse.own_dated):
its observations land on the reference camera's clock of the segment such that the segment's relation
gives back exactly the controller times its own fit states, whatever the timing model's drift said."""

from __future__ import annotations

import numpy as np
import pandas as pd
from hypothesis import given, settings
from hypothesis import strategies as st

from rig.analysis.analyse import SegmentClock, own_dated
from rig.analysis.fiducial import CameraDating
from rig.stereo.timing import TimingResult

TIMING = TimingResult(reference_camera="left", offset_s={"left": 0.0, "right": 0.0041},
                      line_time_s={"left": 13.9e-6, "right": 13.9e-6}, drift_ppm={"left": 0.0, "right": 35.0},
                      method="test")


@settings(max_examples=50, deadline=None)
@given(st.floats(-5.0, 5.0), st.floats(-80e-6, 80e-6), st.floats(-5.0, 5.0), st.floats(-80e-6, 80e-6),
       st.floats(-1e-6, 1e-6))
def test_own_dating_is_kept_through_the_segments_relation(offset_ref: float, rate_ref: float,
                                                         offset_own: float, rate_own: float,
                                                         line_error: float) -> None:
    ts = np.linspace(100.0, 110.0, 40)
    rows = np.linspace(0.0, 1079.0, 40)
    obs = pd.DataFrame({"timestamp_s": ts, "v_px": rows, "time_s": TIMING.times("right", ts, rows)})
    left = pd.DataFrame({"timestamp_s": ts, "v_px": rows, "time_s": TIMING.times("left", ts, rows)})
    clock = SegmentClock(offset_ref, 1e-6, "timing fiducial", rate_ref, 105.0, 0.0,
                         (CameraDating("right", offset_own, 2e-6, rate_own, 104.0, line_error),))
    out = own_dated({"left": left, "right": obs}, TIMING, clock)
    assert out["left"] is left  # the reference camera keeps its dating
    t = out["right"]["time_s"].to_numpy(float)
    controller = t + clock.offset_s + clock.rate * (t - clock.t_ref_s)
    expected = clock.others[0].controller_times_s(TIMING, ts, rows)
    assert np.allclose(controller, expected, rtol=0.0, atol=1e-9)


def test_without_own_datings_nothing_changes() -> None:
    ts, rows = np.array([1.0, 2.0]), np.array([10.0, 20.0])
    sel = {"right": pd.DataFrame({"timestamp_s": ts, "v_px": rows, "time_s": [5.0, 6.0]})}
    assert own_dated(sel, TIMING, SegmentClock(0.1, 1e-3, "start events"))["right"] is sel["right"]
