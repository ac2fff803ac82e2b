"""Calibrate the cameras: the arm slides the calibration plate to known positions along its normal.

At each position (``targets.calibration_plate.start_pose`` moved by ``slide_positions_mm`` along tool z)
the arm stops, the cameras record ``frames_per_position`` still frames, and each marker's image position
is averaged over them. The plate's markers are told from the fixed reference markers (they move between
positions, the references do not) and ordered on the grid (:mod:`rig.deploy.plate_grid`); their base-frame
positions follow from the commanded pose and the plate geometry of the configuration. One DLT per camera
(:func:`rig.stereo.calibrate_dlt`; refined, with radial distortion ``k1`` by default — with a small plate
``k1`` extrapolates best over the measurement volume, docs/stereo_core.md) → ``calibration.json`` with the
residuals. A still recording in which a camera has fewer than half the frames with markers (frames dropped
by the camera or a loaded host: a skipped burst can swallow a whole 0.16-s recording) is recorded again at
the same pose, the n-th n times as long, up to :data:`STILL_ATTEMPTS` recordings (logged); the last one is
used. Truth events: ``arm``
per move and ``calibration_position`` per position.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from procedures._common import (
    arm_marker_positions,
    arm_step,
    fastest_fps,
    mount,
    plate_offsets_tool_mm,
    read_run_json,
    record_still,
    required,
    speed_from,
)
from procedures.params.calibrate import DESCRIPTION, NAME, Parameters  # noqa: F401 (its declaration)
from rig.config.rig_config import RigConfig
from rig.config.targets import CalibrationPlateTarget
from rig.deploy.choices import DISTORTION_MODELS
from rig.record.events import CalibrationPositionEvent
from rig.run.acquire import SETTLED_PX, Acquirer, ReduceOptions, mean_positions, settled_frames
from rig.run.plan import ArmMoves, Plan
from rig.run.procedure import Context, ParameterError

# pandas, the plate's grid (OpenCV, SciPy) and the DLT (SciPy) are imported where they are used: a dry run
# loads this module without them (tests/test_cli_start.py)
if TYPE_CHECKING:
    import pandas as pd

STILL_ATTEMPTS = 3  # still recordings tried per plate position while a camera has too few frames

class StillFramesError(RuntimeError):
    """A still recording of the plate holds too few frames to average (a fault of the acquisition: exit 3)."""


def plate_poses(plate: CalibrationPlateTarget, slides_mm: tuple[float, ...]) -> list[list[float]]:
    """Flange poses of the slid positions: ``start_pose`` moved by each slide along tool z (mm)."""
    start = np.asarray(plate.start_pose, dtype=float)
    z_tool = np.asarray(arm_marker_positions(start, {"z": [0.0, 0.0, 1.0]})["z"]) - start[:3]
    return [np.r_[start[:3] + s * z_tool, start[3:]].tolist() for s in slides_mm]


def _control_points(positions: list[dict[str, Any]], camera: str, plate: CalibrationPlateTarget,
                    min_frames: int) -> tuple[np.ndarray, np.ndarray, list[float]]:
    """(xyz_mm, uv_px, grid residual per position) of one camera over all positions; StillFramesError when
    a position has fewer than ``min_frames`` frames with markers — none at all too, when other positions have
    some (frames dropped: its markers' means would be dropped, the static references then look moved and
    the grid of another position is fitted to the wrong points, "found 39 plate markers")."""
    from rig.deploy.plate_grid import GridError, moving_points, order_grid

    counts = [int(pos["observations"][camera]["frame_index"].nunique()) for pos in positions]
    for i, (pos, n_frames) in enumerate(zip(positions, counts, strict=True)):
        if n_frames < min_frames and any(counts):  # (none anywhere: no marker in view: the grid error)
            raise StillFramesError(
                f"camera {camera!r}, plate position {i} (slide {pos['slide_mm']:g} mm): {n_frames} frames "
                f"with markers recorded, at least {min_frames} needed (calibrate.frames_per_position // 2): "
                "frames dropped by a loaded host, network or camera (see its stop event's n_frames), or "
                "markers lost in some frames; reduce the load or raise "
                "calibrate.frames_per_position")
    means = [mean_positions(p["observations"][camera], min_frames=min_frames) for p in positions]
    uv_sets = [m[["u_px", "v_px"]].to_numpy(float) for m in means]
    moving = moving_points(uv_sets)
    ids = [f"cal_r{r}c{c}" for r in range(plate.rows) for c in range(plate.cols)]
    xyz, uv, resid = [], [], []
    for i, (pts, idx, pos) in enumerate(zip(uv_sets, moving, positions, strict=True)):
        try:
            fit = order_grid(pts[idx], plate.rows, plate.cols)
        except GridError as exc:
            raise GridError(f"camera {camera!r}, plate position {i} (slide "
                            f"{pos['slide_mm']:g} mm): {exc}") from exc
        xyz.append(np.array([pos["points"][k] for k in ids]))
        uv.append(fit.uv_px)
        resid.append(fit.residual_rms_px)
    return np.concatenate(xyz), np.concatenate(uv), resid


def _settled(ctx: Context, position: int, observations: dict[str, pd.DataFrame]) -> dict[str, pd.DataFrame]:
    """Each camera's observations of a plate position from the frames in which the plate was at rest
    (:func:`settled_frames`); the frames left out are logged (the run record keeps them all)."""
    still = {name: settled_frames(obs) for name, obs in observations.items()}
    moved = {name: int(obs["frame_index"].nunique() - still[name]["frame_index"].nunique())
             for name, obs in observations.items()}
    if any(moved.values()):
        ctx.log.warning("calibrate: plate position %d: frames left out of the average, the plate not at rest "
                        "(a marker over %g px from its position in the last frames): %s", position,
                        SETTLED_PX, moved)
    return still


def slides_of(params: Parameters, plate: CalibrationPlateTarget) -> tuple[tuple[float, ...], str]:
    """The plate slides (mm along tool z) and what they come from (the parameter or the rig's)."""
    if params.slide_positions_mm:
        slides, source = tuple(params.slide_positions_mm), "calibrate.slide_positions_mm"
    else:
        slides, source = tuple(plate.slide_positions_mm), "targets.calibration_plate.slide_positions_mm"
    if len(set(slides)) < 2:
        raise ParameterError("calibrate.slide_positions_mm",
                             f"{list(slides)}: allowed: at least 2 distinct positions (the control points "
                             "must not be coplanar)")
    return slides, f"{source} = {[float(s) for s in slides]} mm"


def plan(params: Parameters, config: RigConfig) -> Plan:
    """The slid plate's flange poses and the arm speed (step ``calibrate``); nothing is connected."""
    plate = required(config.targets.calibration_plate, "targets.calibration_plate")
    slides, source = slides_of(params, plate)
    poses = tuple(tuple(p) for p in plate_poses(plate, slides))
    hold_s = params.settle_s + (params.frames_per_position + 1.5) / fastest_fps(config)
    moves = ArmMoves(poses, f"{source} from targets.calibration_plate.start_pose", params.speed_mm_s,
                     speed_from(NAME, params.speed_mm_s), hold_s)
    return Plan(NAME, (arm_step("calibrate", moves, config),))


def calibrate_cameras(ctx: Context, params: Parameters) -> dict[str, Any]:
    """Acquire the slid plate and fit every camera; return the ``calibration.json`` content."""
    from rig.stereo.dlt import calibrate_dlt

    plate = required(ctx.config.targets.calibration_plate, "targets.calibration_plate")
    arm = ctx.arm()
    slides, _ = slides_of(params, plate)
    poses = plan(params, ctx.config).moves("calibrate").poses
    mount(ctx, "calibration_plate")
    offsets = plate_offsets_tool_mm(plate)
    positions = []
    min_frames = max(1, params.frames_per_position // 2)
    with Acquirer(ctx, ReduceOptions(mode="track", window_px=31)) as acq:
        for i, pose in enumerate(poses):
            ctx.progress(i / len(poses), f"calibrate: plate position {i + 1}/{len(poses)}")
            rec = record_still(ctx, acq, arm, pose, "calibrate", frames=params.frames_per_position,
                               settle_s=params.settle_s, speed_mm_s=params.speed_mm_s)
            still = _settled(ctx, i, rec.observations)
            for attempt in range(2, STILL_ATTEMPTS + 1):
                seen = {n: int(o["frame_index"].nunique()) for n, o in still.items()}
                if min(seen.values(), default=0) >= min_frames:
                    break
                ctx.log.warning("calibrate: plate position %d: still frames with markers %s, fewer than %d "
                                "(frames dropped, or the plate not at rest); recording again (%d of %d)", i,
                                seen, min_frames, attempt, STILL_ATTEMPTS)
                rec = acq.record("calibrate",
                                 attempt * (params.frames_per_position + 1.5) / fastest_fps(ctx.config))
                still = _settled(ctx, i, rec.observations)
            points = arm_marker_positions(pose, offsets)
            ctx.event("calibration_position", CalibrationPositionEvent(
                index=i, t_start_s=rec.t_start_s, t_stop_s=rec.t_stop_s, pose=list(pose),
                slide_mm=slides[i], points=points))
            positions.append({"points": points, "observations": still, "slide_mm": slides[i]})
    cameras, grid = {}, {}
    for name in ctx.cameras:
        xyz, uv, resid = _control_points(positions, name, plate, min_frames)
        width_px, height_px = ctx.config.cameras[name].resolution_px
        cam = calibrate_dlt(xyz, uv, refine=params.refine, distortion=DISTORTION_MODELS[params.distortion],
                            image_size=(width_px, height_px))
        cameras[name] = cam.to_dict()
        grid[name] = resid
        ctx.log.info("camera %s: %d control points, reprojection RMS %.3f px", name, len(xyz), cam.rms_px)
    first = next(iter(cameras.values()))
    return {"cameras": cameras, "convention": first["convention"], "units": {"world": "mm", "image": "px"},
            "method": {"procedure": NAME, "refine": params.refine, "distortion": params.distortion,
                       "frames_per_position": params.frames_per_position,
                       "slide_positions_mm": list(slides),
                       "plate": {"rows": plate.rows, "cols": plate.cols, "pitch_mm": plate.pitch_mm}},
            "grid_residual_rms_px": grid}


def calibration_summary(calibration: dict[str, Any]) -> tuple[float, str]:
    """Worst reprojection RMS (px) over the cameras and a one-line summary."""
    rms = {n: float(c["residuals_rms_px"]) for n, c in calibration["cameras"].items()}
    text = ", ".join(f"{n} {v:.3f} px" for n, v in rms.items())
    return max(rms.values()), f"reprojection RMS {text}"


def run_step(ctx: Context, params: Parameters) -> dict[str, Any]:
    """The ``calibrate`` step (skipped on --resume when done); returns the calibration."""
    with ctx.step("calibrate") as step:
        if not step.skipped:
            step.output(ctx.write_json("calibration.json", calibrate_cameras(ctx, params)))
    calibration: dict[str, Any] = read_run_json(ctx, "calibration.json")
    return calibration


def run(ctx: Context, params: Parameters) -> dict[str, Any]:
    calibration = run_step(ctx, params)
    worst, summary = calibration_summary(calibration)
    limit = ctx.config.criteria.calibration_rms_px
    return {"passed": worst <= limit, "summary": f"{summary} (limit {limit:g} px)", "rms_px": worst}
