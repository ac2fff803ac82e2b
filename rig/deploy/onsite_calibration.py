"""On-site calibration from a video pair of the calibration plate held still at known positions.

``rig calibrate LEFT RIGHT --target target.toml --out calibration.json`` (the paper's slid plate, on site):

1. each video is reduced to marker detections, every frame searched whole (:mod:`rig.deploy.video_markers`);
2. **still segments**: a run of frames is still while every marker of each frame lies within ``still_px``
   of its mean position over the run so far (a slide along the optical axis moves the image slowly: the
   drift accumulates against the run's mean, however slow it is, so no frame lag is needed), and a still
   segment is a still run of ≥ ``min_still_frames`` frames — the plate must be held exactly that long.
   The segments are matched **in order** to the positions of ``target.toml``; another number of
   segments is a :class:`OnsiteCalibrationError` that lists the segments found and the longest shorter
   still runs;
3. per segment each marker's image position is averaged over the segment's frames; the plate's markers are
   told from fixed markers (those stay put between positions) and identified on the plate's grid by
   :mod:`rig.deploy.plate_grid` (an unidentifiable grid is a clear error naming the camera and position);
4. one DLT per camera (:func:`rig.stereo.calibrate_dlt`, refined, radial distortion ``k1`` by default)
   with its residuals → ``calibration.json`` (contracts.md layout plus the segments found); a reprojection
   RMS above ``max_rms_px`` means the identification or the coordinates are wrong and is an error.

``target.toml``::

    [plate]
    rows = 5            # grid rows (row 0 on top as the cameras see the plate)
    cols = 7            # grid columns (column 0 on the left)
    [[positions]]       # one table per still position, in the order they were filmed
    markers_mm = [[x, y, z], ...]   # rows × cols points, node r·cols + c, in mm

Units: px, mm, s (the videos' own clocks).
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from rig.deploy.choices import DISTORTION_MODELS
from rig.deploy.plate_grid import GridError, moving_points, order_grid
from rig.deploy.video_markers import ExtractOptions, associate, extract_video
from rig.record.atomic import write_json
from rig.record.out_guard import check_out_file
from rig.stereo import calibrate_dlt
from rig.stereo.errors import StereoError

__all__ = ["DISTORTION_MODELS", "OnsiteCalibrationError", "PlateTarget", "calibrate_from_videos",
           "load_target", "still_segments"]


class OnsiteCalibrationError(ValueError):
    """The videos or the target file cannot give a calibration (the message says what to change)."""


@dataclass(frozen=True)
class PlateTarget:
    """The plate's grid and the known marker coordinates (mm) of every still position, in filming order."""

    rows: int
    cols: int
    positions_mm: tuple[np.ndarray, ...]  # each (rows·cols, 3)


def load_target(path: str | Path) -> PlateTarget:
    """Read ``target.toml`` (layout in the module docstring); errors name the field and what is allowed."""
    path = Path(path)
    if not path.is_file():
        raise OnsiteCalibrationError(f"{path}: no such target file (layout: `rig calibrate --help`)")
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise OnsiteCalibrationError(f"{path}: not valid TOML: {exc}") from exc
    plate = doc.get("plate")
    if not isinstance(plate, dict):
        raise OnsiteCalibrationError(f"{path}: [plate] missing; allowed: rows = int ≥ 2, cols = int ≥ 2")
    rows, cols = _grid_size(path, plate, "rows"), _grid_size(path, plate, "cols")
    positions = doc.get("positions")
    if not isinstance(positions, list) or len(positions) < 2:
        count = len(positions) if isinstance(positions, list) else 0
        raise OnsiteCalibrationError(f"{path}: [[positions]] has {count} entries; allowed: at least 2 "
                                     "plate positions (control points must not be coplanar)")
    out = []
    for i, pos in enumerate(positions):
        pts = pos.get("markers_mm") if isinstance(pos, dict) else None
        try:
            arr = np.asarray(pts, dtype=float)
        except (TypeError, ValueError):
            arr = np.zeros((0,))
        if arr.shape != (rows * cols, 3) or not np.all(np.isfinite(arr)):
            raise OnsiteCalibrationError(
                f"{path}: positions[{i}].markers_mm has shape {arr.shape}; allowed: {rows * cols} finite "
                f"[x, y, z] points in mm (rows × cols = {rows} × {cols}, node r·cols + c)")
        out.append(arr)
    _check_in_depth(path, np.concatenate(out))
    return PlateTarget(rows=rows, cols=cols, positions_mm=tuple(out))


def _grid_size(path: Path, plate: dict[str, object], key: str) -> int:
    """``plate.rows`` / ``plate.cols`` of a target file: an integer ≥ 2."""
    value = plate.get(key)
    if not isinstance(value, int) or isinstance(value, bool) or value < 2:
        raise OnsiteCalibrationError(f"{path}: plate.{key} = {value!r}; allowed: an integer ≥ 2")
    return value


