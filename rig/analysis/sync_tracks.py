"""Time-aligned triangulation of paired 2-D tracks, with the synchronization method as a parameter.

Every observation is first put on the reference camera's clock at its own exposure instant by the timing
model of :mod:`rig.stereo.timing` (:func:`row_corrected_times`: offset, drift and rolling-shutter line
time). The 3-D track is then given at the reference camera's instants by one of (``SYNC_METHODS``):

- ``linear`` — the paper's: each other camera's 2-D track linearly interpolated to the reference instants,
  then triangulated (amplitude gain |H(α)| < 1, metrology notes §5);
- ``cubic`` / ``bandlimited`` — the same with a cubic spline or a windowed-sinc reconstruction
  (:func:`rig.stereo.resample.resample`);
- ``trajectory`` — ours, the default: a cubic B-spline 3-D trajectory fitted to all observations of all
  cameras at their exact row-corrected instants (:func:`rig.stereo.trajectory.fit_spline_trajectory`,
  knots every ``knot_spacing_frames`` frame periods), evaluated at the reference instants. Nothing is
  interpolated in the images, so there is no |H(α)| loss (the spline's own amplitude bias at 60 fps:
  ≤ 0.4 % up to 22 Hz, ≈ 1.4 % at 28 Hz; ``benchmarks/analysis.py``).

Interpolation methods triangulate with reprojection-error refinement (observed, distorted pixels); the
trajectory is fitted in undistorted pixels. Instants outside the span of every partner track are left out
(never extrapolated). Units: s, px, mm.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd

from rig.analysis.disjoint_set import DisjointSet
from rig.analysis.errors import AnalysisError
from rig.analysis.pairing import pair_tracks
from rig.analysis.tracks2d import check_observations, segment_keys, tracks_2d
from rig.config.analysis import SYNC_METHODS
from rig.stereo.dlt import DLTCamera
from rig.stereo.errors import StereoError
from rig.stereo.resample import resample
from rig.stereo.timing import TimingResult
from rig.stereo.trajectory import fit_spline_trajectory
from rig.stereo.triangulate import as_camera, triangulate

#: Second-difference penalty of the trajectory spline (relative to the pixel-scaled equations). Smaller is
#: less amplitude bias and more noise; at 1e-4 (twin, 30 s sweep, σ = 0.1 px) the bias is ≤ 0.4 % up to
#: 22 Hz and ≈ 0.5 % at 26 Hz, and a still marker's noise is 2 % above that at 1e-3 (bias −1.8 % at 26 Hz).
TRAJECTORY_PENALTY = 1e-4
TRACK_COLUMNS = ["segment", "time_s", "track_id", "x_mm", "y_mm", "z_mm", "reprojection_px", "n_cameras"]
Columns = dict[str, np.ndarray]  # a part of the tracks: column name → values, one row per instant


def timing_result(timing: TimingResult | Mapping[str, Any]) -> TimingResult:
    """A :class:`TimingResult` from itself or from the ``timing.json`` dict."""
    if isinstance(timing, TimingResult):
        return timing
    if not isinstance(timing, Mapping):
        raise AnalysisError(
            f"timing must be a TimingResult or the timing.json dict, got {type(timing).__name__}")
    try:
        return TimingResult.from_dict(dict(timing))
    except StereoError as exc:
        raise AnalysisError(f"timing.json content is malformed: {exc}") from exc


def row_corrected_times(
    obs: pd.DataFrame, timing: TimingResult | Mapping[str, Any], camera: str
) -> np.ndarray:
    """Exposure instant (s, reference camera's clock) of each observation of ``camera``:
    τ + offset + drift·1e-6·(τ − epoch) + v·line_time, from ``timestamp_s`` (τ, camera clock) and ``v_px``."""
    check_observations(obs, ("timestamp_s", "v_px"), f"observations of camera {camera!r}")
    tr = timing_result(timing)
    if camera not in tr.offset_s:
        raise AnalysisError(
            f"camera {camera!r} has no entry in the timing (offset_s has {sorted(tr.offset_s)}); "
            "run the sync procedure (`rig run sync`) with this camera"
        )
    return tr.times(camera, obs["timestamp_s"].to_numpy(float), obs["v_px"].to_numpy(float))


def _check_sync(sync: str) -> None:
    if sync not in SYNC_METHODS:
        raise AnalysisError(f"sync={sync!r}: allowed are {SYNC_METHODS}")


def prepare_observations(obs: pd.DataFrame, timing: TimingResult | Mapping[str, Any], camera: str,
                         **track_options: Any) -> pd.DataFrame:
    """A copy of ``obs`` with ``time_s`` (row-corrected, reference clock) and ``track_id`` added if absent."""
    out = obs.copy()
    if "time_s" not in out.columns:
        out["time_s"] = row_corrected_times(out, timing, camera)
    if "track_id" not in out.columns:
        out["track_id"] = tracks_2d(out, **track_options).to_numpy()
    return out


def pair_all(observations: Mapping[str, pd.DataFrame], cameras: Mapping[str, object], reference: str,
             **pair_options: Any) -> tuple[pd.DataFrame, list[str]]:
    """Pair the reference camera's tracks with each other camera's, segment by segment.

    Returns (pairs, notes): pairs has ``segment``, ``camera`` (the other camera) and the columns of
    :data:`rig.analysis.pairing.PAIR_COLUMNS`; notes list ambiguous and unpaired tracks per segment.
    """
    frames, notes = [], []
    ref = observations[reference]
    for seg, ref_seg in _segments(ref):
        for cam in sorted(c for c in observations if c != reference):
            other = _select(observations[cam], seg)
            if other.empty or ref_seg.empty:
                continue
            res = pair_tracks(ref_seg, other, cameras[reference], cameras[cam], **pair_options)
            p = res.pairs.copy()
            p.insert(0, "camera", cam)
            p.insert(0, "segment", seg[0] if seg else "")
            frames.append(p)
            label = seg[0] if seg else "(all)"
            n_amb = int(p["ambiguous"].sum())
            if n_amb:
                notes.append(f"segment {label!r}: {n_amb} ambiguous pair(s) {reference}/{cam} not "
                             "triangulated (markers on a common epipolar plane)")
            if res.unpaired_a or res.unpaired_b:
                notes.append(f"segment {label!r}: unpaired tracks {reference}: {res.unpaired_a}, "
                             f"{cam}: {res.unpaired_b}")
    if not frames:
        cols = ["segment", "camera", "track_a", "track_b", "distance_px", "n_common", "ambiguous", "resolved"]
        return pd.DataFrame(columns=cols), notes
    return pd.concat(frames, ignore_index=True), notes


def _segments(obs: pd.DataFrame) -> list[tuple[tuple[Any, ...], pd.DataFrame]]:
    keys = segment_keys(obs)
    if not keys:
        return [((), obs)]
    groups = obs.groupby(keys, sort=True, dropna=False)
    return [((k,) if not isinstance(k, tuple) else k, g) for k, g in groups]


def _select(obs: pd.DataFrame, seg: tuple[Any, ...]) -> pd.DataFrame:
    keys = segment_keys(obs)
    mask = np.ones(len(obs), dtype=bool)
    for k, v in zip(keys, seg, strict=False):
        mask &= obs[k].to_numpy() == v
    return obs[mask]


def triangulate_tracks(
    observations: Mapping[str, pd.DataFrame],
    cameras: Mapping[str, object],
    timing: TimingResult | Mapping[str, Any],
    *,
    sync: str = "trajectory",
    reference: str | None = None,
    pairs: pd.DataFrame | None = None,
    knot_spacing_frames: float = 0.75,
    trajectory_penalty: float = TRAJECTORY_PENALTY,
    track_options: Mapping[str, Any] | None = None,
    pair_options: Mapping[str, Any] | None = None,
) -> pd.DataFrame:
    """3-D tracks (``TRACK_COLUMNS``, ``time_s`` on the reference camera's clock) from per-camera observations

    ``observations``: camera → observations frame (run-folder columns; ``time_s`` and ``track_id`` are
    computed when absent). ``cameras``: camera → :class:`DLTCamera` or 3×4 matrix. ``timing``: the
    :class:`TimingResult` or ``timing.json`` dict; ``reference`` defaults to its reference camera.
    ``pairs``: from :func:`pair_all`, or ``pair_tracks(...).pairs`` with two cameras (computed when None);
    ambiguous pairs are not triangulated.
    ``frame.attrs["notes"]`` lists what was skipped and why.
    """
    _check_sync(sync)
    tr = timing_result(timing)
    ref = reference or tr.reference_camera
    if ref not in observations or ref not in cameras:
        raise AnalysisError(f"reference camera {ref!r} needs observations and a calibration "
                            f"(have observations {sorted(observations)}, cameras {sorted(cameras)})")
    cams = {name: as_camera(c, i) for i, (name, c) in enumerate(cameras.items()) if name in observations}
    if len(cams) < 2:
        raise AnalysisError(
            f"triangulation needs ≥ 2 calibrated cameras with observations, have {sorted(cams)}")
    obs = {c: prepare_observations(observations[c], tr, c, **dict(track_options or {})) for c in cams}
    notes: list[str] = []
    if pairs is None:
        pairs, notes = pair_all(obs, cams, ref, **dict(pair_options or {}))
    if "camera" not in pairs.columns:
        others = [c for c in cams if c != ref]
        if len(others) != 1:
            raise AnalysisError(f"pairs need a 'camera' column with {len(cams)} cameras ({sorted(cams)})")
        pairs = pairs.assign(camera=others[0])
    missing = [c for c in ("track_a", "track_b") if c not in pairs.columns]
    if missing:
        raise AnalysisError(f"pairs lack column(s) {missing}; pass the pairs of pair_all or pair_tracks")
    usable = pairs[~pairs["ambiguous"].astype(bool)] if "ambiguous" in pairs.columns else pairs
    parts: list[Columns] = []
    labels: list[tuple[str, int]] = []  # (segment, component key) of each part
    arrays = {c: _track_arrays(o) for c, o in obs.items()}
    for key, (comp_seg, comp) in enumerate(_components(usable, obs[ref])):
        part, more = _triangulate_component(comp, arrays, cams, ref, sync=sync,
                                            knot_spacing_frames=knot_spacing_frames,
                                            penalty=trajectory_penalty)
        notes += more
        if part is not None and len(part["time_s"]):
            parts.append(part)
            labels.append((comp_seg, key))
    if parts:
        out = _frame(parts, labels).sort_values(["segment", "time_s"], kind="stable", ignore_index=True)
        out = _number_tracks(out)
    else:
        kinds = {"segment": "object", "track_id": "int64", "n_cameras": "int64"}
        out = pd.DataFrame({c: pd.Series(dtype=kinds.get(c, "float64")) for c in TRACK_COLUMNS})
    out = out[TRACK_COLUMNS]
    out.attrs["notes"] = notes
    return out


def _frame(parts: list[Columns], labels: list[tuple[str, int]]) -> pd.DataFrame:
    """One frame of the components' rows: segment, their columns, component (the temporary key)."""
    n = [len(p["time_s"]) for p in parts]
    columns: dict[str, np.ndarray] = {"segment": np.repeat(np.array([s for s, _ in labels], dtype=object), n)}
    columns.update({c: np.concatenate([p[c] for p in parts]) for c in parts[0]})
    columns["component"] = np.repeat(np.array([k for _, k in labels], dtype=np.int64), n)
    return pd.DataFrame(columns)


def _components(pairs: pd.DataFrame, ref_obs: pd.DataFrame) -> list[tuple[str, dict[str, set[int]]]]:
    """Connected components of the pair graph: (segment, {camera or "": track ids}) — "" = reference."""
    sets: DisjointSet[tuple[str, int]] = DisjointSet()
    for r in pairs.itertuples():
        sets.union(("", int(r.track_a)), (str(r.camera), int(r.track_b)))
    comps: dict[tuple[str, int], dict[str, set[int]]] = {}
    for node in sets.nodes():
        comps.setdefault(sets.find(node), {}).setdefault(node[0], set()).add(node[1])
    seg_of = {}
    if "segment" in ref_obs.columns:
        firsts = ref_obs.drop_duplicates("track_id")
        seg_of = dict(zip(firsts["track_id"].astype(int), firsts["segment"].astype(str), strict=True))
    out = []
    for comp in comps.values():
        a0 = min(comp.get("", {-1}))
        out.append((seg_of.get(a0, ""), comp))
    return out


def _track_arrays(obs: pd.DataFrame) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Track id → (time_s increasing, observed uv (N, 2)); repeated instants dropped; −1 rows left out."""
    sel = obs[obs["track_id"].to_numpy() >= 0].sort_values(["track_id", "time_s"], kind="stable")
    tid = sel["track_id"].to_numpy()
    t_all = sel["time_s"].to_numpy(float)
    uv_all = sel[["u_px", "v_px"]].to_numpy(float)
    cuts = np.flatnonzero(np.diff(tid)) + 1
    out: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    if tid.size == 0:
        return out
    for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, len(tid)], strict=True):
        t, uv = t_all[lo:hi], uv_all[lo:hi]
        keep = np.r_[True, np.diff(t) > 0]
        out[int(tid[lo])] = (t[keep], uv[keep])
    return out


def _track(arrays: dict[int, tuple[np.ndarray, np.ndarray]], ids: set[int]) -> list[tuple[np.ndarray, ...]]:
    """The (time_s, uv) arrays of ``ids`` in id order."""
    return [arrays[tid] for tid in sorted(ids) if tid in arrays]


def _triangulate_component(comp, arrays, cams, ref, *, sync, knot_spacing_frames, penalty):
    notes: list[str] = []
    others = [c for c in cams if c != ref and c in comp]
    parts = []
    for t_a, uv_a in _track(arrays[ref], comp.get("", set())):
        pieces = {c: _track(arrays[c], comp[c]) for c in others}
        try:
            if sync == "trajectory":
                part = _by_trajectory(t_a, uv_a, pieces, cams, ref=ref, others=others,
                                      knot_spacing_frames=knot_spacing_frames, penalty=penalty)
            else:
                part = _by_interpolation(t_a, uv_a, pieces, cams, ref=ref, others=others, sync=sync)
        except StereoError as exc:
            notes.append(f"a track of {ref} ({t_a[0]:.3f}…{t_a[-1]:.3f} s) not triangulated with "
                         f"sync={sync!r}: {exc}")
            continue
        if part is not None:
            parts.append(part)
    if not parts:
        return None, notes
    return {c: np.concatenate([p[c] for p in parts]) for c in parts[0]}, notes


def _by_interpolation(t_a, uv_a, pieces, cams, *, ref, others, sync):
    uvs = [uv_a]
    for c in others:
        acc = np.full_like(uv_a, np.nan)
        for t_b, uv_b in pieces[c]:
            if t_b.size < 2:
                continue
            # a piece too short for a cubic or sinc reconstruction (a few still frames) is joined linearly
            val = resample(t_b, uv_b, t_a, sync if t_b.size >= 4 else "linear")
            acc = np.where(np.isfinite(acc), acc, val)
        uvs.append(acc)
    seen = np.column_stack([np.isfinite(u).all(axis=1) for u in uvs[1:]]).any(axis=1)
    if not seen.any():
        return None
    tri = triangulate([cams[ref]] + [cams[c] for c in others], [u[seen] for u in uvs], refine=True)
    return {"time_s": t_a[seen], "x_mm": tri.xyz_mm[:, 0], "y_mm": tri.xyz_mm[:, 1], "z_mm": tri.xyz_mm[:, 2],
            "reprojection_px": tri.rms_px, "n_cameras": tri.n_views.astype(np.int64)}


def _ideal(cam: DLTCamera, t: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    u = cam.undistort_px(uv, strict=False)
    ok = np.isfinite(u).all(axis=1)
    return t[ok], u[ok]


def _by_trajectory(t_a, uv_a, pieces, cams, *, ref, others, knot_spacing_frames, penalty):
    period = float(np.median(np.diff(t_a))) if t_a.size > 1 else 1.0 / 60.0
    covered = np.zeros((t_a.size, len(others)), dtype=bool)
    data_t: dict[str, list[np.ndarray]] = {c: [] for c in others}
    data_uv: dict[str, list[np.ndarray]] = {c: [] for c in others}
    for k, c in enumerate(others):
        for t_b, uv_b in pieces[c]:
            covered[:, k] |= (t_a >= t_b[0]) & (t_a <= t_b[-1])
            data_t[c].append(t_b)
            data_uv[c].append(uv_b)
    seen = covered.any(axis=1)
    if seen.sum() < 2:
        return None
    lo, hi = t_a[seen][0] - 2 * period, t_a[seen][-1] + 2 * period
    names, ts, uvs = [], [], []
    for c, t_list, uv_list in [(ref, [t_a], [uv_a])] + [(c, data_t[c], data_uv[c]) for c in others]:
        t = np.concatenate(t_list)
        uv = np.concatenate(uv_list)
        order = np.argsort(t, kind="stable")
        t, uv = t[order], uv[order]
        win = (t >= lo) & (t <= hi)
        t, uv = _ideal(cams[c], t[win], uv[win])
        keep = np.r_[True, np.diff(t) > 0] if t.size else np.zeros(0, bool)
        if t.size >= 2:
            names.append(c)
            ts.append(t[keep])
            uvs.append(uv[keep])
    if len(names) < 2 or names[0] != ref:
        return None
    traj = fit_spline_trajectory([cams[c].P for c in names], ts, uvs,
                                 knot_spacing_s=knot_spacing_frames * period, penalty=penalty)
    t_out = t_a[seen]
    xyz = traj.position(t_out)
    sq = np.full((t_out.size, len(names)), np.nan)
    for k, (t, res) in enumerate(zip(ts, traj.residuals_px, strict=True)):
        j = np.clip(np.searchsorted(t, t_out), 1, max(t.size - 1, 1))
        j = np.where(np.abs(t[j - 1] - t_out) <= np.abs(t[np.minimum(j, t.size - 1)] - t_out), j - 1, j)
        j = np.minimum(j, t.size - 1)
        near = np.abs(t[j] - t_out) <= 0.5 * period
        sq[near, k] = np.sum(res[j[near]] ** 2, axis=1)
    n_cams = 1 + covered[seen].sum(axis=1)
    with np.errstate(invalid="ignore"):
        rms = np.sqrt(np.nanmean(sq, axis=1))
    return {"time_s": t_out, "x_mm": xyz[:, 0], "y_mm": xyz[:, 1], "z_mm": xyz[:, 2],
            "reprojection_px": rms, "n_cameras": n_cams.astype(np.int64)}


def _number_tracks(out: pd.DataFrame) -> pd.DataFrame:
    """Rows carry a temporary component key; give each segment's components ids 0, 1, … by first time."""
    out = out.drop_duplicates(["component", "time_s"], keep="first")
    first = out.groupby("component")["time_s"].min().rename("t_first")
    seg = out.groupby("component")["segment"].first()
    order = pd.concat([seg, first], axis=1).sort_values(["segment", "t_first"], kind="stable")
    order["track_id"] = order.groupby("segment").cumcount().astype(np.int64)
    out = out.join(order["track_id"], on="component")
    return out.drop(columns="component").reset_index(drop=True)


__all__ = ["SYNC_METHODS", "TRACK_COLUMNS", "pair_all", "prepare_observations", "row_corrected_times",
           "timing_result", "triangulate_tracks"]
