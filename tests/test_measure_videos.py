"""`rig calibrate` then `rig measure` on videos written by the twin, against the twin's truth.

Tolerances are derived, never tuned: the amplitude's noise floor is the sine fit's own standard uncertainty
(from its residuals), the calibration's scale floor is the largest relative length error of the plate's
points when their exact images are triangulated with the calibration, and the sync method's bias at 5 Hz
is < 0.1 % (rig/analysis/sync_tracks.py); the frequency's floor is the fit's standard uncertainty plus the
reference camera's clock-rate error.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import measure_twin as mt
import numpy as np
import pandas as pd
import pytest
from camera_mkv import write_mkv
from threadpoolctl import threadpool_info, threadpool_limits

from drivers.sim.clock import VirtualClock
from drivers.sim.targets import ReferenceMarkers
from reports.measurement import write_measurement_report
from rig.cli import main
from rig.deploy import measure as measure_module
from rig.deploy.measure import MeasureError, MeasureOptions, measure_videos
from rig.deploy.series import SeriesError, reference_tracks
from rig.deploy.video_markers import ExtractOptions
from rig.record.writer import RunRecord

PairOf = Callable[[str, str], tuple[Path, Path]]  # (fourcc, extension) → (left, right) videos
WINDOW = (0.6, 2.4)  # s on the left video's clock: the exciter runs from 0.4 s


@pytest.fixture(scope="module")
def site(calibrated_site: dict) -> dict:
    return calibrated_site  # built once per session (tests/conftest.py)


@pytest.fixture(scope="module")
def measurement_pair(tmp_path_factory: pytest.TempPathFactory) -> PairOf:
    """``mt.write_pair`` of ``mt.measurement_world()``'s default intervals, rendered once per codec for the
    module's tests (the twin renders the same frames for the same world: each test's own world and cameras
    give the truth). Read-only: a test that alters a video copies it first."""
    rendered: dict[tuple[str, str], tuple[Path, Path]] = {}

    def pair(fourcc: str, ext: str) -> tuple[Path, Path]:
        if (fourcc, ext) not in rendered:
            left, right = mt.camera_pair(mt.measurement_world())
            rendered[fourcc, ext] = mt.write_pair(left, right, tmp_path_factory.mktemp(fourcc), fourcc=fourcc,
                                                  ext=ext)
        return rendered[fourcc, ext]

    return pair


def _exciter_record(folder: Path) -> Path:
    """A run record of the exciter started at ONSET_S (controller clock = the twin's world clock)."""
    clock = VirtualClock()
    rec = RunRecord.create(folder / "runs", "plate", {}, {}, clock)
    rec.event("exciter", {"frequency_hz": 0.0, "setpoint_hz": 0.0, "status": "stopped"})
    clock.advance_to(mt.ONSET_S)
    rec.event("exciter", {"frequency_hz": mt.FREQUENCY_HZ, "setpoint_hz": mt.FREQUENCY_HZ, "status": "run"})
    clock.advance_to(3.0)
    rec.stop("success")
    rec.close()
    return rec.run_dir


def _check_targets(summary: pd.DataFrame, clock_ppm: float, scale_floor: float) -> None:
    targets = summary[summary["role"] == "target"]
    assert len(targets) == 5  # the sweep column's markers; the 4 references are recognised as static
    assert (summary["role"] == "reference").sum() == 4
    for r in targets.itertuples():
        tol_a = 4 * r.amplitude_std_mm + mt.CRANK_MM * (scale_floor + 1e-3)
        assert abs(r.amplitude_mm - mt.CRANK_MM) <= tol_a, (r.track_id, r.amplitude_mm, tol_a)
        tol_f = 4 * r.frequency_std_hz + abs(clock_ppm) * 1e-6 * mt.FREQUENCY_HZ
        assert abs(r.frequency_hz - mt.FREQUENCY_HZ) <= tol_f, (r.track_id, r.frequency_hz, tol_f)
        assert abs(r.direction_z) > 0.99  # the column moves along base z
        assert abs(r.dominant_frequency_hz - mt.FREQUENCY_HZ) <= r.resolution_hz / 2


@pytest.mark.parametrize(("fourcc", "ext"),
                         [("mp4v", "mp4"), pytest.param("MJPG", "avi", marks=pytest.mark.slow)])
def test_calibrate_then_measure_matches_the_twin(site: dict, tmp_path: Path, fourcc: str, ext: str,
                                                 measurement_pair: PairOf) -> None:
    world = mt.measurement_world()
    left, right = mt.camera_pair(world)
    paths = measurement_pair(fourcc, ext)
    timing = tmp_path / "timing.json"
    timing.write_text(json.dumps(mt.truth_timing(left, right, 0.0, 0.15)))
    out = tmp_path / "out"
    record = _exciter_record(tmp_path)
    code = main(["measure", str(paths[0]), str(paths[1]), "--calibration", str(site["calibration"]),
                 "--timing", str(timing), "--out", str(out), "--window", *map(str, WINDOW),
                 "--record", str(record)])
    assert code == 0
    # the controller's clock (= world time on the twin) from the exciter's start seen in the video
    clock = json.loads((out / "clock.json").read_text())
    truth_offset = float(mt.world_time(left, 0.0, np.zeros(1))[0])
    assert clock["streams"] == ["exciter"]
    assert abs(clock["offset_s"] - truth_offset) <= clock["uncertainty_s"], (clock, truth_offset)
    summary = pd.read_csv(out / "tables" / "summary.csv")
    _check_targets(summary, left.clock_ppm, site["scale_floor"])
    for name in ("displacement", "spectra", "tracks_3d"):
        assert (out / "tables" / f"{name}.csv").stat().st_size > 0
    html = (out / "report.html").read_text()
    assert "data:image/svg+xml;base64," in html and "Summary per track" in html
    assert (out / "figures" / "spectrum.svg").is_file()
    assert not any("tracking window" in n for n in json.loads((out / "measure.json").read_text())["notes"])
    # displacement over time against the truth, on the world clock: within the noise and scale floors
    disp = pd.read_csv(out / "tables" / "displacement.csv")
    assert np.allclose(disp["controller_time_s"] - disp["time_s"], clock["offset_s"])
    tid = int(summary[summary["role"] == "target"]["track_id"].iloc[2])
    d = disp[(disp["track_id"] == tid) & disp["time_s"].between(*WINDOW)]
    truth = mt.truth_displacement_mm(world, mt.world_time(left, 0.0, d["time_s"].to_numpy()))
    resid = d["dz_mm"].to_numpy() - (truth - np.median(truth))
    row = summary[summary["track_id"] == tid].iloc[0]
    floor = row["fit_residual_rms_mm"] + mt.CRANK_MM * site["scale_floor"]
    assert np.sqrt(np.mean((resid - resid.mean()) ** 2)) <= 1.5 * floor


@pytest.mark.slow
def test_estimated_timing_finds_the_offset_and_the_result(
        site: dict, tmp_path: Path, measurement_pair: PairOf) -> None:
    left, right = mt.camera_pair(mt.measurement_world())
    paths = measurement_pair("mp4v", "mp4")
    res = measure_videos({"left": paths[0], "right": paths[1]}, site["calibration"], tmp_path / "out",
                         options=MeasureOptions(window_s=WINDOW))
    truth = mt.truth_timing(left, right, 0.0, 0.15)["offset_s"]["right"]
    # the motion's start resolves the whole periods; the line time is not observable from a column whose
    # rows move alike in both views, so the offset's uncertainty holds its share
    assert not res.timing["details"]["coarse"]["ambiguous"]
    assert res.timing["details"]["line_time"]["observable"] is False
    # mp4v's inter-frame coding moves a slow marker's centre in phase with its velocity (≈ 0.2 ms here,
    # docs/deployment.md): 1 ms bounds it (< 1/16 frame)
    assert abs(res.timing["offset_s"]["right"] - truth) < 1e-3
    _check_targets(res.summary, left.clock_ppm, site["scale_floor"])


def _mkv(cam, t0: float, t1: float, path: Path) -> None:
    idx = cam.frame_indices_between(t0, t1)
    stamps = [cam.frame_timestamp_s(i) - cam.frame_timestamp_s(idx[0]) for i in idx]
    write_mkv(path, (cam.render(i) for i in idx), stamps)


def test_duplicated_and_dropped_frames_are_reported_and_the_result_holds(site: dict, tmp_path: Path) -> None:
    world = mt.measurement_world()
    left, right = mt.camera_pair(world, left={"duplicated_frames": (30, 100)}, right={
        "dropped_frames": (50, 51, 95), "duplicated_frames": (70,)})
    _mkv(left, 0.0, 2.5, tmp_path / "left.mkv")
    _mkv(right, 0.15, 2.65, tmp_path / "right.mkv")
    timing = tmp_path / "timing.json"
    timing.write_text(json.dumps(mt.truth_timing(left, right, 0.0, 0.15)))
    refs = ReferenceMarkers().positions_mm  # given positions this time (mm, the calibration's frame)
    res = measure_videos({"left": tmp_path / "left.mkv", "right": tmp_path / "right.mkv"},
                         site["calibration"], tmp_path / "out", timing=timing,
                         options=MeasureOptions(window_s=WINDOW, reference_markers=refs))
    assert any("given positions" in n for n in res.notes)
    with pytest.raises(SeriesError, match=r"nearest track is .* mm away \(allowed 20 mm\)"):
        reference_tracks(res.tracks, [*refs[:2], (0.0, 0.0, 0.0)])
    frames = json.loads((tmp_path / "out" / "frames.json").read_text())
    assert [d["index"] for d in frames["left"]["duplicated"]] == [31, 102]  # delivered indices
    assert all(d["pts_repeated"] and d["image_repeated"] for d in frames["left"]["duplicated"])
    assert frames["right"]["missing_frames"] == 3
    assert [d["missing_frames"] for d in frames["right"]["dropped"]] == [2, 1]
    assert len(frames["right"]["duplicated"]) == 1
    assert any("duplicated" in n for n in res.notes) and any("dropped" in n for n in res.notes)
    write_measurement_report(tmp_path / "out")  # as `rig measure` does after the measurement
    html = (tmp_path / "out" / "report.html").read_text()
    assert "Duplicated frames and their evidence" in html and "sensor noise not renewed" in html
    _check_targets(res.summary, left.clock_ppm, site["scale_floor"])


def test_truncated_video_keeps_the_partial_result(
        site: dict, tmp_path: Path, measurement_pair: PairOf) -> None:
    left, right = mt.camera_pair(mt.measurement_world())
    paths = tuple(Path(shutil.copy(p, tmp_path)) for p in measurement_pair("MJPG", "avi"))
    data = paths[1].read_bytes()
    paths[1].write_bytes(data[: int(len(data) * 0.7)])
    timing = tmp_path / "timing.json"
    timing.write_text(json.dumps(mt.truth_timing(left, right, 0.0, 0.15)))
    out = tmp_path / "out"
    code = main(["measure", str(paths[0]), str(paths[1]), "--calibration", str(site["calibration"]),
                 "--timing", str(timing), "--out", str(out)])
    assert code == 4
    meta = json.loads((out / "measure.json").read_text())
    assert any("truncated" in p for p in meta["problems"])
    assert "Problems with the inputs" in (out / "report.html").read_text()
    frames = json.loads((out / "frames.json").read_text())
    right = frames["right"]
    assert right["truncated"] and 0 < right["frames_read"] < right["frames_declared"]
    assert (pd.read_csv(out / "tables" / "summary.csv")["role"] == "target").sum() == 5


def test_truncated_mp4_and_missing_or_mismatched_calibration_are_clear_errors(
        site: dict, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    world = mt.measurement_world()
    left, right = mt.camera_pair(world)
    paths = mt.write_pair(left, right, tmp_path, t_left_s=(0.0, 0.5), t_right_s=(0.0, 0.5))
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(paths[1].read_bytes()[:-2000])  # the MP4 index (moov) is written last
    assert main(["measure", str(paths[0]), str(cut), "--calibration", str(site["calibration"]),
                 "--out", str(tmp_path / "o1")]) == 4
    assert "no decoder can open it" in capsys.readouterr().err
    assert main(["measure", str(paths[0]), str(paths[1]), "--calibration", str(tmp_path / "none.json"),
                 "--out", str(tmp_path / "o2")]) == 4
    assert "no calibration file" in capsys.readouterr().err
    cal = json.loads(site["calibration"].read_text())
    cal["cameras"]["right"]["image_size"] = [1920, 1080]
    other = tmp_path / "cal_1080p.json"
    other.write_text(json.dumps(cal))
    with pytest.raises(MeasureError, match=r"960×540 px but .* 1920×1080"):
        measure_videos({"left": paths[0], "right": paths[1]}, other, tmp_path / "o3")


def test_rotor_turning_from_the_first_frame_is_one_track_with_its_radius(site: dict, tmp_path: Path) -> None:
    """The paper's synchronisation target filmed already turning at 10 Hz (≈ 45 px per frame at half size),
    with the timing given: the 2-D tracking follows it as one track per camera, so one 3-D track whose
    amplitude along its principal direction is the radius and whose one significant tone is 10 Hz."""
    from drivers.sim.targets import RotorTarget
    from drivers.sim.world import World, WorldLayout

    world = World(VirtualClock(), seed=5, layout=WorldLayout(initial_scene="rotor"))
    world.rotor.set_frequency(-5.0, 10.0)
    left, right = mt.camera_pair(world)
    paths = mt.write_pair(left, right, tmp_path, t_left_s=(0.0, 1.5), t_right_s=(0.15, 1.65))
    timing = tmp_path / "timing.json"
    timing.write_text(json.dumps(mt.truth_timing(left, right, 0.0, 0.15)))
    res = measure_videos({"left": paths[0], "right": paths[1]}, site["calibration"], tmp_path / "out",
                         timing=timing, options=MeasureOptions())
    targets = res.summary[res.summary["role"] == "target"]
    assert len(targets) == 1 and (res.summary["role"] == "reference").sum() == 4
    row = targets.iloc[0]
    overlap = round((1.5 - 0.15) * 60)  # frames both cameras saw; the sync loses an edge frame or two
    assert row["n_samples"] >= overlap - 3, row["n_samples"]  # the whole record in one track
    radius = RotorTarget().radius_mm
    bias = 4e-3  # the trajectory sync's amplitude bias bound up to 22 Hz (rig/analysis/sync_tracks.py)
    tol_mm = 4 * row["amplitude_std_mm"] + radius * (site["scale_floor"] + bias)
    assert abs(row["amplitude_mm"] - radius) <= tol_mm
    assert abs(row["frequency_hz"] - 10.0) <= 4 * row["frequency_std_hz"] + abs(left.clock_ppm) * 1e-5
    assert res.peaks["frequency_hz"].iloc[0] == pytest.approx(row["frequency_hz"])


def test_markers_too_large_for_the_tracking_window_are_noted_and_logged(
        site: dict, tmp_path: Path, measurement_pair: PairOf, caplog: pytest.LogCaptureFixture) -> None:
    """The twin's markers (≈ 12 px across as measured) in a 15 px window: each camera's note names the size
    and a window that fits; the measurement still runs (the note says what the bias can be)."""
    left, right = mt.camera_pair(mt.measurement_world())
    timing = tmp_path / "timing.json"
    timing.write_text(json.dumps(mt.truth_timing(left, right, 0.0, 0.15)))
    paths = measurement_pair("mp4v", "mp4")
    with caplog.at_level("WARNING", logger="rig.deploy.measure"):
        res = measure_videos({"left": paths[0], "right": paths[1]}, site["calibration"], tmp_path / "out",
                             timing=timing, options=MeasureOptions(window_s=WINDOW,
                                                                   extract=ExtractOptions(window_px=15)))
    notes = [n for n in res.notes if "tracking window of 15 px" in n]
    assert [n.split(":")[0] for n in notes] == ["camera left", "camera right"]
    assert all("--window-px 21 or more" in n for n in notes)  # 12 + 8 px, odd
    assert sum("tracking window of 15 px" in r.getMessage() for r in caplog.records) == 2


def test_the_analysis_runs_on_one_blas_thread_and_restores_the_callers_setting(
        site: dict, tmp_path: Path, measurement_pair: PairOf, monkeypatch: pytest.MonkeyPatch) -> None:
    """The 3-D tracks' many small solves on one BLAS thread (more only spin), whatever the caller had set
    (here 2, on any machine), and the caller's setting back afterwards."""
    left, right = mt.camera_pair(mt.measurement_world())
    timing = tmp_path / "timing.json"
    timing.write_text(json.dumps(mt.truth_timing(left, right, 0.0, 0.15)))
    paths = measurement_pair("mp4v", "mp4")
    seen: list[list[int]] = []
    triangulate = measure_module.triangulate_tracks

    def observed(*args: object, **kwargs: object) -> pd.DataFrame:
        seen.append([pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"])
        return triangulate(*args, **kwargs)

    monkeypatch.setattr(measure_module, "triangulate_tracks", observed)
    with threadpool_limits(limits=2, user_api="blas"):
        measure_videos({"left": paths[0], "right": paths[1]}, site["calibration"], tmp_path / "out",
                       timing=timing, options=MeasureOptions(window_s=WINDOW))
        after = [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]
    assert len(seen) == 1 and seen[0] and set(seen[0]) == {1}
    assert after and set(after) == {2}
