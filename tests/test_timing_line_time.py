"""The joint estimator reports a line time it cannot observe (LineTimeNotObservableError) instead of
returning a value at its bound; with a prior on it, the offset's uncertainty covers all the line time can do.

Synthetic two-camera rolling-shutter records with known truth (``timing_synth``): line time 12 µs,
offset 4.3 ms, 0.1 px noise, 7 s at 60 fps.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from timing_synth import oscillation, rotor

from rig.deploy.video_timing import estimate_video_timing
from rig.stereo.dlt import DLTCamera
from rig.stereo.errors import LineTimeNotObservableError, TimingError
from rig.stereo.timing import estimate_offset
from tests.test_timing_joint import FS_HZ, _synthetic

OFFSET_S, LINE_S = 0.0043, 12e-6


def _along_rows():
    # cameras side by side (B 120 mm higher), the marker oscillating along x: it moves along the image rows
    return oscillation(3.0, 30.0, (1.0, 0.0, 0.0), centre_mm=(0.0, 0.0, 1500.0))


@pytest.mark.parametrize("seed", [0, pytest.param(1, marks=pytest.mark.slow),
                                  pytest.param(2, marks=pytest.mark.slow)])
def test_markers_moving_along_their_rows_raise_instead_of_an_impossible_line_time(seed: int) -> None:
    ca, cb, a, b = _synthetic(_along_rows(), seed=seed)
    with pytest.raises(LineTimeNotObservableError, match="line time is not observable") as info:
        estimate_offset(ca, cb, a, b)
    err = info.value
    assert isinstance(err, TimingError)
    # the rows of both cameras change by well under a pixel relative to each other …
    assert err.row_difference_spread_px < 1.0
    # … so the fit cannot even place the line time within its physical range (frame period / largest row)
    assert err.uncertainty_s > err.limit_s
    assert err.limit_s == pytest.approx((1 / FS_HZ) / max(np.max(a[1][:, 1]), np.max(b[1][:, 1])), rel=1e-3)
    assert "line_time_s" in str(err)
    # with the line time given, the offset is found within its uncertainty
    res = estimate_offset(ca, cb, a, b, line_time_s=LINE_S)
    assert abs(res.offset_s["b"] - OFFSET_S) <= 5 * res.uncertainty["offset_s"]["b"]


def test_a_line_time_run_to_its_bound_is_reported() -> None:
    # vertical motion seen by two cameras at the same height: both rows move alike, the row difference is
    # nearly constant, and this record's fit runs to the bound of its line-time interval
    traj = oscillation(3.0, 50.0, (0.0, 1.0, 0.0), centre_mm=(0.0, 0.0, 1500.0))
    ca, cb, a, b = _synthetic(traj, seed=0, height_b_mm=0.0)
    with pytest.raises(LineTimeNotObservableError, match="ran to the bound") as info:
        estimate_offset(ca, cb, a, b)
    assert info.value.at_bound
    bound_s = 0.4 * (1 / FS_HZ) / np.ptp(np.r_[a[1][:, 1], b[1][:, 1]])  # the fit's interval: ±0.4 frame
    assert abs(info.value.estimate_s) == pytest.approx(bound_s, rel=0.01)


def test_an_observable_line_time_is_estimated_without_complaint() -> None:
    # a marker on a tilted circle moves across rows differently in the two cameras: the line time shows
    traj, _, _ = rotor(frequency_hz=6.0, radius_mm=80.0)
    ca, cb, a, b = _synthetic(traj, seed=3)
    res = estimate_offset(ca, cb, a, b)
    u = res.uncertainty["line_time_s"]["b"]
    assert u < (1 / FS_HZ) / 1080
    assert abs(res.line_time_s["b"] - LINE_S) <= 5 * u
    assert abs(res.offset_s["b"] - OFFSET_S) <= 5 * res.uncertainty["offset_s"]["b"]


def _frames(t: np.ndarray, uv: np.ndarray) -> pd.DataFrame:
    return pd.DataFrame({"frame_index": np.arange(len(t)), "timestamp_s": t, "u_px": uv[:, 0],
                         "v_px": uv[:, 1]})


def test_an_unobservable_line_time_with_a_prior_widens_the_offset_uncertainty_to_cover_it() -> None:
    ca, cb, a, b = _synthetic(_along_rows(), seed=0)
    prior = (0.0, (1 / FS_HZ) / 1080)  # 0 … frame period / image height
    res = estimate_offset(ca, cb, a, b, line_time_prior_s=prior)
    info = res.details["line_time"]
    assert not info["observable"] and "not observable" in info["statement"]
    assert res.line_time_s["b"] == pytest.approx(0.5 * prior[1])
    assert res.uncertainty["line_time_s"]["b"] == pytest.approx(prior[1] / np.sqrt(12))
    # the offset moves by −(row of B − row of A) per unit of line time …
    row_diff = float(np.mean(b[1][:, 1] - a[1][:, 1]))
    assert abs(info["offset_per_line_time_s_per_s"] + row_diff) <= 0.05 * abs(row_diff) + 0.05
    # … so its uncertainty holds the whole trade-off, and the truth (12 µs, inside the prior) is covered
    u = res.uncertainty["offset_s"]["b"]
    assert u >= abs(row_diff) * prior[1] / np.sqrt(12) * 0.95
    assert abs(res.offset_s["b"] - OFFSET_S) <= 3 * u
    # the stated bound: the line time anywhere in its range, half the range times the slope
    bound = info["offset_bound_from_line_time_s"]
    assert bound == pytest.approx(abs(info["offset_per_line_time_s_per_s"]) * prior[1] / 2)
    assert f"at most ± {bound * 1e3:.4f} ms" in info["statement"]
    assert abs(res.offset_s["b"] - OFFSET_S) <= bound + 4 * info["offset_uncertainty_statistical_s"]


def _frames(t: np.ndarray, uv: np.ndarray) -> pd.DataFrame:
    return pd.DataFrame({"frame_index": np.arange(len(t)), "timestamp_s": t, "u_px": uv[:, 0],
                         "v_px": uv[:, 1]})


def test_video_timing_states_an_unobservable_line_time_and_its_share_of_the_offset_uncertainty() -> None:
    ca, cb, a, b = _synthetic(_along_rows(), seed=0)
    cams = {"left": DLTCamera(P=ca.P), "right": DLTCamera(P=cb.P)}
    res = estimate_video_timing({"left": _frames(*a), "right": _frames(*b)}, cams,
                                {"left": FS_HZ, "right": FS_HZ}, reference="left")
    note = res.details["line_time_note"]
    assert "not observable" in note and "--line-time-s" in note
    line_max = (1 / FS_HZ) / 1080
    assert res.line_time_s["right"] == pytest.approx(0.5 * line_max)
    assert abs(res.offset_s["right"] - OFFSET_S) <= 3 * res.uncertainty["offset_s"]["right"]
