"""Continuous-time trajectories on all observations of both cameras (twin truth): beyond one camera's
Nyquist limit, amplitude at 25 Hz, frequency, and the B-spline model; where the alias cannot be separated."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from timing_synth import observe, oscillation, stereo_pair
from timing_twin import twin_record

from rig.stereo.errors import AmbiguousFrequencyError, InputArrayError, NonMonotonicTimestampsError
from rig.stereo.sinefit import fit_sine
from rig.stereo.trajectory import fit_sine_trajectory, fit_spline_trajectory

SIGMA_PX = 0.1
CRANK_MM = 4.0  # the twin's crank radius: the sweep column's displacement amplitude
AXIS = np.array([0.0, 0.0, 1.0])


def _column(f_hz: float, **kw):
    return twin_record(
        "sweep_column", "col2", sigma_px=SIGMA_PX, setup=lambda w: w.exciter.set_frequency(0.0, f_hz), **kw
    )


def _scale_px_per_mm(P, X, d):
    x = P @ np.append(X, 1.0)
    J = (P[:2, :3] - np.outer(x[:2] / x[2], P[2, :3])) / x[2]
    return float(np.linalg.norm(J @ d))


def _amplitude_floor_mm(rec):
    """σ of a fitted amplitude along the known axis: σ_px·√2 / √(Σ_c N_c·s_c²), s_c px per mm along it."""
    X = rec.world.positions([rec.marker_id], rec.true_left[:1])[0, 0]
    info = sum(
        n * _scale_px_per_mm(P, X, AXIS) ** 2
        for n, P in ((rec.t_left.size, rec.P_left), (rec.t_right.size, rec.P_right))
    )
    return SIGMA_PX * np.sqrt(2.0 / info)


def _fit(rec, **kw):
    return fit_sine_trajectory(
        [rec.P_left, rec.P_right], [rec.true_left, rec.true_right], [rec.uv_left, rec.uv_right], **kw
    )


def test_a_40_hz_oscillation_beyond_one_cameras_nyquist_limit_with_cameras_half_a_frame_apart():
    rec = _column(40.0, right_start_offset_s=0.5 / 60.0)
    traj, f_hz = _fit(rec)
    floor = _amplitude_floor_mm(rec)
    assert f_hz == pytest.approx(40.0, abs=0.005)
    assert abs(traj.amplitude - CRANK_MM) <= min(0.05 * CRANK_MM, 5 * floor)
    assert abs(abs(traj.direction @ AXIS) - 1.0) < 1e-3
    # Each camera alone sees the alias at 20 Hz: its own four-parameter fit returns the alias.
    alone = fit_sine(rec.t_left, rec.uv_left[:, 1])
    assert alone.frequency_hz == pytest.approx(20.0, abs=0.01)


def test_amplitude_at_25_hz_within_one_percent_with_the_trajectory_fit():
    rec = _column(25.0)
    traj, f_hz = _fit(rec)
    assert f_hz == pytest.approx(25.0, abs=0.005)
    assert abs(traj.amplitude - CRANK_MM) <= min(0.01 * CRANK_MM, 5 * _amplitude_floor_mm(rec))


@pytest.mark.parametrize("f_hz", [3.5, 10.0])
def test_frequency_within_5_millihertz_on_a_10_s_record(f_hz):
    rec = _column(f_hz)
    traj, f_est = _fit(rec)
    # Cramér–Rao floor of the frequency with the amplitude in pixels of both cameras (white noise).
    X = rec.world.positions([rec.marker_id], rec.true_left[:1])[0, 0]
    amp_px = CRANK_MM * np.sqrt(
        np.mean([_scale_px_per_mm(P, X, AXIS) ** 2 for P in (rec.P_left, rec.P_right)])
    )
    n = rec.t_left.size + rec.t_right.size
    duration = np.ptp(rec.true_left)
    floor = np.sqrt(24) * SIGMA_PX / (2 * np.pi * amp_px * duration * np.sqrt(n))
    assert abs(f_est - f_hz) <= min(0.005, 5 * floor)
    assert abs(traj.amplitude - CRANK_MM) <= 5 * _amplitude_floor_mm(rec)


def _synthetic_pair(alpha: float, f_hz: float = 40.0, n: int = 600):
    cam_a, cam_b = stereo_pair()
    traj = oscillation(f_hz, 2.0, (0.3, 1.0, 0.2))
    rng = np.random.default_rng(7)
    tau = np.arange(n) / 60.0
    _, ua, ta = observe(cam_a, traj, tau, sigma_px=SIGMA_PX, rng=rng)
    _, ub, tb = observe(cam_b, traj, tau, offset_s=alpha / 60.0, sigma_px=SIGMA_PX, rng=rng)
    return [cam_a, cam_b], [ta, tb], [ua, ub]


def test_offset_zero_cannot_separate_40_hz_from_its_20_hz_alias_but_a_known_frequency_still_works():
    cams, ts, uvs = _synthetic_pair(0.0)
    with pytest.raises(AmbiguousFrequencyError, match="alias"):
        fit_sine_trajectory(cams, ts, uvs)
    traj, _ = fit_sine_trajectory(cams, ts, uvs, frequency_hz=40.0)
    assert traj.amplitude == pytest.approx(2.0, rel=0.01)


def test_b_spline_trajectory_at_10_hz_tracks_the_motion_at_the_triangulation_noise():
    rec = _column(10.0)
    sp = fit_spline_trajectory(
        [rec.P_left, rec.P_right], [rec.true_left, rec.true_right], [rec.uv_left, rec.uv_right]
    )
    t = np.linspace(rec.true_left[30], rec.true_left[-30], 4000)
    X = sp.position(t)
    err = X - rec.world.positions([rec.marker_id], t)[0]
    # Per-axis noise of a synchronous two-view triangulation at the marker: σ_px·√diag((JᵀJ)⁻¹).
    X0 = rec.world.positions([rec.marker_id], t[:1])[0, 0]
    J = []
    for P in (rec.P_left, rec.P_right):
        x = P @ np.append(X0, 1.0)
        J.append((P[:2, :3] - np.outer(x[:2] / x[2], P[2, :3])) / x[2])
    J = np.vstack(J)
    sigma_xyz = SIGMA_PX * np.sqrt(np.diag(np.linalg.inv(J.T @ J)))
    assert np.all(np.sqrt(np.mean(err**2, axis=0)) <= 2.0 * sigma_xyz)
    assert fit_sine(t, X[:, 2], frequency_hz=10.0).amplitude == pytest.approx(CRANK_MM, rel=0.01)


def test_bad_inputs():
    cams, ts, uvs = _synthetic_pair(0.5, n=60)
    with pytest.raises(InputArrayError, match="one time array"):
        fit_sine_trajectory(cams, ts[:1], uvs)
    back = ts[0].copy()
    back[10] = back[8]
    with pytest.raises(NonMonotonicTimestampsError):
        fit_spline_trajectory(cams, [back, ts[1]], uvs)
    with pytest.raises(InputArrayError, match="shape"):
        fit_sine_trajectory(cams, ts, [uvs[0][:-1], uvs[1]])


def test_the_banded_normal_equations_give_the_sparse_designs_spline_to_rounding():
    """The spline fit sums its normal equations in band form (no sparse design); the assembled sparse design's
    Gauss–Newton steps give the same coefficients, on two cameras sampling a 7 Hz motion at interleaved
    instants, one with a gap."""
    from rig.stereo import trajectory as tr

    rng = np.random.default_rng(11)
    K = np.array([[1400.0, 0, 960], [0, 1400.0, 540], [0, 0, 1]])
    Ps = [K @ np.c_[np.eye(3), [0.0, 0.0, 600.0]],
          K @ np.c_[[[0.96, 0, -0.28], [0, 1, 0], [0.28, 0, 0.96]], [-150.0, 0.0, 620.0]]]
    ts = [np.arange(0.0, 2.0, 1 / 60), np.delete(np.arange(0.004, 2.0, 1 / 60), np.s_[40:52])]

    def position_mm(t):
        return np.c_[3 * np.sin(2 * np.pi * 7 * t), 2 * np.cos(2 * np.pi * 7 * t + 0.3), 0.5 * t]

    uvs = []
    for P, t in zip(Ps, ts, strict=True):
        x = np.c_[position_mm(t), np.ones(len(t))] @ P.T
        uvs.append(x[:, :2] / x[:, 2:] + rng.normal(0, 0.1, (len(t), 2)))
    basis = tr.SplineBasis(0.0, 2.0, 0.75 / 60)
    designs = [basis.design(t) for t in ts]
    rows = [tr._spline_rows(d) for d in designs]
    assert all(r is not None for r in rows) and 3 * basis.size > 4 * (tr._BAND + 1)
    banded = tr._fit_banded(Ps, rows, uvs, basis, iterations=8)
    general = tr._fit_general(Ps, ts, designs, uvs, basis, iterations=8)
    np.testing.assert_allclose(banded, general, rtol=0, atol=1e-9)
    assert np.array_equal(tr.fit_trajectory(Ps, ts, uvs, basis).coefficients, banded)  # the path taken


def _look_at(K: np.ndarray, centre_mm: np.ndarray) -> np.ndarray:
    """P = K [R | −R·c] of a camera at ``centre_mm`` looking at the origin (y of the world roughly down)."""
    z = -centre_mm / np.linalg.norm(centre_mm)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return K @ np.c_[R, -R @ centre_mm]


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), distance_mm=st.floats(400.0, 2000.0), angle_deg=st.floats(8.0, 70.0),
       focal_px=st.floats(800.0, 2500.0), offset_frames=st.floats(0.0, 1.0), n_frames=st.integers(30, 150),
       sigma_px=st.floats(0.0, 0.3))
def test_banded_spline_fit_matches_the_assembled_design_on_random_cameras(
        *, seed, distance_mm, angle_deg, focal_px, offset_frames, n_frames, sigma_px):
    """The banded normal equations (summed per observation from its basis values and G = Σ g gᵀ) against the
    reference that assembles the sparse design row by row (one row per pixel equation), on two random
    well-conditioned cameras (in front, 8–70° apart, 0.4–2 m away) filming a random 3-D motion at random
    interleaved instants. Both are Gauss–Newton on the same equations: they differ by the summation order
    (rounding, ε·cond ≈ 1e-15 relative here) and by at most one step below the stopping threshold
    1e-10·(1 + max|C|); allowed: 1e-9·(1 + max|C|) mm (a nanometre at a metre)."""
    from rig.stereo import trajectory as tr

    rng = np.random.default_rng(seed)
    half = np.radians(angle_deg) / 2
    Ps = []
    for sign in (-1.0, 1.0):
        K = np.array([[focal_px, 0, 960 + rng.uniform(-40, 40)], [0, focal_px, 540 + rng.uniform(-40, 40)],
                      [0, 0, 1]])
        centre = distance_mm * np.array([np.sin(sign * half), rng.uniform(-0.1, 0.1), -np.cos(half)])
        Ps.append(_look_at(K, centre))
    fs = 60.0
    ts = [np.arange(n_frames) / fs, (np.arange(n_frames) + offset_frames) / fs]
    amp = rng.uniform(0.5, 5.0, (3, 3))
    freq = rng.uniform(0.5, 20.0, 3)
    phase = rng.uniform(0, 2 * np.pi, (3, 3))

    def position_mm(t):
        return np.stack([np.sum(amp[k] * np.sin(2 * np.pi * freq * t[:, None] + phase[k]), axis=1)
                         for k in range(3)], axis=1)

    uvs = []
    for P, t in zip(Ps, ts, strict=True):
        x = np.c_[position_mm(t), np.ones(len(t))] @ P.T
        assert np.all(x[:, 2] > 0)
        uvs.append(x[:, :2] / x[:, 2:] + rng.normal(0, sigma_px, (len(t), 2)))
    basis = tr.SplineBasis(0.0, float(ts[1][-1]), 0.75 / fs)
    designs = [basis.design(t) for t in ts]
    rows = [tr._spline_rows(d) for d in designs]
    banded = tr._fit_banded(Ps, [r for r in rows if r is not None], uvs, basis, iterations=8)
    general = tr._fit_general(Ps, ts, designs, uvs, basis, iterations=8)
    np.testing.assert_allclose(banded, general, rtol=0, atol=1e-9 * (1 + np.max(np.abs(general))))


@pytest.mark.parametrize("n_frames", [2, 3, 5, 8, 12])
def test_a_short_track_takes_the_banded_spline_fit_and_agrees_with_the_assembled_design(monkeypatch,
                                                                                       n_frames: int):
    """A still marker seen for a few frames (a calibration plate position: ≈ 8 frames, 5–16 basis functions,
    fewer equations than unknowns without the penalty) takes the banded normal equations too — the sparse
    design's Gauss–Newton cost 25 ms a track, most of a report's analysis of a calibrate step — and gives the
    assembled design's coefficients to the hypothesis test's tolerance above."""
    from rig.stereo import trajectory as tr

    rng = np.random.default_rng(n_frames)
    K = np.array([[1400.0, 0, 960], [0, 1400.0, 540], [0, 0, 1]])
    Ps = [_look_at(K, np.array([-250.0, 20.0, -900.0])), _look_at(K, np.array([250.0, -20.0, -900.0]))]
    fs = 60.0
    ts = [np.arange(n_frames) / fs, (np.arange(n_frames) + 0.27) / fs]
    still_mm = np.array([12.0, -30.0, 5.0, 1.0])
    uvs = []
    for P, t in zip(Ps, ts, strict=True):
        x = np.tile(P @ still_mm, (len(t), 1))
        uvs.append(x[:, :2] / x[:, 2:] + rng.normal(0, 0.05, (len(t), 2)))
    basis = tr.SplineBasis(0.0, float(ts[1][-1]), 0.75 / fs)
    designs = [basis.design(t) for t in ts]
    general = tr._fit_general(Ps, ts, designs, uvs, basis, iterations=8)

    def not_the_general_path(*args, **kwargs):
        raise AssertionError("the sparse design's path was taken")

    monkeypatch.setattr(tr, "_fit_general", not_the_general_path)
    fitted = tr.fit_trajectory(Ps, ts, uvs, basis)
    atol_mm = 1e-9 * (1 + np.max(np.abs(general)))
    np.testing.assert_allclose(fitted.coefficients, general, rtol=0, atol=atol_mm)
    assert np.max(np.abs(fitted.position(ts[0]) - still_mm[:3])) < 0.5  # mm: the marker stood still