def _check_in_depth(path: Path, xyz_mm: np.ndarray) -> None:
    """A DLT needs control points that span 3-D: refuse points that are (nearly) coplanar or collinear."""
    centred = xyz_mm - xyz_mm.mean(axis=0)
    spread_mm = np.linalg.svd(centred, compute_uv=False) / math.sqrt(len(xyz_mm))  # RMS extent per axis
    if spread_mm[2] <= 1e-3 * spread_mm[0]:
        raise OnsiteCalibrationError(
            f"{path}: the control points of all positions lie in one plane (RMS {spread_mm[2]:.3g} mm out of "
            f"it, against {spread_mm[0]:.3g} mm across); a DLT needs points in depth: slide the plate along "
            "its normal between positions and give each position's own markers_mm")


def _per_frame(obs: pd.DataFrame) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    obs = obs[~obs["duplicate"].to_numpy(bool)] if "duplicate" in obs.columns else obs
    frames, starts = np.unique(obs["frame_index"].to_numpy(), return_index=True)
    uv = obs[["u_px", "v_px"]].to_numpy(float)
    stamps = obs["timestamp_s"].to_numpy(float)[starts]
    ends = np.r_[starts[1:], len(obs)] if len(starts) else starts
    return frames, stamps, [uv[a:b] for a, b in zip(starts, ends, strict=True)]


def _motion_px(a: np.ndarray, b: np.ndarray, gate_px: float) -> float:
    """Largest displacement of a marker between two frames (inf if the markers do not correspond)."""
    if len(a) == 0 or len(a) != len(b):
        return math.inf
    idx = associate(a, b, gate_px)
    if np.any(idx < 0):
        return math.inf
    return float(np.max(np.linalg.norm(b - a[idx], axis=1)))


def _still_run(uv: list[np.ndarray], first: int, still_px: float, gate_px: float) -> int:
    """Last frame of the still run starting at ``first``: each later frame's markers (the same number,
    each within ``gate_px``) stay within ``still_px`` of their running mean over the run."""
    ref = uv[first]
    if len(ref) == 0:
        return first
    total, count, last = ref.copy(), 1, first
    for j in range(first + 1, len(uv)):
        if len(uv[j]) != len(ref):
            break
        idx = associate(total / count, uv[j], gate_px)
        if np.any(idx < 0):
            break
        moved = np.zeros(len(ref))
        moved[idx] = np.linalg.norm(uv[j] - total[idx] / count, axis=1)
        if moved.max() > still_px:
            break
        total[idx] += uv[j]
        count, last = count + 1, j
    return last


def still_segments(obs: pd.DataFrame, *, still_px: float = 0.3, min_still_frames: int = 20,
                   short_runs: list[int] | None = None) -> list[dict[str, Any]]:
    """Still segments of one camera's detections (see the module docstring): list of
    ``{"first_index", "last_index", "t_start_s", "t_stop_s", "frames": [frame indices]}`` in time order.
    ``short_runs``: if given, receives the length (frames) of the longest still run between two segments
    (and before the first / after the last) that was shorter than ``min_still_frames``."""
    if not (still_px > 0 and min_still_frames >= 2):
        raise OnsiteCalibrationError(f"still_px={still_px!r} (> 0), min_still_frames={min_still_frames!r} "
                                     "(≥ 2)")
    frames, stamps, uv = _per_frame(obs)
    gate = max(10.0 * still_px, 5.0)
    segments, i, longest_short = [], 0, 0
    while i < len(frames):
        j = _still_run(uv, i, still_px, gate)
        if j - i + 1 < min_still_frames:
            longest_short = max(longest_short, j - i + 1 if len(uv[i]) and j > i else 0)
            i += 1
            continue
        if short_runs is not None and longest_short:
            short_runs.append(longest_short)
        longest_short = 0
        segments.append({"first_index": int(frames[i]), "last_index": int(frames[j]),
                         "t_start_s": float(stamps[i]), "t_stop_s": float(stamps[j]),
                         "frames": frames[i:j + 1].tolist()})
        i = j + 1
    if short_runs is not None and longest_short:
        short_runs.append(longest_short)
    return segments


def _mean_positions(obs: pd.DataFrame, segment: dict[str, Any], gate_px: float = 2.0) -> np.ndarray:
    """Mean (u, v) of every marker seen in ≥ 80 % of the segment's frames."""
    sel = obs[obs["frame_index"].isin(segment["frames"])]
    _, _, per = _per_frame(sel)
    ref = per[0]
    sums, counts = np.zeros_like(ref), np.zeros(len(ref))
    for uv in per:
        idx = associate(ref, uv, gate_px)
        ok = idx >= 0
        np.add.at(sums, idx[ok], uv[ok])
        np.add.at(counts, idx[ok], 1)
    keep = counts >= 0.8 * len(per)
    return sums[keep] / counts[keep, None]


def _describe(segments: list[dict[str, Any]]) -> str:
    return ", ".join(f"{s['t_start_s']:.2f}–{s['t_stop_s']:.2f} s" for s in segments) or "none"


