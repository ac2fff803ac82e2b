"""Cross-camera pairing of 2-D tracks on twin data: right pairs, a decoy left unpaired or flagged ambiguous
(never guessed), markers on a common epipolar plane resolved by the volume or the ordering constraint, a
broken track paired piece by piece, bad options named."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from analysis_twin import twin

from rig.analysis.errors import AnalysisError
from rig.analysis.pairing import pair_tracks
from rig.analysis.sync_tracks import TRACK_COLUMNS, prepare_observations, triangulate_tracks

VOLUME = ((0.0, 800.0), (-500.0, 500.0), (-100.0, 800.0))  # the twin's robot envelope and references, grown


def _prepared(tw, **track_options):
    return {c: prepare_observations(tw.observations[c], tw.timing, c, **track_options)
            for c in ("left", "right")}


def _marker_of(obs: pd.DataFrame) -> dict[int, str]:
    g = obs[obs["track_id"] >= 0].groupby("track_id")["marker_id"]
    assert (g.nunique() == 1).all()
    return g.first().to_dict()


def _check_correct(res, obs):
    ma, mb = _marker_of(obs["left"]), _marker_of(obs["right"])
    for r in res.pairs.itertuples():
        assert ma[r.track_a] == mb[r.track_b], (r, ma[r.track_a], mb[r.track_b])


@pytest.fixture(scope="module")
def column():
    return twin("sweep_column", setup=lambda w: w.exciter.set_frequency(0.0, 8.0), t_start_s=1.0,
                t_stop_s=2.0, sigma_px=0.2, seed=11)


def test_every_marker_is_paired_with_itself(column):
    obs = _prepared(column)
    res = pair_tracks(obs["left"], obs["right"], column.cameras["left"], column.cameras["right"],
                      volume_mm=VOLUME)
    assert len(res.pairs) == 9 and not res.pairs["ambiguous"].any()
    assert res.unpaired_a == [] and res.unpaired_b == []
    _check_correct(res, obs)
    # the cost of a right pair is the pixel noise's epipolar distance, far inside the gate
    assert res.pairs["distance_px"].max() < 1.0


def test_common_epipolar_plane_is_resolved_by_volume_or_order(column):
    """ref0 and ref2 lie on a line parallel to the baseline: one epipolar plane. Without a volume the swap
    is geometrically possible (flagged ambiguous, then resolved by the ordering constraint); with the
    volume the swapped pairs triangulate outside it and are not candidates at all."""
    obs = _prepared(column)
    cams = column.cameras["left"], column.cameras["right"]
    plain = pair_tracks(obs["left"], obs["right"], *cams, use_order=False)
    ma = _marker_of(obs["left"])
    amb = {ma[t] for t in plain.pairs.loc[plain.pairs["ambiguous"], "track_a"]}
    assert amb == {"ref0", "ref2"}
    ordered = pair_tracks(obs["left"], obs["right"], *cams)
    assert not ordered.pairs["ambiguous"].any()
    by_order = ordered.pairs.loc[ordered.pairs["resolved"] == "order", "track_a"]
    assert {ma[t] for t in by_order} == {"ref0", "ref2"}
    _check_correct(ordered, obs)
    boxed = pair_tracks(obs["left"], obs["right"], *cams, volume_mm=VOLUME, use_order=False)
    assert not boxed.pairs["ambiguous"].any()
    _check_correct(boxed, obs)


def _with_decoy(tw, obs, marker: str, depth_shift_mm: float | None, pixel_shift=(0.0, 0.0)):
    """Camera B (right) sees an extra marker: the real one moved along A's viewing ray by depth_shift_mm
    (same epipolar line of A's observation), or shifted in B's image by pixel_shift."""
    right = obs["right"]
    real = right[right["marker_id"] == marker].copy()
    if depth_shift_mm is not None:
        w = tw.world_time(real["time_s"].to_numpy())
        X = tw.world.positions([marker], w)[0]
        C = tw.cameras["left"].centre_mm
        ray = (X - C) / np.linalg.norm(X - C, axis=1, keepdims=True)
        uv = tw.cameras["right"].project(X + depth_shift_mm * ray)
        real["u_px"], real["v_px"] = uv[:, 0], uv[:, 1]
    else:
        real["u_px"] += pixel_shift[0]
        real["v_px"] += pixel_shift[1]
    real["marker_id"] = "decoy"
    real["track_id"] = right["track_id"].max() + 1
    return {"left": obs["left"], "right": pd.concat([right, real], ignore_index=True)}


def test_decoy_off_the_epipolar_lines_stays_unpaired(column):
    obs = _with_decoy(column, _prepared(column), "col2", None, pixel_shift=(0.0, 25.0))
    res = pair_tracks(obs["left"], obs["right"], column.cameras["left"], column.cameras["right"],
                      volume_mm=VOLUME)
    decoy = int(obs["right"]["track_id"].max())
    assert res.unpaired_b == [decoy]
    assert not res.pairs["ambiguous"].any()
    _check_correct(res, obs)


def test_decoy_on_the_epipolar_line_is_flagged_not_guessed(column):
    obs = _with_decoy(column, _prepared(column), "col2", depth_shift_mm=80.0)
    cams = column.cameras["left"], column.cameras["right"]
    res = pair_tracks(obs["left"], obs["right"], *cams, volume_mm=VOLUME)
    ma = _marker_of(obs["left"])
    flagged = res.pairs[res.pairs["ambiguous"]]
    assert [ma[t] for t in flagged["track_a"]] == ["col2"]
    assert (flagged["resolved"] == "").all()
    others = res.pairs[~res.pairs["ambiguous"]]
    assert len(others) == 8
    # triangulation leaves the ambiguous marker out instead of picking one of the two
    tracks = triangulate_tracks(obs, dict(zip(("left", "right"), cams, strict=True)), column.timing,
                                sync="linear", pairs=res.pairs)
    assert tracks["track_id"].nunique() == 8


def test_a_track_broken_in_one_camera_pairs_with_both_pieces():
    tw = twin("sweep_column", setup=lambda w: w.exciter.set_frequency(0.0, 3.0), t_start_s=1.0,
              t_stop_s=2.5, sigma_px=0.2, seed=4, marker_ids=["col2"],
              right_overrides={"dropped_frames": tuple(range(90, 100))})
    obs = _prepared(tw)
    assert obs["right"]["track_id"].nunique() == 2 and obs["left"]["track_id"].nunique() == 1
    res = pair_tracks(obs["left"], obs["right"], tw.cameras["left"], tw.cameras["right"])
    assert sorted(res.pairs["resolved"]) == ["assignment", "continuation"]
    tracks = triangulate_tracks(obs, tw.cameras, tw.timing, sync="trajectory")
    assert tracks["track_id"].nunique() == 1
    # the instants of A inside the gap are not given (no B observation brackets them) …
    t_gap = obs["right"].groupby("track_id")["time_s"].agg(["min", "max"]).sort_values("min")
    lo, hi = t_gap["max"].iloc[0], t_gap["min"].iloc[1]
    assert not ((tracks["time_s"] > lo) & (tracks["time_s"] < hi)).any()
    # … and every A instant bracketed by one of the pieces is
    t_a = obs["left"]["time_s"].to_numpy()
    inside = np.zeros(t_a.size, bool)
    for r in t_gap.itertuples():
        inside |= (t_a >= r.min) & (t_a <= r.max)
    assert len(tracks) == inside.sum()


BAD_OPTIONS = [({"gate_px": -1.0}, "gate_px"), ({"min_common": 1}, "min_common"),
               ({"volume_mm": ((0, 1), (0, 1))}, "volume_mm"),
               ({"ambiguity_margin_px": 0.0}, "ambiguity_margin_px")]


@pytest.mark.parametrize(("kwargs", "word"), BAD_OPTIONS)
def test_bad_options_are_named(column, kwargs, word):
    obs = _prepared(column)
    with pytest.raises(AnalysisError, match=word):
        pair_tracks(obs["left"], obs["right"], column.cameras["left"], column.cameras["right"], **kwargs)


def test_observations_without_track_ids_are_refused(column):
    with pytest.raises(AnalysisError, match="track_id"):
        pair_tracks(column.observations["left"].assign(time_s=0.0), column.observations["right"],
                    column.cameras["left"], column.cameras["right"])


def test_rows_of_the_calibration_plate_are_resolved_by_order():
    """Seven markers per row on one epipolar plane: within the volume each row is a cluster of mutually
    ambiguous candidates; without the ordering constraint they are flagged, with it all 35 are right."""
    tw = twin("calibration_plate", t_start_s=1.0, t_stop_s=1.5, sigma_px=0.2, seed=2)
    obs = _prepared(tw)
    cams = tw.cameras["left"], tw.cameras["right"]
    flagged = pair_tracks(obs["left"], obs["right"], *cams, volume_mm=VOLUME, use_order=False)
    ma = _marker_of(obs["left"])
    amb = {ma[t] for t in flagged.pairs.loc[flagged.pairs["ambiguous"], "track_a"]}
    assert len(amb) >= 28 and all(m.startswith("cal_") for m in amb)
    ordered = pair_tracks(obs["left"], obs["right"], *cams, volume_mm=VOLUME)
    assert len(ordered.pairs) == 39 and not ordered.pairs["ambiguous"].any()
    _check_correct(ordered, obs)


def test_a_camera_without_observations_gives_no_pairs_and_an_empty_tracks_frame(column):
    obs = _prepared(column)
    none = obs["right"].iloc[:0]
    res = pair_tracks(obs["left"], none, column.cameras["left"], column.cameras["right"])
    assert res.pairs.empty and len(res.unpaired_a) == 9 and res.unpaired_b == []
    tracks = triangulate_tracks({"left": obs["left"], "right": none}, column.cameras, column.timing)
    assert tracks.empty and list(tracks.columns) == TRACK_COLUMNS
    assert tracks["track_id"].dtype == np.int64 and tracks["n_cameras"].dtype == np.int64


def _median_distances_pair_by_pair(obs, cams) -> pd.DataFrame:
    """The candidates' costs by the module docstring's definition, one pair at a time: B's track (a
    not-a-knot cubic spline, linear under 4 samples) at A's instants inside B's span, the median of the
    symmetric epipolar distances."""
    from scipy.interpolate import CubicSpline

    from rig.stereo.epipolar import epipolar_distance_px, fundamental_from_projections

    def tracks(o, cam):
        o = o[o["track_id"] >= 0].sort_values(["track_id", "time_s"], kind="stable")
        uv = cam.undistort_px(o[["u_px", "v_px"]].to_numpy(float), strict=False)
        return {int(k): (o["time_s"].to_numpy()[idx], uv[idx])
                for k, idx in o.groupby("track_id").indices.items()}

    F = fundamental_from_projections(*cams)
    rows = []
    for ia, (t_a, uv_a) in tracks(obs["left"], cams[0]).items():
        for ib, (t_b, uv_b) in tracks(obs["right"], cams[1]).items():
            inside = (t_a >= t_b[0]) & (t_a <= t_b[-1])
            if inside.sum() < 2:
                continue
            at_a = (CubicSpline(t_b, uv_b, axis=0)(t_a[inside]) if t_b.size >= 4 else
                    np.column_stack([np.interp(t_a[inside], t_b, uv_b[:, k]) for k in range(2)]))
            dist = epipolar_distance_px(F, uv_a[inside], at_a, pairwise=False)
            rows.append((ia, ib, float(np.median(dist)), int(inside.sum())))
    return pd.DataFrame(rows, columns=["track_a", "track_b", "distance_px", "n_common"])


def test_candidate_costs_are_the_pair_by_pair_medians_from_one_distance_call(monkeypatch):
    """Every pair's distances come from one call over all pairs (not one per pair) and equal, to the bit,
    the pair-by-pair definition; a broken track and an odd and even count of common instants included."""
    from rig.analysis import pairing

    tw = twin("sweep_column", setup=lambda w: w.exciter.set_frequency(0.0, 3.0), t_start_s=1.0,
              t_stop_s=2.5, sigma_px=0.2, seed=4, right_overrides={"dropped_frames": tuple(range(90, 100))})
    obs = _prepared(tw)
    cams = tw.cameras["left"], tw.cameras["right"]
    calls = []
    real = pairing.epipolar_distance_px
    monkeypatch.setattr(pairing, "epipolar_distance_px", lambda *a, **k: calls.append(1) or real(*a, **k))
    res = pair_tracks(obs["left"], obs["right"], *cams)
    assert len(calls) == 1
    expected = _median_distances_pair_by_pair(obs, cams)
    got = res.candidates[["track_a", "track_b", "distance_px", "n_common"]]
    assert len(got) > 50 and set(got["n_common"] % 2) == {0, 1}
    pd.testing.assert_frame_equal(got.sort_values(["track_a", "track_b"], ignore_index=True),
                                  expected.sort_values(["track_a", "track_b"], ignore_index=True),
                                  check_exact=True)
