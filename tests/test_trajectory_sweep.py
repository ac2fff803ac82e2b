"""Sliding chirped-sinusoid trajectories follow a twin sweep through one camera's Nyquist limit (30 Hz)."""

from __future__ import annotations

import numpy as np
import pytest
from timing_twin import twin_record

from rig.stereo.errors import InputArrayError, TooFewSamplesError
from rig.stereo.trajectory_sweep import sliding_sine_trajectory

SIGMA_PX = 0.1
CRANK_MM = 4.0
WINDOW_S = 0.5


def _scale_px_per_mm(P, X, d):
    x = P @ np.append(X, 1.0)
    J = (P[:2, :3] - np.outer(x[:2] / x[2], P[2, :3])) / x[2]
    return float(np.linalg.norm(J @ d))


def test_sweep_from_22_to_38_hz_is_tracked_in_frequency_and_amplitude():
    rec = twin_record(
        "sweep_column",
        "col2",
        sigma_px=SIGMA_PX,
        duration_s=4.0,
        setup=lambda w: w.exciter.sweep(1.0, 22.0, 38.0, 4.0),
    )
    t_l = rec.left_clock_of_world(rec.true_left)
    t_r = rec.left_clock_of_world(rec.true_right)
    sw = sliding_sine_trajectory(
        [rec.P_left, rec.P_right], [t_l, t_r], [rec.uv_left, rec.uv_right], window_s=WINDOW_S, step_s=0.5
    )
    L = rec.left
    world_mid = (
        (sw.time_s - L.timestamp_origin_s) / (1 + L.clock_ppm * 1e-6) + L.start_offset_s + 0.5 * L.exposure_s
    )
    f_true = rec.world.exciter.frequency_hz(world_mid)
    # Per-window noise floors from the pixel noise (white, both cameras, n observations per window):
    X = rec.world.positions([rec.marker_id], rec.true_left[:1])[0, 0]
    d = np.array([0.0, 0.0, 1.0])
    s2 = np.mean([_scale_px_per_mm(P, X, d) ** 2 for P in (rec.P_left, rec.P_right)])
    n = sw.n_observations
    amp_floor = SIGMA_PX * np.sqrt(2.0 / (n * s2))
    f_floor = np.sqrt(24) * SIGMA_PX / (2 * np.pi * CRANK_MM * np.sqrt(s2) * WINDOW_S * np.sqrt(n))
    assert sw.frequency_hz.min() < 30.0 < sw.frequency_hz.max()  # crosses one camera's Nyquist limit
    assert np.all(np.abs(sw.frequency_hz - f_true) <= 5 * f_floor)
    assert np.all(np.abs(sw.amplitude - CRANK_MM) <= 5 * amp_floor)
    np.testing.assert_allclose(sw.rate_hz_s, 4.0, atol=0.3)
    assert np.all(np.abs(sw.direction @ d) > 0.999)


def test_bad_windows():
    rec = twin_record(
        "sweep_column",
        "col2",
        sigma_px=SIGMA_PX,
        duration_s=1.0,
        setup=lambda w: w.exciter.set_frequency(0.0, 10.0),
    )
    args = ([rec.P_left, rec.P_right], [rec.true_left, rec.true_right], [rec.uv_left, rec.uv_right])
    with pytest.raises(TooFewSamplesError, match="overlap"):
        sliding_sine_trajectory(*args, window_s=2.0, step_s=0.5)
    with pytest.raises(InputArrayError, match="positive"):
        sliding_sine_trajectory(*args, window_s=0.5, step_s=0.0)
