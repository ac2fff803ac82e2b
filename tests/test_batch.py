"""``rig batch`` on a small archive written by the twin: the same results as ``rig measure`` per segment,
on the embedded LocalCluster and on a real external Dask scheduler with two workers; a corrupt segment is
reported and the rest complete; a batch killed with SIGKILL is resumed without redoing finished tasks.

The estimated timing is most of a task's CPU (≈ 10 of 11 CPU-s): it is estimated where it is tested (pair
p2 of the shared batch: the trend and the timing continuity); elsewhere the pair's ``timing.json`` (the
manifest's ``timing``, as ``rig measure --timing``) stands in for it."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
from batch_archive import Archive, write_archive

from rig.deploy.batch import plan, run_batch, target_trend, timing_continuity
from rig.deploy.batch_manifest import ManifestError, load_manifest, match_segments, segment_start_utc
from rig.deploy.measure import MeasureOptions, measure_videos

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
WAIT_S = 900.0  # generous bounds for a loaded machine; the tests synchronise on files, not on time
SLOW_TIMEOUT_S = 1200  # a batch is minutes of CPU on a loaded 2-core machine


@pytest.fixture(scope="module")
def archive(tmp_path_factory: pytest.TempPathFactory, calibrated_site: dict) -> Archive:
    return write_archive(tmp_path_factory.mktemp("archive"), calibrated_site["calibration"])


@pytest.fixture(scope="module")
def local_batch(archive: Archive, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Both pairs: p1 measured with its timing.json, p2 with each segment's timing estimated."""
    out = tmp_path_factory.mktemp("batch") / "out"
    report = run_batch(load_manifest(archive.manifest_mixed), out, n_workers=2, say=lambda text: None)
    assert len(report.done) == 5 and not report.failed and not report.unmatched
    return out


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(ROOT / "tests")])}


# ---------------------------------------------------------------------------- manifest
def test_segment_start_times_come_from_the_file_names(tmp_path: Path) -> None:
    assert segment_start_utc(Path("cam_20261201-120000.mp4")).isoformat() == "2026-12-01T12:00:00+00:00"
    assert segment_start_utc(Path("x/20261201T235959_left.avi")).hour == 23
    with pytest.raises(ManifestError, match="no start time"):
        segment_start_utc(Path("left.mp4"))
    with pytest.raises(ManifestError, match="not a date"):
        segment_start_utc(Path("cam_20261341-120000.mp4"))


def test_unmatched_segments_are_reported_not_dropped(archive: Archive, tmp_path: Path) -> None:
    manifest = load_manifest(archive.manifest)
    pair = manifest.pairs[0]
    matched, alone = match_segments(pair.left, pair.right[:-1], tolerance_s=1.0)
    assert len(matched) == len(pair.left) - 1 and alone == [pair.left[-1]]
    tasks, unmatched = plan(manifest)
    assert len(tasks) == 5 and unmatched == []


def test_a_given_timing_is_an_input_of_each_task(archive: Archive) -> None:
    given, _ = plan(load_manifest(archive.manifest_of["p1"]))
    estimated = [t for t in plan(load_manifest(archive.manifest))[0] if t.pair == "p1"]
    assert [t.timing for t in given] == [archive.timing_of["p1"]] * 3
    assert [t.timing for t in estimated] == [None] * 3
    assert not {t.task_id for t in given} & {t.task_id for t in estimated}  # other inputs, other tasks


P1 = ("[[sites]]\nname = 's'\n[[sites.pairs]]\nname = 'p'\ncalibration = 'calibration.json'\n"
      "left = ['p1/left/*.mp4']\nright = ['p1/right/*.mp4']\n")


