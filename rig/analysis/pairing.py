"""Cross-camera pairing of 2-D tracks: which track of camera B is the same marker as a track of camera A.

Two tracks are compared over their common time span: camera B's track is interpolated (cubic spline) to
camera A's instants (both on one clock, row-corrected — :func:`rig.analysis.sync_tracks.row_corrected_times`)
and the
**median** symmetric epipolar distance (px, undistorted pixels, :func:`rig.stereo.epipolar_distance_px`)
is the pair's cost; the median ignores the few instants where the interpolation error of fast motion is
large. The right pair's cost is the pixel noise's for slow motion and grows with the motion between frames
(the interpolation error), hence the default gate of 8 px — still far below the image spacing of markers
(≥ 50 px on the rig's targets) that it must tell apart (twin: 0.2 px for a 10 Hz rotor, 4.4 px for the
sweep column at 30 Hz = fs/2). A candidate is *feasible* when its cost is ≤ ``gate_px``, it has
≥ ``min_common`` common instants, and the point it triangulates to (median over the span) lies in front
of both cameras and inside ``volume_mm`` when given (a pair that triangulates behind a camera or far
outside the measured scene is a wrong pair, not a measurement).

Assignment: ``scipy.optimize.linear_sum_assignment`` first maximises the number of feasible pairs, then
minimises the sum of squared costs. A track broken in one camera (a marker lost for a while) pairs with
each of its pieces: a track left over after the assignment also takes a feasible partner whose other
partners do not overlap it in time.

Ambiguity is flagged, never guessed: a pair is ``ambiguous`` when another feasible candidate of either
track, overlapping in time, costs within ``ambiguity_margin_px`` (default ``gate_px / 2``) of the pair's
own cost — markers on a common epipolar plane (e.g. a row of markers level with a horizontal baseline).
With ``use_order=True`` such a cluster is resolved by the **ordering constraint** when it can be: within one
epipolar plane, markers on targets facing the cameras appear in the same order in both views, i.e. sorted
by the angle between their viewing ray and the baseline (C_a → C_b) the k-th of A is the k-th of B. The
cluster is resolved only when both cameras see the same number of its tracks, all overlapping in time, and
every order-paired candidate is feasible; such pairs get ``resolved = "order"``. Otherwise the pairs stay
``ambiguous`` and are not triangulated by :func:`rig.analysis.sync_tracks.triangulate_tracks`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.interpolate import CubicSpline
from scipy.optimize import linear_sum_assignment

from rig.analysis.disjoint_set import DisjointSet
from rig.analysis.errors import AnalysisError
from rig.analysis.tracks2d import check_observations
from rig.stereo.dlt import DLTCamera
from rig.stereo.epipolar import epipolar_distance_px, fundamental_from_projections
from rig.stereo.triangulate import as_camera, linear_triangulation

PAIR_COLUMNS = ["track_a", "track_b", "distance_px", "n_common", "ambiguous", "resolved"]
Volume = tuple[tuple[float, float], tuple[float, float], tuple[float, float]]


@dataclass(frozen=True)
class TrackPairs:
    """Result of :func:`pair_tracks`.

    ``pairs``: one row per accepted or ambiguous pair (``PAIR_COLUMNS``; ``resolved`` is "assignment",
    "continuation" (a second partner of a broken track), "order" or "" for ambiguous ones).
    ``candidates``: every candidate with common instants: ``track_a, track_b, distance_px, n_common,
    in_front, in_volume, feasible``. ``unpaired_a`` / ``unpaired_b``: tracks without any pair.
    """

    pairs: pd.DataFrame
    candidates: pd.DataFrame
    unpaired_a: list[int]
    unpaired_b: list[int]

    @property
    def usable(self) -> pd.DataFrame:
        """The pairs to triangulate (not ambiguous)."""
        return self.pairs[~self.pairs["ambiguous"].astype(bool)].reset_index(drop=True)


@dataclass
class _Track:
    t: np.ndarray  # (N,) s, increasing
    uv: np.ndarray  # (N, 2) undistorted px
    angle: float = math.nan  # median angle between the viewing ray and the baseline, rad
    spline: CubicSpline | None = None  # built on first use


def _tracks(obs: pd.DataFrame, cam: DLTCamera, what: str) -> dict[int, _Track]:
    check_observations(obs, ("time_s", "u_px", "v_px", "track_id"), what)
    sel = obs[obs["track_id"].to_numpy() >= 0].sort_values(["track_id", "time_s"], kind="stable")
    tid = sel["track_id"].to_numpy()
    t_all = sel["time_s"].to_numpy(float)
    uv_all = cam.undistort_px(sel[["u_px", "v_px"]].to_numpy(float), strict=False)
    cuts = np.flatnonzero(np.diff(tid)) + 1
    out: dict[int, _Track] = {}
    if tid.size == 0:
        return out
    for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, len(tid)], strict=True):
        t, uv = t_all[lo:hi], uv_all[lo:hi]
        ok = np.isfinite(uv).all(axis=1)
        t, uv = t[ok], uv[ok]
        if t.size >= 2:
            keep = np.r_[True, np.diff(t) > 0]
            out[int(tid[lo])] = _Track(t[keep], uv[keep])
    return out


def _interpolate(track: _Track, t_s: np.ndarray) -> np.ndarray:
    """B's track at A's instants: not-a-knot cubic spline (≥ 4 samples), else linear."""
    if track.t.size >= 4:
        if track.spline is None:
            track.spline = CubicSpline(track.t, track.uv, axis=0, bc_type="not-a-knot")
        return track.spline(t_s)
    return np.column_stack([np.interp(t_s, track.t, track.uv[:, k]) for k in range(2)])


def _ray_angles(cam: DLTCamera, uv: np.ndarray, baseline: np.ndarray) -> np.ndarray:
    """Angle (rad) between each pixel's forward viewing ray and the unit ``baseline`` vector."""
    rays = np.linalg.solve(cam.P[:, :3], np.column_stack([uv, np.ones(len(uv))]).T).T  # forward: m3·d = 1 > 0
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    return np.arccos(np.clip(rays @ baseline, -1.0, 1.0))


