"""The paper's rotating-marker delay on the twin: faithful (incl. its rolling-shutter bias) and its errors."""

from __future__ import annotations

import numpy as np
import pytest
from timing_twin import twin_record

from rig.stereo.errors import (
    InputArrayError,
    NonMonotonicTimestampsError,
    NotRotatingError,
    TooFewSamplesError,
)
from rig.stereo.timing import estimate_offset
from rig.stereo.timing_rotor import rotor_angles

SIGMA_PX = 0.1
CENTRE_MM = (420.0, 0.0, 300.0)  # the twin's rotor (drivers/sim/targets.py RotorTarget defaults)
AXIS = (1.0, 0.0, 0.0)


def _record(hz: float, **kw):
    return twin_record(
        "rotor", "rotor", sigma_px=SIGMA_PX, setup=lambda w: w.rotor.set_frequency(0.0, hz), **kw
    )


def _paper(rec, **kw):
    guess = rec.truth_offset_s(float(np.mean(rec.t_right))) + 0.003
    return estimate_offset(
        rec.P_left,
        rec.P_right,
        (rec.t_left, rec.uv_left),
        (rec.t_right, rec.uv_right),
        method="rotor",
        rotor_centre_mm=CENTRE_MM,
        rotor_axis=AXIS,
        offset_guess_s=guess,
        names=("left", "right"),
        **kw,
    )


def test_paper_method_measures_the_frame_delay_including_its_rolling_shutter_bias():
    rec = _record(10.0)
    res = _paper(rec)
    # What the method measures without noise: for each A frame and its closest B frame, the delay between
    # the instants the marker was actually exposed (rows differ), minus the time-stamp difference — averaged.
    j = np.searchsorted(rec.t_right + res.offset_s["right"], rec.t_left)
    j = np.clip(j, 1, rec.t_right.size - 1)
    j -= np.abs(rec.t_right[j - 1] + res.offset_s["right"] - rec.t_left) < np.abs(
        rec.t_right[j] + res.offset_s["right"] - rec.t_left
    )
    exposed = rec.left_clock_of_world(rec.true_right[j]) - rec.left_clock_of_world(rec.true_left)
    expected = float(np.mean(exposed - (rec.t_right[j] - rec.t_left)))
    # Angle noise σ_θ ≈ σ_px/(radius·scale) per frame, delay noise σ_θ/ω; 5σ over n pairs, plus the
    # ripple's incomplete averaging (deterministic, bounded by its spread / √n).
    n = res.details["n_pairs"]
    tol = 5 * res.details["delay_spread_s"] / np.sqrt(n)
    assert res.offset_s["right"] == pytest.approx(expected, abs=tol)
    # Its error against the row-0 offset is the rolling-shutter bias ℓ·mean(v_B − v_A) the paper ignores.
    truth = rec.truth_offset_s(res.epoch_s["right"])
    bias = rec.right.line_time_s * float(np.mean(rec.uv_right[j, 1] - rec.uv_left[:, 1]))
    assert res.offset_s["right"] - truth == pytest.approx(bias, abs=tol + 5e-6)
    assert res.details["rotation_hz"] == pytest.approx(10.0, abs=1e-3)
    assert res.details["radius_mm"]["left"] == pytest.approx(60.0, abs=0.1)
    assert res.method == "rotor"


def test_a_rotor_that_does_not_turn_raises_not_rotating():
    with pytest.raises(NotRotatingError, match=r"circle|revolution"):
        _paper(_record(0.0, duration_s=3.0))
    with pytest.raises(NotRotatingError, match="revolution"):
        _paper(_record(0.1, duration_s=3.0))  # 0.3 revolutions: no steady rate to speak of


def test_a_rotor_too_fast_for_the_frame_rate_raises():
    with pytest.raises(NotRotatingError, match="too fast"):
        _paper(_record(27.0, duration_s=2.0))


def test_bad_inputs():
    rec = _record(10.0, duration_s=2.0)
    with pytest.raises(TooFewSamplesError):
        estimate_offset(
            rec.P_left,
            rec.P_right,
            (rec.t_left[:5], rec.uv_left[:5]),
            (rec.t_right, rec.uv_right),
            method="rotor",
            rotor_centre_mm=CENTRE_MM,
            rotor_axis=AXIS,
        )
    back = rec.t_left.copy()
    back[30] = back[29] - 0.001
    with pytest.raises(NonMonotonicTimestampsError):
        estimate_offset(
            rec.P_left,
            rec.P_right,
            (back, rec.uv_left),
            (rec.t_right, rec.uv_right),
            method="rotor",
            rotor_centre_mm=CENTRE_MM,
            rotor_axis=AXIS,
        )
    with pytest.raises(InputArrayError, match="axis"):
        estimate_offset(
            rec.P_left,
            rec.P_right,
            (rec.t_left, rec.uv_left),
            (rec.t_right, rec.uv_right),
            method="rotor",
            rotor_centre_mm=CENTRE_MM,
            rotor_axis=(0.0, 0.0, 0.0),
        )


def test_angles_unwrap_over_many_turns():
    rec = _record(10.0, duration_s=2.0)
    theta, radius, _ = rotor_angles(rec.P_left, rec.uv_left, np.array(CENTRE_MM), np.array(AXIS), "left")
    assert abs(theta[-1] - theta[0]) / (2 * np.pi) == pytest.approx(
        10.0 * (rec.t_left[-1] - rec.t_left[0]), rel=1e-2
    )
    assert radius == pytest.approx(60.0, abs=0.1)


def test_row_corrected_phase_method_measures_the_line_time_from_the_ripple():
    # every pair's delay is δ + ℓ·(v_B − v_A): the once-per-revolution ripple the paper ignores gives ℓ
    rec = _record(10.0)
    res = _paper(rec, estimate_line_time=True)
    truth = rec.truth_offset_s(res.epoch_s["right"])
    u_off, u_line = res.uncertainty["offset_s"]["right"], res.uncertainty["line_time_s"]["right"]
    assert u_line < 0.1 * rec.right.line_time_s  # observable: the rows of the two views differ along the turn
    assert abs(res.line_time_s["right"] - rec.right.line_time_s) <= 5 * u_line
    assert abs(res.offset_s["right"] - truth) <= 5 * u_off
    assert abs(res.drift_ppm["right"] - rec.truth_drift_ppm()) <= 5 * res.uncertainty["drift_ppm"]["right"]