@pytest.mark.parametrize(("text", "field"), [
    ("[batch]\nname = 'x'\nspeed = 3\n", "batch.speed"),
    ("[batch]\nmax_retries = 99\n[[sites]]\nname = 's'\n", "batch.max_retries"),
    ("[[sites]]\nname = 'bad name!'\n", "sites[0].name"),
    ("[[sites]]\nname = 's'\n[[sites.pairs]]\nname = 'p'\ncalibration = 'nope.json'\nleft = ['a']\n"
     "right = ['b']\n", "sites[0].pairs[0].calibration"),
    ("[[sites]]\nname = 's'\n[[sites.pairs]]\nname = 'p'\ncalibration = 'calibration.json'\n"
     "left = ['none/*.mp4']\nright = ['p1/right/*.mp4']\n", "sites[0].pairs[0].left"),
    ("[[sites]]\nname = 's'\n[[sites.pairs]]\nname = 'p'\ncalibration = 'calibration.json'\n"
     "left = ['p1/left/*.mp4']\nright = ['p1/right/*.mp4']\nsync = 'magic'\n", "sites[0].pairs[0].sync"),
    *((f"{P1}timing = '{name}'\n", "sites[0].pairs[0].timing")  # missing, not a timing, other cameras
      for name in ("none.json", "calibration.json", "cams.json")),
])
def test_a_malformed_manifest_names_the_field(archive: Archive, text: str, field: str) -> None:
    timing = json.loads(archive.timing_of["p1"].read_text())
    timing["offset_s"] = {"left": 0.0, "centre": 0.1}  # cameras a pair's videos are not
    (archive.folder / "cams.json").write_text(json.dumps(timing))
    path = archive.folder / "bad.toml"
    path.write_text(text)
    with pytest.raises(ManifestError) as err:
        load_manifest(path)
    assert err.value.field == field


# ---------------------------------------------------------------------------- the batch
@pytest.mark.slow
@pytest.mark.timeout(SLOW_TIMEOUT_S)
def test_batch_gives_the_results_of_rig_measure_per_segment(archive: Archive, local_batch: Path,
                                                             tmp_path: Path) -> None:
    segments = pd.read_parquet(local_batch / "segments")
    assert set(segments["pair"].astype(str)) == {"p1", "p2"} and segments["task_id"].nunique() == 5
    (task, *_), _ = plan(load_manifest(archive.manifest_mixed))
    assert task.pair == "p1" and task.timing == archive.timing_of["p1"]
    alone = measure_videos({"left": task.left, "right": task.right}, archive.calibration, tmp_path / "alone",
                           timing=archive.timing_of["p1"], options=MeasureOptions())
    mine = segments[segments["task_id"] == task.task_id].sort_values("track_id")
    expected = alone.summary.sort_values("track_id")
    for column in ("amplitude_mm", "frequency_hz", "rms_mm", "x_mm", "z_mm"):
        assert mine[column].to_numpy() == pytest.approx(expected[column].to_numpy(), rel=1e-12, nan_ok=True)
    series = pd.read_parquet(local_batch / "displacement", filters=[("task_id", "==", task.task_id)])
    assert len(series) == len(alone.displacement)
    # the series starts where both cameras film: the right one starts offset_s after the left (the file
    # name's time), the first 3-D sample comes within a frame of it
    offset_s = json.loads(archive.timing_of["p1"].read_text())["offset_s"]["right"]
    first_s = (series["time_utc"].min() - pd.Timestamp(task.start_utc)).total_seconds()
    assert offset_s - 1 / 60 < first_s < offset_s + 1 / 60


