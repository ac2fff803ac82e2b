"""``rig batch`` splits a long recording into windows with an overlap: each window a task running
``rig measure``'s code, trimmed back to its core; together they give what ``rig measure`` gives on the whole
file (a twin-written recording), and the windows' timing is checked for continuity like segments'."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from batch_archive import write_long_pair

from rig.deploy.batch import plan, run_batch, timing_continuity, windows
from rig.deploy.batch_manifest import ManifestError, load_manifest
from rig.deploy.measure import MeasureOptions, MeasureResult, measure_videos

# three windows (the first, a middle one overlapped at both ends, the last with the tail) of ≥ 1 s (the
# manifest's least); the overlap longer than the band-limited kernel's half-width (32 frames, 0.53 s)
SECONDS = 4.5
WINDOW_S = 1.5
OVERLAP_S = 0.6


def _manifest(folder: Path, window_s: float = WINDOW_S, overlap_s: float = OVERLAP_S) -> Path:
    path = folder / "manifest.toml"
    path.write_text(f'[batch]\nname = "long"\nmax_retries = 0\n\n[[sites]]\nname = "bridge"\n\n'
                    f'[[sites.pairs]]\nname = "pier"\ncalibration = "calibration.json"\n'
                    f'left = ["pair/left/*.mp4"]\nright = ["pair/right/*.mp4"]\n'
                    f"window_s = {window_s}\noverlap_s = {overlap_s}\n", encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def long_pair(tmp_path_factory: pytest.TempPathFactory, calibrated_site: dict) -> Path:
    folder = tmp_path_factory.mktemp("long")
    write_long_pair(folder, SECONDS, calibration=calibrated_site["calibration"])
    return folder


@pytest.fixture(scope="module")
def whole(long_pair: Path, tmp_path_factory: pytest.TempPathFactory) -> MeasureResult:
    (task,), _ = plan(load_manifest(_manifest(long_pair, window_s=0.0)))
    return measure_videos({"left": task.left, "right": task.right}, long_pair / "calibration.json",
                          tmp_path_factory.mktemp("whole"), options=MeasureOptions())


def test_windows_cover_a_recording_once() -> None:
    assert windows(6.0, 2.0) == [(0.0, 2.0), (2.0, 4.0), (4.0, math.inf)]
    assert windows(7.9, 2.0) == [(0.0, 2.0), (2.0, 4.0), (4.0, math.inf)]  # the last takes the tail
    assert windows(3.9, 2.0) == [(0.0, math.inf)]  # shorter than two windows: one task
    assert windows(100.0, 0.0) == [(0.0, math.inf)]


def test_continuity_reads_window_starts_at_fractions_of_a_second() -> None:
    # windows of 1.5 s start at 12:00:00, 12:00:01.5, 12:00:03 (isoformat drops a zero fraction): every
    # start is read, the steps are 1.5 s, and a drift of 50 ppm over them is no jump
    timing = {"u_offset_s": 1e-5, "drift_ppm": 50.0, "u_drift_ppm": 1.0, "line_time_s": 0.0}
    outcomes = [{"site": "s", "pair": "p", "task_id": f"w{k}",
                 "start_utc": (pd.Timestamp("2026-12-01T12:00:00+00:00")
                               + pd.Timedelta(seconds=1.5 * k)).isoformat(),
                 "timing": {**timing, "offset_s": 0.004 + 50e-6 * 1.5 * k}} for k in range(3)]
    assert outcomes[1]["start_utc"] == "2026-12-01T12:00:01.500000+00:00"
    table = timing_continuity(outcomes)
    assert table["task_id"].tolist() == ["w0", "w1", "w2"] and not table["jump"].any()
    assert table["residual_s"].iloc[1:].to_numpy() == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize(("fields", "field"), [("window_s = 0.5", "window_s"),
                                              ("window_s = 10.0\noverlap_s = 5.0", "overlap_s"),
                                              ("window_s = -1.0", "window_s")])
def test_a_bad_window_names_the_field(long_pair: Path, tmp_path: Path, fields: str, field: str) -> None:
    text = _manifest(long_pair).read_text(encoding="utf-8")
    text = text.split("window_s")[0] + fields + "\n"
    (tmp_path / "pair").symlink_to(long_pair / "pair")
    (tmp_path / "calibration.json").symlink_to(long_pair / "calibration.json")
    path = tmp_path / "manifest.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ManifestError, match=field):
        load_manifest(path)


def _nearest_track(series: pd.DataFrame, xyz: np.ndarray) -> pd.DataFrame:
    rest = series.groupby("track_id")[["x_mm", "y_mm", "z_mm"]].median()
    tid = rest.index[np.argmin(np.linalg.norm(rest.to_numpy(float) - xyz, axis=1))]
    return series[series["track_id"] == tid]


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_windows_give_the_whole_file_measurement(long_pair: Path, whole: MeasureResult,
                                                 tmp_path: Path) -> None:
    manifest = load_manifest(_manifest(long_pair))
    tasks, _ = plan(manifest)
    assert [t.core_s for t in tasks] == [(0.0, 1.5), (1.5, 3.0), (3.0, math.inf)]
    # one LocalCluster worker: the windows' results do not depend on where they ran, and under xdist the
    # second worker only adds a process importing the stack (test_batch.py's local_batch runs two)
    report = run_batch(manifest, tmp_path / "out", n_workers=1, say=lambda text: None)
    assert len(report.done) == 3 and not report.failed and not report.jumps
    series = pd.read_parquet(tmp_path / "out" / "displacement")
    summary = pd.read_parquet(tmp_path / "out" / "segments")
    ref = whole.displacement
    targets = ref[ref["role"] == "target"]
    for tid, track in targets.groupby("track_id"):
        rest = track[["x_mm", "y_mm", "z_mm"]].median().to_numpy(float)
        # the whole file's per-sample noise of this target: from second differences (the motion, smooth at
        # 60 frames/s, cancels to first order; var(Δ²x) = 6σ² for white noise)
        noise_mm = float(np.nanstd(np.diff(track["x_mm"].to_numpy(float), 2)) / np.sqrt(6.0))
        joined = []
        for task in tasks:
            mine = _nearest_track(series[series["task_id"] == task.task_id], rest)
            assert task.core_s is not None
            lo, hi = task.core_s
            assert mine["time_s"].min() >= lo and mine["time_s"].max() < hi  # trimmed to the core
            joined.append(mine)
        windowed = pd.concat(joined).sort_values("time_s")
        assert windowed["time_s"].is_unique  # no sample twice where windows meet
        both = track.merge(windowed, on="time_s", suffixes=("", "_w"))
        assert len(both) >= 0.97 * len(track)  # every instant of the whole file, but a few at the ends
        for axis in ("x_mm", "y_mm", "z_mm"):
            diff = both[axis] - both[f"{axis}_w"]
            # the same pixels measured: the windows differ from the whole file by their own timing estimate
            # and reference pose, each far below one sample's noise
            assert float(np.sqrt(np.nanmean(diff**2))) < noise_mm, (tid, axis)
        row = whole.summary[whole.summary["track_id"] == tid].iloc[0]
        for task in tasks:
            mine = _nearest_track(summary[summary["task_id"] == task.task_id], rest).iloc[0]
            # each window's sine fit (1.5 s) against the whole file's (4.5 s): within the deployment targets
            # the segment tests hold (1 % amplitude, 1e-3 frequency; here at most ≈ 0.5 % and 4.5e-4)
            assert mine["amplitude_mm"] == pytest.approx(row["amplitude_mm"], rel=0.01), (tid, task.core_s)
            assert mine["frequency_hz"] == pytest.approx(row["frequency_hz"], rel=1e-3), (tid, task.core_s)
    continuity = pd.read_csv(tmp_path / "out" / "continuity.csv")
    assert len(continuity) == 3 and not continuity["jump"].any()
