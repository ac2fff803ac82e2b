"""Known-truth observations from the twin (drivers/sim) for the timing, trajectory and spectrum tests.

The default stereo pair of the simulated rig (its clock errors, start offsets, time-stamp origins and line
times), with lens distortion switched off so that the cameras are exactly their 3×4 matrices K[R|t]
(calibration is not under test here). ``SimCamera.truth_observations`` gives exact centres at exact row
times; Gaussian pixel noise of ``sigma_px`` is added here.

Truth of the timing model of :mod:`rig.stereo.timing` (reference = left camera, times on its clock):
world time w = s + (τ − o)/(1 + p·1e-6) + v·ℓ + e/2 per camera (start offset s, time-stamp origin o,
clock error p, line time ℓ, exposure e). Expressed on the left camera's clock, a right-camera observation
is at o_L + (w − s_L − e_L/2)(1 + p_L·1e-6), which the model writes as τ + offset + drift·(τ − epoch) + v·ℓ.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from analysis_twin import projection

from drivers.sim.stereo_rig import default_camera_specs, make_camera
from drivers.sim.world import World


@dataclass
class TwinRecord:
    P_left: np.ndarray
    P_right: np.ndarray
    left: object  # SimCamera
    right: object
    t_left: np.ndarray  # camera time stamps (left clock)
    uv_left: np.ndarray
    true_left: np.ndarray  # world time of each observation
    t_right: np.ndarray
    uv_right: np.ndarray
    true_right: np.ndarray
    world: World
    marker_id: str

    def truth_offset_s(self, epoch_s: float) -> float:
        """offset_s of the right camera (at row 0, time stamp ``epoch_s``) on the left camera's clock."""
        return float(self.right_on_left_clock(np.array([epoch_s]), np.array([0.0]))[0] - epoch_s)

    def truth_drift_ppm(self) -> float:
        pl, pr = self.left.clock_ppm * 1e-6, self.right.clock_ppm * 1e-6
        return ((1 + pl) / (1 + pr) - 1) * 1e6

    def right_on_left_clock(self, tau_right: np.ndarray, v_px: np.ndarray) -> np.ndarray:
        L, R = self.left, self.right
        w = (
            R.start_offset_s
            + (tau_right - R.timestamp_origin_s) / (1 + R.clock_ppm * 1e-6)
            + v_px * R.line_time_s
            + 0.5 * R.exposure_s
        )
        return L.timestamp_origin_s + (w - L.start_offset_s - 0.5 * L.exposure_s) * (1 + L.clock_ppm * 1e-6)

    def left_clock_of_world(self, w: np.ndarray) -> np.ndarray:
        L = self.left
        return L.timestamp_origin_s + (w - L.start_offset_s - 0.5 * L.exposure_s) * (1 + L.clock_ppm * 1e-6)


def offset_floor_s(rec: TwinRecord, sigma_px: float, *, line_time: bool = True, drift: bool = True) -> float:
    """Standard deviation of the offset from white pixel noise alone (Cramér–Rao), with the line time and
    drift free as in the joint fit. r is the Sampson distance of each left observation to the right camera's
    track; ∂r/∂δ = g comes from the exact motion at the left camera's instants; the line time shifts the
    pair by (v_B − v_A) and the drift by (τ_B − epoch), so their columns are g·Δv and g·Δτ·1e-6."""
    from rig.stereo.epipolar import fundamental_from_projections
    from rig.stereo.timing_joint import sampson_px

    F = fundamental_from_projections(rec.P_left, rec.P_right)
    h = 1e-5

    def proj(P, X):
        x = np.column_stack([X, np.ones(len(X))]) @ P.T
        return x[:, :2] / x[:, 2:3]

    X0 = rec.world.positions([rec.marker_id], rec.true_left)[0]
    X1 = rec.world.positions([rec.marker_id], rec.true_left + h)[0]
    uv_a = proj(rec.P_left, X0)
    uv_b = proj(rec.P_right, X0)
    g = (sampson_px(F, uv_a, proj(rec.P_right, X1)) - sampson_px(F, uv_a, uv_b)) / h
    cols = [g]
    if line_time:
        cols.append(g * (uv_b[:, 1] - uv_a[:, 1]))
    if drift:
        cols.append(g * (rec.t_left - rec.t_left.mean()) * 1e-6)
    J = np.column_stack(cols)
    return float(sigma_px * np.sqrt(np.linalg.inv(J.T @ J)[0, 0]))


def twin_record(
    scene: str,
    marker_id: str,
    *,
    duration_s: float = 10.0,
    sigma_px: float = 0.1,
    seed: int = 0,
    right_start_offset_s: float | None = None,
    right_overrides: dict | None = None,
    setup=None,
    lens_distortion: bool = False,
) -> TwinRecord:
    """Observations of ``marker_id`` in ``scene`` from t = 1 s for ``duration_s``; ``setup(world)`` sets
    the bodies in motion (e.g. ``world.rotor.set_frequency(0.0, 10.0)``). ``lens_distortion=True`` keeps the
    default pair's lens distortion: ``uv`` are then the observed (distorted) centres."""
    world = World(seed=seed)
    world.set_scene(scene, 0.0)
    if setup is not None:
        setup(world)
    left_spec, right_spec = default_camera_specs()
    zero = (0.0, 0.0, 0.0, 0.0)
    lens = {} if lens_distortion else {"distortion": zero}
    left = make_camera(left_spec, world, **lens)
    extra = {} if right_start_offset_s is None else {"start_offset_s": right_start_offset_s}
    extra.update(right_overrides or {})
    right = make_camera(right_spec, world, **lens, **extra)
    rng = np.random.default_rng(seed + 1000)
    out = []
    for cam in (left, right):
        df = cam.truth_observations(1.0, 1.0 + duration_s, [marker_id])
        uv = df[["u_px", "v_px"]].to_numpy(float)
        uv = uv + rng.normal(0.0, sigma_px, uv.shape) if sigma_px > 0 else uv
        out += [df["timestamp_s"].to_numpy(float), uv, df["t_true_s"].to_numpy(float)]
    return TwinRecord(projection(left), projection(right), left, right, *out, world, marker_id)
