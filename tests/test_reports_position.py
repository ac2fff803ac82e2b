"""Error versus position on synthetic tracks with known injected errors (exact expected values)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import reports_synth as synth

from reports import position
from reports.errors import ReportError
from reports.load import accuracy_poses, camera_centres_mm
from reports.tables import _unsettled_note
from rig.record.folder import Calibration

TOL = 1e-9  # exact data: only rounding


@pytest.fixture(scope="module")
def poses() -> pd.DataFrame:
    events = pd.DataFrame(
        [
            {"stream": "accuracy_pose", "seq": i, "time_s": ev["t_stop_s"], "data": ev}
            for i, ev in enumerate(synth.accuracy_events())
        ]
    )
    return accuracy_poses(events)


@pytest.fixture(scope="module")
def errors(poses: pd.DataFrame) -> pd.DataFrame:
    tracks = synth.make_tracks("trajectory")
    return position.position_errors(position.match_static(tracks, poses))


def _expected_error(row: pd.Series) -> np.ndarray:
    ti = list(synth.TARGETS_MM).index(row["target"])
    mi = list(synth.FRAME_MARKERS_MM).index(row["marker_id"])
    return synth.pose_offset_mm(ti, int(row["cycle"]), mi)


def test_every_pose_error_equals_the_injected_offset(errors: pd.DataFrame) -> None:
    assert len(errors) == len(synth.accuracy_events()) * len(synth.FRAME_MARKERS_MM)
    for _, row in errors.iterrows():
        expected = _expected_error(row)
        got = row[["ex_mm", "ey_mm", "ez_mm"]].to_numpy(float)
        np.testing.assert_allclose(got, expected, atol=TOL)
        assert row["error_mm"] == pytest.approx(np.linalg.norm(expected), abs=TOL)
        assert row["n_samples"] == 31  # 0.5 s window at 60 fps, both ends included


def test_summary_statistics(errors: pd.DataFrame) -> None:
    norms = np.array([np.linalg.norm(_expected_error(r)) for _, r in errors.iterrows()])
    s = position.position_summary(errors)
    assert s["n_matched"] == s["n_commanded"] == len(norms) and s["n_missing"] == 0
    assert s["mean_mm"] == pytest.approx(norms.mean(), abs=TOL)
    assert s["rms_mm"] == pytest.approx(np.sqrt(np.mean(norms**2)), abs=TOL)
    assert s["max_mm"] == pytest.approx(np.sqrt(0.3**2 + 0.1**2 + 0.04**2), abs=TOL)
    assert s["p95_mm"] == pytest.approx(np.percentile(norms, 95), abs=TOL)


def test_iso9283_accuracy_and_repeatability(errors: pd.DataFrame) -> None:
    table = position.iso9283(errors)
    assert len(table) == len(synth.TARGETS_MM) * len(synth.FRAME_MARKERS_MM)
    # cycle c adds -0.05·c in y: attained y offsets 0, -0.05, -0.10 → mean -0.05, distances 0.05, 0, 0.05
    dist = np.array([0.05, 0.0, 0.05])
    rp = dist.mean() + 3 * dist.std(ddof=1)
    for _, row in table.iterrows():
        ti = list(synth.TARGETS_MM).index(row["target"])
        mi = list(synth.FRAME_MARKERS_MM).index(row["marker_id"])
        ap = np.array([0.1 * (ti + 1), -0.05, 0.02 * mi])
        assert row["n_cycles"] == synth.N_CYCLES
        np.testing.assert_allclose(row[["ap_x_mm", "ap_y_mm", "ap_z_mm"]].to_numpy(float), ap, atol=TOL)
        assert row["ap_p_mm"] == pytest.approx(np.linalg.norm(ap), abs=TOL)
        assert row["rp_l_mm"] == pytest.approx(rp, abs=TOL)


def test_vdi_vde_length_errors(errors: pd.DataFrame) -> None:
    table = position.length_errors(errors)
    assert len(table) == len(synth.accuracy_events()) * 3  # 3 pairs per pose of 3 markers
    pair = table.set_index(["index", "marker_a", "marker_b"])
    # markers differ only by 0.02 mm per marker index in z
    assert pair.loc[(0, "frame0", "frame2"), "length_error_mm"] == pytest.approx(0.04, abs=TOL)
    assert pair.loc[(4, "frame0", "frame1"), "length_error_mm"] == pytest.approx(
        np.hypot(200.0, 0.02) - 200.0, abs=TOL
    )
    assert pair.loc[(8, "frame1", "frame2"), "length_error_mm"] == pytest.approx(
        np.hypot(200.0, 150.02) - 250.0, abs=TOL
    )
    assert pair.loc[(8, "frame1", "frame2"), "length_cal_mm"] == pytest.approx(250.0, abs=TOL)


def test_reference_markers_are_not_taken_and_a_far_track_is_missing(poses: pd.DataFrame) -> None:
    tracks = synth.make_tracks("trajectory")
    # move every marker of pose 0 far beyond the gate: those rows must be reported missing, not mismatched
    moved = tracks.copy()
    in_pose0 = (moved["segment"] == "accuracy") & (moved["track_id"] < 99)
    moved.loc[in_pose0, "x_mm"] += 500.0
    errs = position.position_errors(position.match_static(moved, poses, gate_mm=50.0))
    missing = errs[errs["error_mm"].isna()]
    assert sorted(missing["index"].unique()) == [0]
    assert len(missing) == 3
    assert (errs.loc[errs["index"] == 0, "track_id"] == -1).all()
    assert position.position_summary(errs)["n_missing"] == 3


def test_noise_gives_type_a_uncertainty(poses: pd.DataFrame) -> None:
    sigma = 0.05
    tracks = synth.make_tracks("trajectory", position_noise_mm=sigma, seed=3)
    errs = position.position_errors(position.match_static(tracks, poses))
    # standard error of a 31-sample mean per axis is σ/√31; its estimate scatters by ≈ 1/√(2·30)
    u = errs[["u_x_mm", "u_y_mm", "u_z_mm"]].to_numpy(float).ravel()
    expected = sigma / np.sqrt(31)
    assert np.mean(u) == pytest.approx(expected, rel=4 / np.sqrt(2 * 30 * len(u)))
    # the mean errors stay within 4 standard errors of the injected ones
    for _, row in errs.iterrows():
        diff = row[["ex_mm", "ey_mm", "ez_mm"]].to_numpy(float) - _expected_error(row)
        assert np.all(np.abs(diff) < 4 * expected + 1e-12)


def test_geometry_columns() -> None:
    centres = camera_centres_mm(Calibration.from_dict(synth.CALIBRATION))
    for name, c in synth.CAMERA_CENTRES_MM.items():
        np.testing.assert_allclose(centres[name], c, atol=1e-6)
    frame = pd.DataFrame({"x_cmd_mm": [0.0, 100.0], "y_cmd_mm": [0.0, 0.0], "z_cmd_mm": [300.0, 300.0]})
    out = position.add_geometry(frame, centres)
    # cameras' midpoint (0, -2500, 300); volume centre (50, 0, 300)
    axis = np.array([50.0, 2500.0, 0.0]) / np.hypot(50.0, 2500.0)
    rel = np.array([[0.0, 2500.0, 0.0], [100.0, 2500.0, 0.0]])
    off = np.linalg.norm(rel - np.outer(rel @ axis, axis), axis=1)
    np.testing.assert_allclose(out["distance_mm"], np.linalg.norm(rel, axis=1), atol=1e-9)
    np.testing.assert_allclose(out["off_axis_mm"], off, atol=1e-9)


def test_bad_inputs_raise() -> None:
    with pytest.raises(ReportError, match="gate_mm"):
        position.match_static(pd.DataFrame(), pd.DataFrame(), gate_mm=0)
    with pytest.raises(ReportError, match="missing column"):
        position.match_static(pd.DataFrame({"time_s": []}), pd.DataFrame())


def test_a_track_of_another_segment_is_never_taken(poses: pd.DataFrame) -> None:
    """A decoy exactly at the commanded position, at the same instants but recorded by another step."""
    tracks = synth.make_tracks("trajectory")
    ev = synth.accuracy_events()[0]
    t = tracks.loc[(tracks["segment"] == "accuracy") & (tracks["track_id"] == 0), "time_s"].to_numpy()
    x, y, z = ev["markers"]["frame0"]
    decoy = pd.DataFrame(
        {
            "segment": "elsewhere",
            "time_s": t,
            "track_id": 0,
            "x_mm": x,
            "y_mm": y,
            "z_mm": z,
            "reprojection_px": 0.1,
            "n_cameras": 2,
        }
    )
    errs = position.position_errors(position.match_static(pd.concat([tracks, decoy]), poses))
    row = errs[(errs["index"] == 0) & (errs["marker_id"] == "frame0")].iloc[0]
    assert row["ex_mm"] == pytest.approx(0.1, abs=TOL)  # the injected error, not the decoy's zero


def test_a_static_marker_at_rest_keeps_all_its_samples() -> None:
    """White noise alone is never taken for motion: 120,000 samples in windows of the fewest samples judged
    (6; longer windows estimate the noise better). Bound: < 2e-4 per sample in the worst case (see
    position.SETTLED_FACTOR); measured 1.2e-5."""
    rng = np.random.default_rng(7)
    left_out = sum(int(np.count_nonzero(~position.settled_samples(rng.normal(0.0, 0.01, (6, 3)))))
                   for _ in range(20_000))
    assert left_out <= 24, left_out  # 2e-4 × 120,000
    assert position.settled_samples(np.zeros((5, 3))).all()  # too few to judge: all kept
    assert position.settled_samples(np.ones((40, 3))).all()  # noise-free: all kept


def test_samples_taken_while_the_arm_arrived_are_left_out_and_counted(poses: pd.DataFrame) -> None:
    """The first 3 frames of a pose's window caught the markers still arriving (0.9, 0.6, 0.3 mm off in x:
    an arm at ≈ 18 mm/s, or frames stamped late): averaged in, they would bias x by 0.058 mm (6 σ of the
    mean); they are left out, counted in ``n_unsettled``, and the error is the injected one within the
    noise."""
    noise_mm = 0.01
    tracks = synth.make_tracks("trajectory", position_noise_mm=noise_mm, seed=3)
    pose = poses[poses["index"] == 0].iloc[0]
    in_window = ((tracks["segment"] == pose["segment"]) & (tracks["time_s"] >= pose["t_start_s"])
                 & (tracks["time_s"] <= pose["t_stop_s"]))
    arriving = tracks[in_window].groupby("track_id", group_keys=False).apply(
        lambda t: t.sort_values("time_s").head(3), include_groups=False).index
    approach_mm = np.tile([0.9, 0.6, 0.3], len(arriving) // 3)
    tracks.loc[arriving, "x_mm"] += approach_mm
    errors = position.position_errors(position.match_static(tracks, poses))
    first = errors[errors["index"] == 0]
    assert len(first) == len(synth.FRAME_MARKERS_MM)
    assert (first["n_unsettled"] == 3).all() and (first["n_samples"] == 28).all()
    assert (errors[errors["index"] != 0]["n_unsettled"] == 0).all()
    for _, row in first.iterrows():
        got = row[["ex_mm", "ey_mm", "ez_mm"]].to_numpy(float)
        u_mean_mm = noise_mm / np.sqrt(row["n_samples"])
        np.testing.assert_allclose(got, _expected_error(row), atol=5 * u_mean_mm)
    biased_mm = approach_mm[:3].sum() / 31  # what the plain mean of all 31 samples would have added to x
    assert biased_mm > 5 * noise_mm / np.sqrt(31)
    # the certificate's position values say so
    assert _unsettled_note(errors) == (f", {3 * len(first)} samples in {len(first)} of them left out: taken "
                                       "while the marker still moved")
    assert _unsettled_note(errors[errors["index"] != 0]) == ""
