"""Known-truth observations of the twin for the analysis tests (no rendering: SimCamera.truth_observations).

The default stereo pair of the simulated rig (clock errors, start offsets, time-stamp origins, line times),
with lens distortion kept or switched off. Truth of the timing model of :mod:`rig.stereo.timing`
(reference = left camera, times on its clock): a camera with start offset s, time-stamp origin o, clock
error p (ppm), line time ℓ and exposure e exposes row v of the frame stamped τ at world time
w = s + (τ − o)/(1 + p·1e-6) + v·ℓ + e/2; on the left camera's clock that is
t = o_L + (w − s_L − e_L/2)(1 + p_L·1e-6), which is exactly τ + offset + drift·(τ − epoch) + v·line_time
with the values of :func:`true_timing`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from drivers.sim.stereo_rig import default_camera_specs, make_camera
from drivers.sim.world import World
from rig.stereo.dlt import DLTCamera
from rig.stereo.timing import TimingResult


def projection(cam) -> np.ndarray:
    """The 3×4 matrix K[R|t] (mm → px) of a :class:`drivers.sim.camera.SimCamera`."""
    return cam.camera_matrix @ np.column_stack([cam.rotation, cam.tvec])


def true_camera(cam) -> DLTCamera:
    d = tuple(float(v) for v in cam.distortion)
    return DLTCamera(projection(cam), (cam.width_px, cam.height_px), distortion=d if any(d) else None,
                     convention="external")


def true_timing(left, right) -> TimingResult:
    pl, pr = left.clock_ppm * 1e-6, right.clock_ppm * 1e-6
    epoch = right.timestamp_origin_s
    t_epoch = left.timestamp_origin_s + (1 + pl) * (
        right.start_offset_s - left.start_offset_s + 0.5 * (right.exposure_s - left.exposure_s))
    return TimingResult(
        reference_camera=left.name,
        offset_s={left.name: 0.0, right.name: t_epoch - epoch},
        line_time_s={left.name: left.line_time_s * (1 + pl), right.name: right.line_time_s * (1 + pl)},
        drift_ppm={left.name: 0.0, right.name: ((1 + pl) / (1 + pr) - 1) * 1e6},
        method="truth",
        epoch_s={left.name: 0.0, right.name: epoch},
    )


@dataclass
class Twin:
    world: World
    left: object
    right: object
    observations: dict[str, pd.DataFrame]
    cameras: dict[str, DLTCamera]
    timing: TimingResult
    sigma_px: float
    extra: dict = field(default_factory=dict)

    def world_time(self, t_ref_s: np.ndarray) -> np.ndarray:
        """World (controller) time of instants on the left (reference) camera's clock."""
        L = self.left
        return L.start_offset_s + 0.5 * L.exposure_s + (np.asarray(t_ref_s) - L.timestamp_origin_s) / (
            1 + L.clock_ppm * 1e-6)


def twin(
    scene: str,
    *,
    setup=None,
    t_start_s: float = 1.0,
    t_stop_s: float = 3.0,
    sigma_px: float = 0.1,
    seed: int = 0,
    marker_ids: list[str] | None = None,
    distortion: bool = False,
    segment: str = "seg",
    left_overrides: dict | None = None,
    right_overrides: dict | None = None,
) -> Twin:
    """Noisy observations (Gaussian, ``sigma_px`` per coordinate) of ``scene`` between two world times."""
    world = World(seed=seed)
    world.set_scene(scene, 0.0)
    if setup is not None:
        setup(world)
    ls, rs = default_camera_specs()
    zero = {} if distortion else {"distortion": (0.0, 0.0, 0.0, 0.0)}
    left = make_camera(ls, world, **{**zero, **(left_overrides or {})})
    right = make_camera(rs, world, **{**zero, **(right_overrides or {})})
    rng = np.random.default_rng(seed + 17)
    obs = {}
    for cam in (left, right):
        df = cam.truth_observations(t_start_s, t_stop_s, marker_ids)
        if sigma_px > 0:
            df["u_px"] = df["u_px"] + rng.normal(0.0, sigma_px, len(df))
            df["v_px"] = df["v_px"] + rng.normal(0.0, sigma_px, len(df))
        df["segment"] = segment
        obs[cam.name] = df.reset_index(drop=True)
    return Twin(world, left, right, obs, {c.name: true_camera(c) for c in (left, right)},
                true_timing(left, right), sigma_px)