@pytest.mark.slow
@pytest.mark.timeout(SLOW_TIMEOUT_S)
def test_trend_follows_each_target_over_the_archive(archive: Archive, local_batch: Path) -> None:
    trend = target_trend(local_batch)
    for pair, frequency_hz in archive.frequency_hz.items():
        rows = trend[trend["pair"] == pair]
        assert sorted(set(rows["target"])) == ["T1", "T2", "T3", "T4", "T5"]  # the column's five markers
        assert rows.groupby("target")["segment_start_utc"].nunique().eq(rows["task_id"].nunique()).all()
        # 1 %: the deployment target for amplitudes to 10 Hz; the twin's noise gives ≈ 0.5 % on 2 s segments
        assert rows["amplitude_mm"].to_numpy() == pytest.approx(archive.amplitude_mm, rel=0.01)
        assert rows["frequency_hz"].to_numpy() == pytest.approx(frequency_hz, rel=1e-3)
    # each estimated offset is the true one (its first segment's; 47 ppm of drift over the archive moves it
    # < 0.2 ms) — or a whole period of the steady 7 Hz away, and then the segment states the candidates
    segments = pd.read_parquet(local_batch / "segments").drop_duplicates("task_id")
    estimated = segments[segments["pair"].astype(str) == "p2"]
    true_s = json.loads(archive.timing_of["p2"].read_text(encoding="utf-8"))["offset_s"]["right"]
    period_s = 1.0 / archive.frequency_hz["p2"]
    assert len(estimated) == 2
    for offset_s, candidates in estimated[["offset_s", "offset_candidates"]].itertuples(index=False):
        periods = round((offset_s - true_s) / period_s)
        assert abs(offset_s - true_s - periods * period_s) < 0.5e-3
        assert periods == 0 or candidates > 1, (offset_s, true_s, candidates)
    assert segments[segments["pair"].astype(str) == "p1"]["offset_candidates"].isna().all()  # given
    continuity = pd.read_csv(local_batch / "continuity.csv")
    assert set(continuity["pair"]) == {"p2"}  # p1's timing was given, not estimated: nothing to check
    assert len(continuity) == 2 and not continuity["jump"].any()  # the twin's cameras run on unbroken


def test_a_timing_jump_between_segments_is_reported() -> None:
    base = {"site": "s", "pair": "p", "u_offset_s": 1e-5, "drift_ppm": 50.0, "u_drift_ppm": 1.0,
            "line_time_s": 0.0}
    outcomes = [{"task_id": f"t{k}", "start_utc": f"2026-12-01T12:{k:02d}:00+00:00",
                 "timing": {**base, "offset_s": 0.004 + 50e-6 * 60 * k + (0.003 if k == 3 else 0.0)}}
                for k in range(5)]
    for outcome in outcomes:
        outcome.update(site="s", pair="p")
    table = timing_continuity(outcomes)
    assert table["jump"].tolist() == [False, False, False, True, True]  # into and out of the jumped one
    assert table["residual_s"].iloc[3] == pytest.approx(0.003, abs=1e-6)
    assert table["pair_drift_ppm"].iloc[0] == pytest.approx(50.0)


@pytest.mark.slow
@pytest.mark.timeout(SLOW_TIMEOUT_S)
def test_a_rerun_skips_finished_tasks(archive: Archive, local_batch: Path) -> None:
    stamps = {p: p.stat().st_mtime_ns for p in (local_batch / "tasks").iterdir()}
    report = run_batch(load_manifest(archive.manifest_mixed), local_batch, say=lambda text: None)
    assert len(report.skipped) == 5 and report.done == [] and not report.failed
    assert {p: p.stat().st_mtime_ns for p in (local_batch / "tasks").iterdir()} == stamps
    starts = [json.loads(line) for line in (local_batch / "batch.jsonl").read_text().splitlines()]
    assert [d["type"] for d in starts].count("start") == 2


@pytest.mark.slow
@pytest.mark.timeout(SLOW_TIMEOUT_S)
def test_a_corrupt_segment_is_reported_and_the_rest_complete(archive: Archive, tmp_path: Path) -> None:
    folder = tmp_path / "archive"
    shutil.copytree(archive.folder, folder, ignore=shutil.ignore_patterns("demo"))
    broken = sorted((folder / "p2" / "right").iterdir())[0]
    broken.write_bytes(b"\x00\x01 not a video " * 1000)
    out = tmp_path / "out"
    # one LocalCluster worker: the retry and the other task need no second one (each is a nanny and a worker
    # process importing the stack); the two-worker cluster is local_batch's
    report = run_batch(load_manifest(folder / "manifest_p2.toml"), out, n_workers=1, say=lambda text: None)
    assert len(report.done) == 1 and len(report.failed) == 1
    (error,) = report.failed.values()
    assert broken.name in error
    docs = [json.loads(line) for line in (out / "batch.jsonl").read_text().splitlines()]
    failed = [d for d in docs if d["type"] == "task" and d["status"] == "failed"]
    assert len(failed) == 1 and failed[0]["attempts"] == 2 and failed[0]["right"] == str(broken)