def _in_volume(xyz: np.ndarray, volume: Volume | None) -> np.ndarray:
    """(N,) True where the points (N, 3) lie in the box (all True without one; NaN rows False)."""
    if volume is None:
        return np.ones(len(xyz), bool)
    box = np.asarray(volume, float)
    with np.errstate(invalid="ignore"):
        return np.all((xyz >= box[:, 0]) & (xyz <= box[:, 1]), axis=1)


def _check_volume(volume_mm: object) -> Volume | None:
    if volume_mm is None:
        return None
    arr = np.asarray(volume_mm, dtype=float)
    if arr.shape != (3, 2) or not np.isfinite(arr).all() or np.any(arr[:, 0] >= arr[:, 1]):
        raise AnalysisError(
            f"volume_mm={volume_mm!r}: pass ((x_min, x_max), (y_min, y_max), (z_min, z_max)) mm, min < max"
        )
    return tuple((float(lo), float(hi)) for lo, hi in arr)  # type: ignore[return-value]


def _overlap(a: _Track, b: _Track) -> bool:
    return min(a.t[-1], b.t[-1]) > max(a.t[0], b.t[0])


def pair_tracks(
    obs_a: pd.DataFrame,
    obs_b: pd.DataFrame,
    cam_a: object,
    cam_b: object,
    *,
    gate_px: float = 8.0,
    ambiguity_margin_px: float | None = None,
    min_common: int = 2,
    volume_mm: object = None,
    use_order: bool = True,
) -> TrackPairs:
    """Pair the 2-D tracks of camera A with those of camera B (see the module docstring).

    ``obs_a``/``obs_b``: observations with ``time_s`` (s, one clock for both cameras), ``u_px``, ``v_px``
    (observed, distorted pixels) and ``track_id`` (−1 rows ignored), e.g. from
    :func:`rig.analysis.tracks2d.tracks_2d`.
    ``cam_a``/``cam_b``: :class:`DLTCamera` or 3×4 matrices. ``volume_mm``: optional box
    ((x_min, x_max), (y_min, y_max), (z_min, z_max)) in mm where markers can be.
    """
    for name, v in (("gate_px", gate_px), ("ambiguity_margin_px", ambiguity_margin_px)):
        if v is not None and (isinstance(v, bool) or not (math.isfinite(float(v)) and float(v) > 0)):
            raise AnalysisError(f"{name}={v!r}: pass a positive number of pixels")
    if isinstance(min_common, bool) or int(min_common) != min_common or min_common < 2:
        raise AnalysisError(f"min_common={min_common!r}: pass an integer ≥ 2")
    gate = float(gate_px)
    margin = gate / 2.0 if ambiguity_margin_px is None else float(ambiguity_margin_px)
    volume = _check_volume(volume_mm)
    ca, cb = as_camera(cam_a, 0), as_camera(cam_b, 1)
    F = fundamental_from_projections(ca, cb)
    ta, tb = _tracks(obs_a, ca, "observations of camera A"), _tracks(obs_b, cb, "observations of camera B")
    baseline = cb.centre_mm - ca.centre_mm
    baseline /= np.linalg.norm(baseline)
    for tr in ta.values():
        tr.angle = float(np.median(_ray_angles(ca, tr.uv, baseline)))
    for tr in tb.values():
        tr.angle = float(np.median(_ray_angles(cb, tr.uv, baseline)))
    rows, probe = _candidates(ta, tb, F, min_common)
    cand = pd.DataFrame(rows, columns=["track_a", "track_b", "distance_px", "n_common"])
    # where each candidate puts the marker (at its median instant): in front of both cameras, in the volume?
    in_front = np.zeros(len(rows), bool)
    in_vol = np.zeros(len(rows), bool)
    gated = np.flatnonzero(cand["distance_px"].to_numpy() <= gate) if rows else np.zeros(0, int)
    if gated.size:
        xyz = linear_triangulation([ca.P, cb.P], probe[gated])
        xyz_h = np.column_stack([xyz, np.ones(len(xyz))])
        ok = np.isfinite(xyz).all(axis=1)
        in_front[gated] = ok & (xyz_h @ ca.P[2] > 0) & (xyz_h @ cb.P[2] > 0)
        in_vol[gated] = ok & _in_volume(xyz, volume)
    cand["in_front"] = in_front
    cand["in_volume"] = in_vol
    cand["feasible"] = (cand["distance_px"].to_numpy() <= gate) & in_front & in_vol if rows else in_front
    pairs = _assign(cand, ta, tb, margin)
    if use_order and len(pairs) and pairs["ambiguous"].any():
        pairs = _resolve_by_order(pairs, cand, ta, tb)
    used_a, used_b = set(pairs["track_a"]), set(pairs["track_b"])
    return TrackPairs(
        pairs.sort_values(["track_a", "track_b"], ignore_index=True),
        cand,
        sorted(set(ta) - used_a),
        sorted(set(tb) - used_b),
    )