def calibrate_from_videos(videos: dict[str, str | Path], target: PlateTarget | str | Path, *,
                          distortion: str = "k1", refine: bool = True, still_px: float = 0.3,
                          min_still_frames: int = 20,
                          detect: dict[str, Any] | None = None, max_rms_px: float = 2.0) -> dict[str, Any]:
    """The ``calibration.json`` content from one video per camera (name → path) of the slid plate.

    ``max_rms_px``: largest reprojection RMS accepted (px); above it the grid identification or the target
    coordinates are wrong (a consistent but transposed or mirrored assignment still fits a homography)."""
    if distortion not in DISTORTION_MODELS:
        raise OnsiteCalibrationError(f"distortion={distortion!r}; allowed: {sorted(DISTORTION_MODELS)}")
    if len(videos) < 2:
        raise OnsiteCalibrationError(f"{len(videos)} video(s) given; a stereo calibration needs 2")
    tgt = target if isinstance(target, PlateTarget) else load_target(target)
    opts = ExtractOptions(mode="detect", detect=dict(detect or {}))
    cameras, details, sizes = {}, {}, {}
    for name, path in videos.items():
        vo = extract_video(path, name, opts)
        if vo.error:
            raise OnsiteCalibrationError(f"camera {name!r} ({path}): {vo.report.error or vo.error}; a "
                                         "calibration needs the whole video: copy or export it again")
        if vo.observations.empty:
            raise OnsiteCalibrationError(
                f"camera {name!r} ({path}): no marker found in any of its {vo.report.frames_read} frames; "
                "film the plate with its markers in view, in focus and well exposed")
        sizes[name] = (vo.width_px, vo.height_px)
        short: list[int] = []
        segs = still_segments(vo.observations, still_px=still_px, min_still_frames=min_still_frames,
                              short_runs=short)
        if len(segs) != len(tgt.positions_mm):
            found = (f"; the longest shorter still runs last {short} frame(s) (--min-still-frames, or hold "
                     "longer)" if short else "")
            raise OnsiteCalibrationError(
                f"camera {name!r} ({path}): found {len(segs)} still segment(s) ({_describe(segs)}) but "
                f"target lists {len(tgt.positions_mm)} positions; hold the plate still (every marker "
                f"within --still-px {still_px:g} px of its mean) ≥ {min_still_frames} frames "
                f"(--min-still-frames) at each listed position{found}")
        means = [_mean_positions(vo.observations, s) for s in segs]
        moving = moving_points(means)
        xyz, uv, grid_rms = [], [], []
        for i, (pts, idx) in enumerate(zip(means, moving, strict=True)):
            try:
                fit = order_grid(pts[idx], tgt.rows, tgt.cols)
            except GridError as exc:
                raise OnsiteCalibrationError(f"camera {name!r}, position {i} ({_describe([segs[i]])}): "
                                             f"plate grid not identified: {exc}") from exc
            xyz.append(tgt.positions_mm[i])
            uv.append(fit.uv_px)
            grid_rms.append(fit.residual_rms_px)
        try:
            cam = calibrate_dlt(np.concatenate(xyz), np.concatenate(uv), refine=refine,
                                distortion=DISTORTION_MODELS[distortion], image_size=sizes[name])
        except StereoError as exc:
            raise OnsiteCalibrationError(f"camera {name!r}: DLT failed: {exc}") from exc
        if not cam.rms_px <= max_rms_px:
            raise OnsiteCalibrationError(
                f"camera {name!r}: the control points do not fit a camera (reprojection RMS "
                f"{cam.rms_px:.2f} px > {max_rms_px:g} px): the plate's grid (rows × cols = {tgt.rows} × "
                f"{tgt.cols}, row 0 on top) or the target coordinates do not match the filmed plate")
        cameras[name] = cam.to_dict()
        details[name] = {"video": str(path), "segments": [{k: v for k, v in s.items() if k != "frames"}
                                                          for s in segs],
                         "grid_residual_rms_px": grid_rms, "frames": vo.report.to_dict()}
    first = next(iter(cameras.values()))
    return {"cameras": cameras, "convention": first["convention"], "units": {"world": "mm", "image": "px"},
            "method": {"command": "rig calibrate", "refine": refine, "distortion": distortion,
                       "still_px": still_px, "min_still_frames": min_still_frames,
                       "plate": {"rows": tgt.rows, "cols": tgt.cols}, "positions": len(tgt.positions_mm)},
            "videos": details}


def residual_summary(calibration: dict[str, Any]) -> str:
    """One line per camera: control points, reprojection RMS and max (px)."""
    return "\n".join(f"  {n}: {c['n_points']} points, reprojection RMS {c['residuals_rms_px']:.3f} px, "
                     f"max {c['residuals_max_px']:.3f} px" for n, c in calibration["cameras"].items())


def write_calibration(calibration: dict[str, Any], out: str | Path, *, force: bool = False) -> Path:
    """Write ``calibration.json`` atomically (parent folders created); never into a run folder, and over
    an existing file only with ``force`` (:func:`rig.record.out_guard.check_out_file`)."""
    out = Path(out)
    check_out_file(out, force=force)
    out.parent.mkdir(parents=True, exist_ok=True)
    return write_json(out, calibration)
