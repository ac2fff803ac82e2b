"""The simulated rolling-shutter camera: projection, rolling-shutter kinematics, exposure blur, clock.

Rendered marker centres are measured with a plain intensity centroid written here (the stereo core is
not imported: the twin must be checked independently). Tolerances come from the injected noise.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.sim.camera import SimCamera, look_at
from drivers.sim.render import NoiseModel
from drivers.sim.stereo_rig import default_stereo_pair
from drivers.sim.targets import SingleMarker, SweepColumn, TargetSet
from drivers.sim.world import World, WorldLayout

NOISELESS = NoiseModel(read_noise_dn=0.0, shot_noise_dn2_per_dn=0.0)
DIST = (-0.09, 0.07, 0.0011, -0.0007)


def _rodrigues(rvec: np.ndarray) -> np.ndarray:
    theta = float(np.linalg.norm(rvec))
    k = rvec / theta
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(theta) * kx + (1 - math.cos(theta)) * kx @ kx


def _pinhole_distorted(cam: SimCamera, xyz: np.ndarray) -> np.ndarray:
    """Independent projection: pinhole, then Brown–Conrady k1, k2, p1, p2, then the camera matrix."""
    pc = xyz @ _rodrigues(cam.rvec).T + cam.tvec
    x, y = pc[:, 0] / pc[:, 2], pc[:, 1] / pc[:, 2]
    k1, k2, p1, p2 = cam.distortion
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    k = cam.camera_matrix
    return np.column_stack([k[0, 0] * xd + k[0, 2], k[1, 1] * yd + k[1, 2]])


def _centroid(img: np.ndarray, uv: np.ndarray, radius_px: int, background_dn: float) -> tuple[float, float]:
    u0, v0 = (round(float(x)) for x in uv)
    win = img[v0 - radius_px : v0 + radius_px + 1, u0 - radius_px : u0 + radius_px + 1].astype(float)
    win -= background_dn
    yy, xx = np.mgrid[v0 - radius_px : v0 + radius_px + 1, u0 - radius_px : u0 + radius_px + 1]
    s = win.sum()
    return float((xx * win).sum() / s), float((yy * win).sum() / s)


def _centroid_sigma_px(noise: NoiseModel, radius_px: int, marker_radius_px: float) -> float:
    """1-σ noise of the centroid above: Σ (x − u)² σ_i² / S² over the window (per axis)."""
    yy, xx = np.mgrid[-radius_px : radius_px + 1, -radius_px : radius_px + 1]
    inside = xx**2 + yy**2 <= marker_radius_px**2
    level = np.where(inside, noise.marker_level_dn, noise.background_level_dn)
    var = noise.read_noise_dn**2 + noise.shot_noise_dn2_per_dn * level + 1 / 12  # + quantisation
    signal = inside.sum() * (noise.marker_level_dn - noise.background_level_dn)
    return float(math.sqrt((xx**2 * var).sum()) / signal)


def test_projection_matches_an_independent_pinhole_and_distortion_formula() -> None:
    world = World()
    left, right = default_stereo_pair(world, distortion=DIST)
    for cam in (left, right):
        obs = cam.truth_observations(0.0, 0.05)
        xyz = np.array([world.markers(t, [m])[m] for t, m in zip(obs.t_true_s, obs.marker_id, strict=True)])
        np.testing.assert_allclose(obs[["u_px", "v_px"]].to_numpy(), _pinhole_distorted(cam, xyz), atol=1e-8)
        assert set(obs.marker_id) == set(world.marker_ids)  # all 39 markers in view


def test_rendered_static_centres_agree_with_the_projection_within_noise() -> None:
    world = World(seed=7)
    noise = NoiseModel()
    cam = default_stereo_pair(world, distortion=DIST, noise=noise)[0]
    obs = cam.truth_observations(0.0, 0.02)
    img = cam.render(int(obs.frame_index.iloc[0]))
    radius = 14
    marker_r = 6.0 * cam.camera_matrix[0, 0] / 1500.0
    sigma = _centroid_sigma_px(noise, radius, marker_r)
    # perspective: the image of a disc is an ellipse whose centre is off the projected 3-D centre by at most
    # ≈ f·r²·tanθ/Z² (θ: viewing angle off the disc normal) — bound it for the rig (θ < 25°, Z > 1400 mm)
    bias = cam.camera_matrix[0, 0] * 8.0**2 * math.tan(math.radians(25)) / 1400.0**2
    for _, o in obs[obs.frame_index == obs.frame_index.iloc[0]].iterrows():
        bg = noise.background_level_dn
        u, v = _centroid(img, np.array([o.u_px, o.v_px]), radius, bg)
        assert abs(u - o.u_px) < 5 * sigma + bias + 0.01, (o.marker_id, u - o.u_px, sigma)
        assert abs(v - o.v_px) < 5 * sigma + bias + 0.01, (o.marker_id, v - o.v_px, sigma)


def _moving_marker_world(velocity_mm_s: tuple[float, float, float]) -> tuple[World, float]:
    """The single marker on the flange cruising at a constant velocity through the home pose at t = 1 s."""
    world = World(layout=WorldLayout(initial_scene="single_marker",
                                     targets=TargetSet(single_marker=SingleMarker(marker_diameter_mm=16.0))))
    v = np.array(velocity_mm_s)
    speed = float(np.linalg.norm(v))
    accel = 1e7  # reaches cruise in 0.1 ms
    home = np.array([350.0, 0.0, 300.0, 90.0, 0.0, 90.0])
    start, end = home.copy(), home.copy()
    start[:3] -= v * 1.0
    end[:3] += v * 1.0
    world.robot.move(-10.0, start, 1000.0, 5000.0)
    world.robot.move(0.0, end, speed, accel)
    return world, speed / accel / 2  # cruise lags the nominal timing by half the acceleration time


@pytest.mark.parametrize("line_time_s", [0.9 / 60 / 1080, 0.0])
def test_rolling_shutter_kinematics_of_a_vertically_moving_marker(line_time_s: float) -> None:
    world, lag_s = _moving_marker_world((0.0, 0.0, 600.0))  # 600 mm/s upwards ≈ 1000 px/s
    cam = SimCamera("c", world, rvec=look_at((1850.0, 0.0, 300.0), (380.0, 0.0, 300.0))[0],
                    tvec=look_at((1850.0, 0.0, 300.0), (380.0, 0.0, 300.0))[1], noise=NOISELESS,
                    psf_sigma_px=0.0, line_time_s=line_time_s)
    offset_px = []
    for i in range(cam.first_frame_index_at_or_after(0.8), cam.first_frame_index_at_or_after(1.2)):
        t0 = cam.frame_start_true_s(i)
        # the test's own row-time kinematics: z(t) = 300 + 600 (t − lag − 1) at the marker, solved for the row
        def v_at(t: float) -> float:
            p = np.array([[380.0, 0.0, 300.0 + 600.0 * (t - lag_s - 1.0)]])
            return float(_pinhole_distorted(cam, p)[0, 1])
        v = 540.0
        for _ in range(50):
            v = v_at(t0 + v * line_time_s + 0.5 * cam.exposure_s)
        u_exp = float(_pinhole_distorted(cam, np.array([[380.0, 0.0, 300.0]]))[0, 0])
        _, v_meas = _centroid(cam.render(i), np.array([u_exp, v]), 16, NOISELESS.background_level_dn)
        # no noise: the tolerance covers 8-bit rounding, the 4-sub-scanline vertical anti-aliasing (≤ 0.006 px
        # for this disc) and the perspective shift of the ellipse centre (≤ 0.006 px here)
        assert abs(v_meas - v) < 0.02, (i, v_meas - v)
        offset_px.append(v_at(t0 + 0.5 * cam.exposure_s) - v)  # where a global shutter would see it
    if line_time_s > 0:  # the rolling-shutter displacement is large compared to the tolerance
        assert min(abs(o) for o in offset_px) > 1.0
    else:
        assert max(abs(o) for o in offset_px) < 1e-9


def test_horizontal_motion_shears_the_disc_row_by_row() -> None:
    world, _ = _moving_marker_world((0.0, 1500.0, 0.0))
    lt = 0.9 / 60 / 1080
    eye, tgt = (1850.0, 0.0, 300.0), (380.0, 0.0, 300.0)
    cam = SimCamera("c", world, rvec=look_at(eye, tgt)[0], tvec=look_at(eye, tgt)[1], noise=NOISELESS,
                    psf_sigma_px=0.0)
    i = cam.first_frame_index_at_or_after(0.99)
    obs = cam.truth_observations(cam.frame_start_true_s(i) - 1e-9, cam.frame_start_true_s(i) + 0.02)
    u0, v0 = obs.u_px.iloc[0], obs.v_px.iloc[0]
    img = cam.render(i).astype(float) - NOISELESS.background_level_dn
    rows = np.arange(round(v0) - 6, round(v0) + 7)
    cols = np.arange(round(u0) - 20, round(u0) + 21)
    row_centres = [(img[r, cols] * cols).sum() / img[r, cols].sum() for r in rows]
    slope = np.polyfit(rows, row_centres, 1)[0]
    u_speed = (cam.project(np.array([[380.0, 1.0, 300.0]])) - cam.project(np.array([[380.0, 0.0, 300.0]])))
    expected = u_speed[0, 0] * 1500.0 * lt  # px per row
    assert slope == pytest.approx(expected, rel=0.05)
    assert abs(expected) > 0.03


def _fit_amplitude(t: np.ndarray, x: np.ndarray, f_hz: float) -> tuple[float, float]:
    a = np.column_stack([np.sin(2 * np.pi * f_hz * t), np.cos(2 * np.pi * f_hz * t), np.ones_like(t)])
    coef, *_ = np.linalg.lstsq(a, x, rcond=None)
    resid = x - a @ coef
    amp = float(np.hypot(coef[0], coef[1]))
    sigma_amp = float(np.sqrt(resid @ resid / (len(t) - 3)) * math.sqrt(2.0 / len(t)))
    return amp, sigma_amp


def _oscillation_amplitude_px(exposure_s: float, f_hz: float) -> tuple[float, float, float]:
    """Horizontal oscillation of a column marker: (rendered amplitude, its 1-σ, true projected amplitude)."""
    col = SweepColumn(axis=(0.0, 1.0, 0.0), count=1, marker_diameter_mm=12.0)
    world = World(seed=2, layout=WorldLayout(initial_scene="sweep_column", crank_radius_mm=4.0,
                                             targets=TargetSet(sweep_column=col)))
    world.exciter.set_frequency(0.0, f_hz)
    cam = default_stereo_pair(world, exposure_s=exposure_s)[0]
    obs = cam.truth_observations(0.0, 2.0, ["col0"])
    u_meas = np.array([_centroid(cam.render(int(i)), np.array([u, v]), 22, cam.noise.background_level_dn)[0]
                       for i, u, v in zip(obs.frame_index, obs.u_px, obs.v_px, strict=True)])
    amp, sigma = _fit_amplitude(obs.t_true_s.to_numpy(), u_meas, f_hz)
    true_amp, _ = _fit_amplitude(obs.t_true_s.to_numpy(), obs.u_px.to_numpy(), f_hz)
    return amp, sigma, true_amp


@pytest.mark.slow
def test_long_exposure_shrinks_the_amplitude_by_sinc_and_a_short_one_does_not() -> None:
    f_hz = 13.0
    for exposure_s in (1 / 60.5, 1 / 6000):
        amp, sigma, true_amp = _oscillation_amplitude_px(exposure_s, f_hz)
        x = math.pi * f_hz * exposure_s
        gain = math.sin(x) / x
        # tolerance: 5 σ of the fitted amplitude (from the fit residuals: pixel noise) + 0.2 % for the
        # projection's nonlinearity over ±6 px (same in both amplitudes, so it nearly cancels)
        tol = 5 * sigma / true_amp + 2e-3
        assert amp / true_amp == pytest.approx(gain, abs=tol), (exposure_s, amp, true_amp)
        if exposure_s > 0.01:
            assert 1 - gain > 10 * tol  # the blur is far above the tolerance


def test_time_stamps_follow_offset_and_ppm() -> None:
    world = World()
    cam = SimCamera("c", world, fps=59.94, clock_ppm=80.0, start_offset_s=0.7, timestamp_origin_s=100.0)
    idx = np.arange(0, 5000, 7)
    stamps = np.array([cam.frame_timestamp_s(int(i)) for i in idx])
    truth = np.array([cam.frame_start_true_s(int(i)) for i in idx])
    np.testing.assert_allclose(stamps, 100.0 + idx / 59.94, rtol=0, atol=1e-9)
    slope, intercept = np.polyfit(stamps - 100.0, truth, 1)
    assert slope == pytest.approx(1 / (1 + 80e-6), abs=1e-10)
    assert intercept == pytest.approx(0.7, abs=1e-9)
    row_time = cam.frame_start_true_s(3) + 540 * cam.line_time_s + cam.exposure_s / 2
    assert cam.row_time_true_s(3, 540) == pytest.approx(row_time, abs=1e-12)
    assert cam.frame_start_true_s(3) == pytest.approx(0.7 + 3 / (59.94 * (1 + 80e-6)), abs=1e-12)
    i = cam.first_frame_index_at_or_after(1.0)
    assert cam.frame_start_true_s(i) >= 1.0 > cam.frame_start_true_s(i - 1)


def test_dropped_and_duplicated_frames_appear_where_asked() -> None:
    world = World()
    cam = SimCamera("c", world, dropped_frames=(5, 9), duplicated_frames=(12,))
    sensor = [cam.sensor_frame(i) for i in range(14)]
    assert sensor == [0, 1, 2, 3, 4, 6, 7, 8, 10, 11, 12, 12, 13, 14]
    gaps = np.diff([cam.frame_timestamp_s(i) for i in range(14)]) * 60
    np.testing.assert_allclose(gaps, [1, 1, 1, 1, 2, 1, 1, 2, 1, 1, 0, 1, 1], atol=1e-9)
    np.testing.assert_array_equal(cam.render(10), cam.render(11))  # a duplicate is the same image
    assert not np.array_equal(cam.render(9), cam.render(10))


def test_random_drops_follow_the_probability() -> None:
    cam = SimCamera("c", World(), drop_probability=0.02, duplicate_probability=0.01, seed=4)
    n = 20_000
    sensor = np.array([cam.sensor_frame(i) for i in range(n)])
    steps = np.diff(sensor)
    p_drop, p_dup = (steps >= 2).mean(), (steps == 0).mean()
    assert p_drop == pytest.approx(0.02, abs=5 * math.sqrt(0.02 * 0.98 / n))
    assert p_dup == pytest.approx(0.01, abs=5 * math.sqrt(0.01 * 0.99 / n))


def test_random_drops_only_inside_the_drop_window() -> None:
    # frames start at 0.5 s + k / 60 s: the window [10, 20) s holds sensor frames 570 … 1169
    cam = SimCamera("c", World(), start_offset_s=0.5, drop_probability=0.2, drop_window_s=(10.0, 20.0),
                    seed=4)
    sensor = np.array([cam.sensor_frame(i) for i in range(2500)])
    lost = np.setdiff1d(np.arange(sensor.max()), sensor)
    assert lost.min() >= 570 and lost.max() <= 1169
    assert lost.size == pytest.approx(0.2 * 600, abs=5 * math.sqrt(0.2 * 0.8 * 600))
    with pytest.raises(ValueError, match="drop_window_s must be"):
        SimCamera("c", World(), drop_probability=0.2, drop_window_s=(20.0, 10.0))


def test_truth_observation_times_are_the_rows_exposure_midpoints() -> None:
    world = World()
    world.rotor.set_frequency(0.0, 10.0)
    world.set_scene("rotor", 0.0)
    cam = default_stereo_pair(world)[1]
    obs = cam.truth_observations(0.0, 0.5, ["rotor"])
    assert len(obs) == len(cam.frame_indices_between(0.0, 0.5)) >= 28
    for _, o in obs.iterrows():
        assert o.t_true_s == pytest.approx(cam.row_time_true_s(int(o.frame_index), o.v_px), abs=1e-12)
        uv = cam.project(world.positions(["rotor"], [o.t_true_s])[:, 0])[0]
        np.testing.assert_allclose(uv, [o.u_px, o.v_px], atol=1e-6)
        assert o.timestamp_s == cam.frame_timestamp_s(int(o.frame_index))


def test_rendering_is_deterministic_per_seed_and_noise_is_right() -> None:
    world = World(seed=11)
    a = default_stereo_pair(world)[0]
    b = default_stereo_pair(world)[0]
    np.testing.assert_array_equal(a.render(3), b.render(3))
    c = default_stereo_pair(world, seed=12)[0]
    assert not np.array_equal(a.render(3), c.render(3))
    img = a.render(3).astype(float)
    bg = img[900:1060, 1500:1900]  # no marker there
    noise = a.noise
    assert bg.mean() == pytest.approx(noise.background_level_dn, abs=0.05)
    bg_var = noise.read_noise_dn**2 + noise.shot_noise_dn2_per_dn * noise.background_level_dn
    expected_sd = math.sqrt(bg_var + 1 / 12)
    assert bg.std() == pytest.approx(expected_sd, rel=0.03)


def test_bad_camera_arguments_are_refused() -> None:
    world = World()
    with pytest.raises(ValueError, match="line_time_s"):
        SimCamera("c", world, line_time_s=1e-3)
    with pytest.raises(ValueError, match="exposure_s"):
        SimCamera("c", world, exposure_s=0.1)
    with pytest.raises(ValueError, match="distortion"):
        SimCamera("c", world, distortion=(0.1, 0.2))
    with pytest.raises(ValueError, match="frame_index"):
        SimCamera("c", world).render(-1)


@pytest.mark.parametrize(("fourcc", "suffix"), [("mp4v", ".mp4"), ("MJPG", ".avi")])
def test_write_video_round_trip(tmp_path, fourcc: str, suffix: str) -> None:
    import cv2
    world = World()
    cam = default_stereo_pair(world)[0]
    path = tmp_path / f"left{suffix}"
    n = cam.write_video(path, 0.0, 0.1, fourcc)
    # frames whose whole readout (row 0 start … last row's exposure end, 15.2 ms) lies in [0, 0.1] s
    assert n == len(cam.frame_indices_between(0.0, 0.1)) == 6
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY))
    cap.release()
    assert len(frames) == n
    diff = np.abs(frames[0].astype(float) - cam.render(0).astype(float))
    assert diff.mean() < 4.0  # lossy codecs, but the same picture


def test_a_disc_turned_away_from_the_camera_is_neither_drawn_nor_observed() -> None:
    world = World(layout=WorldLayout(initial_scene="single_marker"))
    cam = default_stereo_pair(world, noise=NOISELESS)[0]
    assert "arm" in set(cam.truth_observations(0.0, 0.05).marker_id)
    world.robot.move(0.0, (350.0, 0.0, 300.0, 90.0, 0.0, -90.0), 100.0, 500.0)  # flange turned by 180°
    t_end = world.robot.t_end_s()
    obs = cam.truth_observations(t_end, t_end + 0.05)
    assert "arm" not in set(obs.marker_id) and len(obs) > 0
    i = cam.frame_indices_between(t_end, t_end + 0.05)[0]
    uv = cam.project(world.positions(["arm"], [t_end])[:, 0])[0]
    u, v = (round(float(x)) for x in uv)
    assert cam.render(i)[v - 15 : v + 16, u - 15 : u + 16].max() == NOISELESS.background_level_dn


@pytest.mark.parametrize("tilt_deg", [0.0, 40.0, 60.0])
def test_a_tilted_disc_is_drawn_as_the_ellipse_perspective_predicts(tilt_deg: float) -> None:
    world = World(layout=WorldLayout(initial_scene="single_marker",
                                     targets=TargetSet(single_marker=SingleMarker(marker_diameter_mm=40.0))))
    world.robot.move(0.0, (350.0, 0.0, 300.0, 90.0, 0.0, 90.0 + tilt_deg), 100.0, 500.0)  # turn about z
    eye, tgt = (1850.0, 0.0, 300.0), (380.0, 0.0, 300.0)
    cam = SimCamera("c", world, rvec=look_at(eye, tgt)[0], tvec=look_at(eye, tgt)[1], noise=NOISELESS,
                    psf_sigma_px=0.0)
    t = max(world.robot.t_end_s(), 0.0) + 0.1
    i = cam.first_frame_index_at_or_after(t)
    centre = world.positions(["arm"], [t])[:, 0]
    uv = cam.project(centre)[0]
    img = cam.render(i).astype(float) - NOISELESS.background_level_dn
    u0, v0 = (round(float(x)) for x in uv)
    win = img[v0 - 45 : v0 + 46, u0 - 45 : u0 + 46]
    yy, xx = np.mgrid[-45:46, -45:46].astype(float)
    s = win.sum()
    mu = np.array([(xx * win).sum(), (yy * win).sum()]) / s
    cov = np.array([[((xx - mu[0]) ** 2 * win).sum(), ((xx - mu[0]) * (yy - mu[1]) * win).sum()],
                    [((xx - mu[0]) * (yy - mu[1]) * win).sum(), ((yy - mu[1]) ** 2 * win).sum()]]) / s
    minor, major = np.sqrt(np.linalg.eigvalsh(cov))
    normal = world.marker_normal("arm", t)
    view = np.array(eye) - centre[0]
    cos_view = float(normal @ view / np.linalg.norm(view))
    # an ellipse of semi-axes a, b has second moments a²/4, b²/4: the axis ratio is the foreshortening
    # (1-px anti-aliased edge and 8-bit rounding: 1 % on this 65-px disc)
    assert minor / major == pytest.approx(cos_view, abs=0.01)
    # the area shrinks by the same factor
    r_px = 20.0 * cam.camera_matrix[0, 0] / np.linalg.norm(view)
    assert s / (NOISELESS.marker_level_dn - NOISELESS.background_level_dn) == pytest.approx(
        math.pi * r_px**2 * cos_view, rel=0.01)