@pytest.mark.slow
@pytest.mark.timeout(SLOW_TIMEOUT_S)
def test_batch_through_an_external_scheduler_with_two_workers(archive: Archive, tmp_path: Path) -> None:
    scheduler_file = tmp_path / "scheduler.json"
    procs = [subprocess.Popen([str(BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", "0",
                               "--no-dashboard", "--scheduler-file", str(scheduler_file)],
                              env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        _wait_for(lambda: scheduler_file.is_file() and scheduler_file.stat().st_size > 0)
        address = json.loads(scheduler_file.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        # without a nanny: each worker one process (a nanny doubles the processes importing the stack)
        worker = [str(BIN / "dask"), "worker", address, "--no-nanny", "--nthreads", "1",
                  "--no-dashboard", "--host", "127.0.0.1"]
        procs += [subprocess.Popen(worker, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                  for _ in range(2)]
        out = tmp_path / "out"
        argv = [sys.executable, "-m", "rig.cli", "batch", str(archive.manifest_of["p2"]), "--out", str(out),
                "--scheduler", address]
        done = subprocess.run(argv, env=_env(), capture_output=True, text=True, timeout=WAIT_S, check=False)
        assert done.returncode == 0, done.stderr[-2000:]
        assert "2 tasks done" in done.stdout and address in done.stdout
        assert len(list((out / "tasks").iterdir())) == 2 and (out / "trend.png").is_file()
    finally:
        # one at a time, the workers first, while the scheduler still takes their goodbye: a worker without
        # a nanny terminated together with its scheduler was seen (CI, load 2) retrying it for over 60 s
        for proc in reversed(procs):
            proc.terminate()
            try:
                proc.wait(timeout=60)
            except subprocess.TimeoutExpired:  # the teardown is not what this test checks: no process is left
                proc.kill()
                proc.wait(timeout=60)


@pytest.mark.slow
@pytest.mark.timeout(SLOW_TIMEOUT_S)
def test_kill_9_then_rerun_completes_without_redoing_finished_tasks(archive: Archive, tmp_path: Path) -> None:
    out = tmp_path / "out"
    argv = [sys.executable, "-m", "rig.cli", "batch", str(archive.manifest_of["p1"]), "--out", str(out),
            "--workers", "1"]
    proc = subprocess.Popen(argv, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        # killed as soon as one task is done: the two others take ≥ 2 CPU-s more on the one worker
        _wait_for(lambda: (out / "tasks").is_dir() and bool(_final(out / "tasks", "*.json")), poll_s=0.02)
        os.killpg(proc.pid, signal.SIGKILL)  # the batch and its LocalCluster's processes, at once
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    finished = {p.name: p.stat().st_mtime_ns for p in _final(out / "tasks", "*.json")}
    assert 1 <= len(finished) < 3
    done = subprocess.run(argv, env=_env(), capture_output=True, text=True, timeout=WAIT_S, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    assert f"{len(finished)} skipped as done before" in done.stdout
    assert {n: (out / "tasks" / n).stat().st_mtime_ns for n in finished} == finished
    assert len(_final(out / "tasks", "*.json")) == 3
    for path in _final(out, "**/*.parquet"):  # a file killed half-written never has its final name
        pd.read_parquet(path)


def _final(folder: Path, pattern: str) -> list[Path]:
    """The files matching ``pattern`` under their final names: pathlib's ``*`` also matches the atomic
    writer's temporaries (``.stem.<hex>.tmp.json``: dot names), which a SIGKILL can leave half-written."""
    return [p for p in folder.glob(pattern) if not p.name.startswith(".")]


def _wait_for(condition, timeout_s: float = WAIT_S, poll_s: float = 0.2) -> None:
    end = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < end, "timed out (the machine may be very loaded)"
        time.sleep(poll_s)