def write_run(runs_dir, tw: Twin, segments: list[tuple[str, float, float]], *, rig: dict | None = None,
              calibration: bool = True, timing: bool = True, camera_events: bool = True,
              blind: tuple[tuple[str, str], ...] = (), event_style: str = "acquire",
              resume_before: str | None = None):
    """A run folder written by the real record writer: per recording (name, t_start_s, t_stop_s) — consecutive
    recordings of one name in one step, like the accuracy procedure's poses — ``camera`` start events and
    the twin's noisy observations; ``calibration.json`` / ``timing.json`` from the true cameras and timing;
    ``blind`` (segment, camera) pairs record nothing. ``event_style``:
    "acquire" writes the events after the recording with ``t_s`` = start time and ``segment`` in the data
    (as rig/run/acquire.py does); "contract" writes them at the start with the contract's fields only.
    ``resume_before``: the session stops (abort) before that recording and a resumed session records the
    rest. Returns the run folder."""
    import json

    from rig.record.writer import RunRecord

    world = tw.world
    world.clock.advance_to(0.0)
    snapshot = rig if rig is not None else {"cameras": {"left": {"fps": 60.0}, "right": {"fps": 60.0}}}
    rec = RunRecord.create(runs_dir, "twin", {}, snapshot, world.clock, versions={})
    rng = np.random.default_rng(99)
    for k, (name, t0, t1) in enumerate(segments):
        world.clock.advance_to(t0)
        if name == resume_before and (k == 0 or segments[k - 1][0] != name):
            rec.stop("abort", "test: interrupted")
            rec.close()
            rec = RunRecord.resume(rec.run_dir, world.clock, rig_snapshot=snapshot, versions={})
        if k == 0 or segments[k - 1][0] != name:  # consecutive recordings of one name share a step
            rec.step_begin(name)
        starts = []
        for cam in (tw.left, tw.right):
            first = cam.first_frame_index_at_or_after(t0)
            start = {"camera": cam.name, "action": "start", "first_index": first,
                     "first_timestamp_s": cam.frame_timestamp_s(first)}
            if camera_events and event_style == "contract":
                rec.event("camera", start)
            starts.append(start)
            df = cam.truth_observations(t0, t1, None)
            if (name, cam.name) in blind:
                df = df.iloc[:0]
            if tw.sigma_px > 0:
                df["u_px"] = df["u_px"] + rng.normal(0.0, tw.sigma_px, len(df))
                df["v_px"] = df["v_px"] + rng.normal(0.0, tw.sigma_px, len(df))
            writer = rec.observation_writer(cam.name)
            if len(df):
                writer.append(df[["frame_index", "timestamp_s", "u_px", "v_px"]])
            writer.close()
        world.clock.advance_to(t1)
        if camera_events and event_style == "acquire":
            for start in starts:
                rec.event("camera", {**start, "segment": name, "t_s": t0})
        if k + 1 == len(segments) or segments[k + 1][0] != name:
            rec.step_done(name)
    rec.stop("success")
    rec.close()
    run_dir = rec.run_dir
    if calibration:
        cal = {"cameras": {n: c.to_dict() for n, c in tw.cameras.items()}, "convention": "external"}
        (run_dir / "calibration.json").write_text(json.dumps(cal))
    if timing:
        (run_dir / "timing.json").write_text(json.dumps(tw.timing.to_dict()))
    return run_dir
