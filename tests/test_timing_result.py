"""TimingResult ⇄ timing.json and the row-corrected time model."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig.stereo.errors import InputArrayError
from rig.stereo.timing import TimingResult, corrected_times


def _result() -> TimingResult:
    return TimingResult(
        reference_camera="left",
        offset_s={"left": 0.0, "right": -790.74},
        line_time_s={"left": 13.9e-6, "right": 13.9e-6},
        drift_ppm={"left": 0.0, "right": -47.0},
        method="joint",
        uncertainty={"offset_s": {"left": 0.0, "right": 4.9e-6}, "drift_ppm": {"left": 0.0, "right": 0.6}},
        epoch_s={"left": 0.0, "right": 808.1},
        details={"residual_rms_px": np.float64(0.1), "correlation": np.eye(2)},
    )


def test_round_trip_through_json_matches_the_contract_layout():
    d = _result().to_dict()
    text = json.dumps(d)  # numpy scalars and arrays are converted
    back = TimingResult.from_dict(json.loads(text))
    assert back.to_dict() == d
    for key in ("reference_camera", "offset_s", "line_time_s", "drift_ppm", "method", "uncertainty"):
        assert key in d
    assert d["details"]["correlation"] == [[1.0, 0.0], [0.0, 1.0]]


def test_times_apply_offset_drift_about_the_epoch_and_the_row():
    res = _result()
    tau = np.array([808.1, 818.1])
    v = np.array([0.0, 500.0])
    t = res.times("right", tau, v)
    expected = tau - 790.74 - 47e-6 * (tau - 808.1) + v * 13.9e-6
    np.testing.assert_allclose(t, expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.times("left", tau, v), tau + v * 13.9e-6, rtol=0, atol=1e-12)
    with pytest.raises(InputArrayError, match="middle"):
        res.times("middle", tau, v)


@settings(max_examples=50, deadline=None)
@given(
    offset=st.floats(-1e3, 1e3),
    line=st.floats(0, 3e-5),
    drift=st.floats(-500, 500),
    epoch=st.floats(-1e3, 1e3),
)
def test_corrected_times_are_increasing_in_the_frame_stamp_and_row(offset, line, drift, epoch):
    tau = np.linspace(0.0, 10.0, 11)
    v = np.full(11, 300.0)
    t = corrected_times(tau, v, offset_s=offset, line_time_s=line, drift_ppm=drift, epoch_s=epoch)
    assert np.all(np.diff(t) > 0)
    t_lower = corrected_times(
        tau, v + 100.0, offset_s=offset, line_time_s=line, drift_ppm=drift, epoch_s=epoch
    )
    assert np.all(t_lower >= t)


def test_from_dict_names_what_is_missing():
    with pytest.raises(InputArrayError, match="reference_camera"):
        TimingResult.from_dict({"offset_s": {}, "method": "joint"})
    with pytest.raises(InputArrayError, match="offset_s"):
        TimingResult.from_dict({"reference_camera": "left", "offset_s": {"right": 0.0}, "method": "joint"})
    with pytest.raises(InputArrayError, match="drift_ppm"):
        TimingResult.from_dict(
            {"reference_camera": "l", "offset_s": {"l": 0.0}, "method": "x", "drift_ppm": {"l": "fast"}}
        )
    with pytest.raises(InputArrayError, match=r"uncertainty must map quantity → \{camera"):
        TimingResult.from_dict(
            {"reference_camera": "l", "offset_s": {"l": 0.0}, "method": "x",
             "uncertainty": {"offset_s": 2e-5}}
        )
    with pytest.raises(InputArrayError, match="same shape"):
        corrected_times(np.zeros(3), np.zeros(4))