def _candidates(ta: dict[int, _Track], tb: dict[int, _Track], F: np.ndarray,
                min_common: int) -> tuple[list[tuple[int, int, float, int]], np.ndarray]:
    """Every pair (A before B, in the tracks' order) with ≥ ``min_common`` of A's instants inside B's span:
    rows (track_a, track_b, median epipolar distance px, n_common) and the probe (n, 2, 2): A's and B's
    undistorted pixels at the instant of the median distance. The spans are slices of A's increasing
    times, B is interpolated once per track over all its pairs' instants, and the distances of all pairs
    are one call (every step point by point: the values of a pair-by-pair loop)."""
    ids_b = list(tb)
    b_first = np.array([tb[ib].t[0] for ib in ids_b])
    b_last = np.array([tb[ib].t[-1] for ib in ids_b])
    spans = []  # (track_a, track_b, first, end): A's instants first:end inside B's span
    for ia, a in ta.items():
        firsts = np.searchsorted(a.t, b_first, side="left")
        ends = np.searchsorted(a.t, b_last, side="right")
        spans += [(ia, ids_b[j], int(firsts[j]), int(ends[j]))
                  for j in np.flatnonzero(ends - firsts >= min_common)]
    if not spans:
        return [], np.zeros((0, 2, 2))
    n = np.array([end - first for _, _, first, end in spans])
    starts = np.r_[0, np.cumsum(n)[:-1]]
    uva = np.concatenate([ta[ia].uv[first:end] for ia, _, first, end in spans])
    uvb = np.empty_like(uva)
    by_b: dict[int, list[int]] = {}
    for i, (_, ib, _, _) in enumerate(spans):
        by_b.setdefault(ib, []).append(i)
    for ib, members in by_b.items():
        at = np.concatenate([np.arange(starts[i], starts[i] + n[i]) for i in members])
        uvb[at] = _interpolate(tb[ib], np.concatenate([ta[spans[i][0]].t[spans[i][2]:spans[i][3]]
                                                       for i in members]))
    dist = epipolar_distance_px(F, uva, uvb, pairwise=False)
    pair_of = np.repeat(np.arange(len(spans)), n)
    order = np.lexsort((dist, pair_of))  # by pair, then by distance (NaN last, as argsort)
    upper = order[starts + n // 2]  # the instant of the median distance (the upper one of an even count)
    lower = order[starts + np.maximum(n // 2 - 1, 0)]
    has_nan = np.add.reduceat(np.isnan(dist), starts) > 0
    median = np.where(n % 2 == 1, dist[upper], np.where(has_nan, np.nan, (dist[lower] + dist[upper]) / 2.0))
    rows = [(ia, ib, float(m), int(k)) for (ia, ib, _, _), m, k in zip(spans, median, n, strict=True)]
    return rows, np.stack([uva[upper], uvb[upper]], axis=1)


def _assign(cand: pd.DataFrame, ta: dict[int, _Track], tb: dict[int, _Track], margin: float) -> pd.DataFrame:
    feas = cand[cand["feasible"]]
    if feas.empty:
        return pd.DataFrame({c: pd.Series(dtype=t) for c, t in zip(
            PAIR_COLUMNS, ["int64", "int64", "float64", "int64", "bool", "object"], strict=True)})
    ia = sorted(set(feas["track_a"]))
    ib = sorted(set(feas["track_b"]))
    pos_a, pos_b = {t: i for i, t in enumerate(ia)}, {t: j for j, t in enumerate(ib)}
    D = np.full((len(ia), len(ib)), np.inf)
    N = np.zeros((len(ia), len(ib)), dtype=np.int64)
    for r in feas.itertuples():
        D[pos_a[r.track_a], pos_b[r.track_b]] = r.distance_px
        N[pos_a[r.track_a], pos_b[r.track_b]] = r.n_common
    ok = np.isfinite(D)
    finite_max = float(np.max(D[ok])) if ok.any() else 1.0
    big = (finite_max + 1.0) ** 2 * (min(D.shape) + 1.0)
    rr, cc = linear_sum_assignment(np.where(ok, np.where(ok, D, 0.0) ** 2, big))
    chosen = [(i, j, "assignment") for i, j in zip(rr, cc, strict=True) if ok[i, j]]
    partners_a: dict[int, list[int]] = {}
    partners_b: dict[int, list[int]] = {}
    for i, j, _ in chosen:
        partners_a.setdefault(i, []).append(j)
        partners_b.setdefault(j, []).append(i)
    # continuation: a leftover track takes a partner whose other partners do not overlap it in time
    for i in range(len(ia)):
        if i in partners_a:
            continue
        for j in np.argsort(np.where(ok[i], D[i], np.inf)):
            if not ok[i, j]:
                break
            if all(not _overlap(ta[ia[i]], ta[ia[k]]) for k in partners_b.get(j, [])):
                chosen.append((i, j, "continuation"))
                partners_a.setdefault(i, []).append(j)
                partners_b.setdefault(j, []).append(i)
                break
    for j in range(len(ib)):
        if j in partners_b:
            continue
        for i in np.argsort(np.where(ok[:, j], D[:, j], np.inf)):
            if not ok[i, j]:
                break
            if all(not _overlap(tb[ib[j]], tb[ib[k]]) for k in partners_a.get(i, [])):
                chosen.append((i, j, "continuation"))
                partners_a.setdefault(i, []).append(j)
                partners_b.setdefault(j, []).append(i)
                break
    out = []
    for i, j, how in chosen:
        d = D[i, j]
        rivals_b = [k for k in range(len(ib)) if k != j and ok[i, k] and D[i, k] <= d + margin
                    and _overlap(tb[ib[k]], tb[ib[j]])]
        rivals_a = [k for k in range(len(ia)) if k != i and ok[k, j] and D[k, j] <= d + margin
                    and _overlap(ta[ia[k]], ta[ia[i]])]
        amb = bool(rivals_a or rivals_b)
        out.append((ia[i], ib[j], float(d), int(N[i, j]), amb, "" if amb else how))
    return pd.DataFrame(out, columns=PAIR_COLUMNS)


def _resolve_by_order(pairs: pd.DataFrame, cand: pd.DataFrame, ta: dict[int, _Track],
                      tb: dict[int, _Track]) -> pd.DataFrame:
    feas = cand[cand["feasible"]]
    edges = {(int(r.track_a), int(r.track_b)): (float(r.distance_px), int(r.n_common))
             for r in feas.itertuples()}
    amb = pairs[pairs["ambiguous"]]
    # clusters: connected components of the feasible-candidate graph, seeded by ambiguous pairs
    sets: DisjointSet[tuple[str, int]] = DisjointSet()
    members_a = set(amb["track_a"].astype(int))
    members_b = set(amb["track_b"].astype(int))
    changed = True
    while changed:
        changed = False
        for a, b in edges:
            if (a in members_a or b in members_b) and not (a in members_a and b in members_b):
                members_a.add(a)
                members_b.add(b)
                changed = True
    for a, b in edges:
        if a in members_a and b in members_b:
            sets.union(("a", a), ("b", b))
    clusters: dict[tuple[str, int], tuple[list[int], list[int]]] = {}
    for a in members_a:
        clusters.setdefault(sets.find(("a", a)), ([], []))[0].append(a)
    for b in members_b:
        clusters.setdefault(sets.find(("b", b)), ([], []))[1].append(b)
    resolved_rows = []
    drop_a: set[int] = set()
    drop_b: set[int] = set()
    for ca_list, cb_list in clusters.values():
        if len(ca_list) != len(cb_list) or len(ca_list) < 2:
            continue
        if not all(_overlap(ta[x], ta[y]) for x in ca_list for y in ca_list if x != y):
            continue
        if not all(_overlap(tb[x], tb[y]) for x in cb_list for y in cb_list if x != y):
            continue
        sa = sorted(ca_list, key=lambda t: ta[t].angle)
        sb = sorted(cb_list, key=lambda t: tb[t].angle)
        if not all((a, b) in edges for a, b in zip(sa, sb, strict=True)):
            continue
        for a, b in zip(sa, sb, strict=True):
            d, n = edges[(a, b)]
            resolved_rows.append((a, b, d, n, False, "order"))
        drop_a.update(ca_list)
        drop_b.update(cb_list)
    if not resolved_rows:
        return pairs
    keep = pairs[~(pairs["track_a"].isin(drop_a) | pairs["track_b"].isin(drop_b))]
    return pd.concat([keep, pd.DataFrame(resolved_rows, columns=PAIR_COLUMNS)], ignore_index=True)
