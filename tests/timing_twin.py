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

    def truth_offset_s(self, epoch_s: float) -> float:
        """offset_s of the right camera (at row 0, time stamp ``epoch_s``) on the left camera's clock."""
        return float(self.right_on_left_clock(np.array([epoch_s]), np.array([0.0]))[0] - epoch_s)

    def truth_drift_ppm(self) -> float:
        pl, pr = self.left.clock_ppm * 1e-6, self.right.clock_ppm * 1e-6
        return ((1 + pl) / (1 + pr) - 1) * 1e6

    def right_on_left_clock(self, tau_right: np.ndarray, v_px: np.ndarray) -> np.ndarray:
        L, R = self.left, self.right
        w = (R.start_offset_s + (tau_right - R.timestamp_origin_s) / (1 + R.clock_ppm * 1e-6)
             + v_px * R.line_time_s + 0.5 * R.exposure_s)
        return L.timestamp_origin_s + (w - L.start_offset_s - 0.5 * L.exposure_s) * (1 + L.clock_ppm * 1e-6)

    def left_clock_of_world(self, w: np.ndarray) -> np.ndarray:
        L = self.left
        return L.timestamp_origin_s + (w - L.start_offset_s - 0.5 * L.exposure_s) * (1 + L.clock_ppm * 1e-6)


def projection(cam) -> np.ndarray:
    return cam.camera_matrix @ np.column_stack([cam.rotation, cam.tvec])


def twin_record(
    scene: str,
    marker_id: str,
    *,
    duration_s: float = 10.0,
    sigma_px: float = 0.1,
    seed: int = 0,
    right_start_offset_s: float | None = None,
    setup=None,
) -> TwinRecord:
    """Observations of ``marker_id`` in ``scene`` from t = 1 s for ``duration_s``; ``setup(world)`` sets
    the bodies in motion (e.g. ``world.rotor.set_frequency(0.0, 10.0)``)."""
    world = World(seed=seed)
    world.set_scene(scene, 0.0)
    if setup is not None:
        setup(world)
    left_spec, right_spec = default_camera_specs()
    zero = (0.0, 0.0, 0.0, 0.0)
    left = make_camera(left_spec, world, distortion=zero)
    extra = {} if right_start_offset_s is None else {"start_offset_s": right_start_offset_s}
    right = make_camera(right_spec, world, distortion=zero, **extra)
    rng = np.random.default_rng(seed + 1000)
    out = []
    for cam in (left, right):
        df = cam.truth_observations(1.0, 1.0 + duration_s, [marker_id])
        uv = df[["u_px", "v_px"]].to_numpy(float)
        uv = uv + rng.normal(0.0, sigma_px, uv.shape) if sigma_px > 0 else uv
        out += [df["timestamp_s"].to_numpy(float), uv, df["t_true_s"].to_numpy(float)]
    return TwinRecord(projection(left), projection(right), left, right, *out)
