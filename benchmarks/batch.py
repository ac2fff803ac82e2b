"""Benchmark of ``rig batch``: throughput with 1 and 2 Dask workers, scaling, and the engine's overhead.

An archive written by the twin (tests/batch_archive.py: two camera pairs of half-size 960 × 540 cameras,
``--segments`` segments of ``--segment-s`` seconds each per pair, a 5-marker column and 4 references) is
measured three ways, each into a fresh output folder:

  loop       the same task function (``rig.deploy.batch.run_task``) called in a plain loop in this process:
  the
             baseline, no engine
  dask×1     ``run_batch`` on a LocalCluster with 1 worker process
  dask×2     ``run_batch`` on a LocalCluster with 2 worker processes (one per core here)

Prints, per way: wall time, seconds of video per second of wall time (×real time), and for the loop its CPU
time per second of video (what one core costs, nearly independent of other load). Then the scaling efficiency
(dask×2 throughput / (2 × dask×1)), the engine's overhead per task against the loop ((dask×1 − loop) / tasks,
cluster start included and excluded), and a sizing table: cores needed to keep up with K camera pairs
filming 1080p60 around the clock, from the measured per-core CPU cost scaled by the pixel count (×4 for
1080p against the benchmark's 960 × 540) and the measured scaling efficiency.

Windows of a long recording (``--long-s`` s, one pair, ``window_s`` = ``--window-s``, ``overlap_s`` = 1 s):
the wall and CPU time to reach and read each window's frames (core ± overlap, both cameras) by the reader
as it was, decoding every frame from the file's first and passing over those before the window, against a
verified frame-exact seek (drivers/camera/seek.py, ``VideoFile.frames(start_s)``), the same frames
delivered (checked). ``--windows-only`` runs this part alone.
Run: .venv/bin/python benchmarks/batch.py [--segments 3] [--segment-s 2] [--long-s 32] [--window-s 4]
[--windows-only]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import batch_archive  # noqa: E402

from drivers.camera.video_file import VideoFile  # noqa: E402
from rig.deploy.batch import dask_client, plan, run_batch, run_task  # noqa: E402
from rig.deploy.batch_manifest import load_manifest  # noqa: E402

FULL_HD_PIXEL_RATIO = (1920 * 1080) / (960 * 540)


def _loop(tasks: list, out: Path) -> tuple[float, float, float]:
    """Wall s, CPU s of this process and seconds of video for the tasks run one after the other."""
    t0, c0 = time.perf_counter(), time.process_time()
    video_s = sum(run_task(task, str(out))["video_s"] for task in tasks)
    return time.perf_counter() - t0, time.process_time() - c0, video_s


def _dask(manifest_path: Path, out: Path, workers: int) -> tuple[float, float]:
    """Wall s (cluster start included) and seconds of video of a batch on ``workers`` local workers."""
    t0 = time.perf_counter()
    report = run_batch(load_manifest(manifest_path), out, n_workers=workers, say=lambda text: None)
    if report.failed:
        raise RuntimeError(f"tasks failed: {report.failed}")
    return time.perf_counter() - t0, report.video_seconds


def _read_window(path: Path, start_s: float, stop_s: float, *, seek: bool) -> tuple[float, float, list[int]]:
    """Wall s and CPU s (this process, decoder threads included) to reach and read the frames stamped
    within [start_s, stop_s], and their indices: by a seek, or (seek False) decoding from the first frame
    and passing over the earlier ones."""
    t0, c0 = time.perf_counter(), time.process_time()
    indices = []
    for frame in VideoFile(path).frames(start_s if seek else None):
        if frame.timestamp_s > stop_s:
            break
        if frame.timestamp_s >= start_s:
            indices.append(frame.index)
    return time.perf_counter() - t0, time.process_time() - c0, indices


def windows_benchmark(root: Path, long_s: float, window_s: float, overlap_s: float = 1.0) -> None:
    """Reading the windows of a long recording (both cameras) with and without seeking."""
    batch_archive.write_long_pair(root, long_s)
    manifest = root / "manifest.toml"
    manifest.write_text(f'[batch]\nname = "long"\nmax_retries = 0\n\n[[sites]]\nname = "bridge"\n\n'
                        f'[[sites.pairs]]\nname = "pier"\ncalibration = "calibration.json"\n'
                        f'left = ["pair/left/*.mp4"]\nright = ["pair/right/*.mp4"]\n'
                        f"window_s = {window_s}\noverlap_s = {overlap_s}\n", encoding="utf-8")
    tasks, _ = plan(load_manifest(manifest))
    print(f"\nwindows: a {long_s:g} s recording per camera (960 × 540, 60 FPS, MP4 mp4v), {len(tasks)} "
          f"windows of {window_s:g} s ± {overlap_s:g} s; reading a window's frames, both cameras")
    print(f"{'window':>6s} {'from s':>6s} {'decode from 0: wall s':>21s} {'CPU s':>6s} "
          f"{'seek: wall s':>12s} {'CPU s':>6s} {'× (CPU)':>7s}")
    totals = np.zeros(4)
    for k, task in enumerate(tasks):
        assert task.core_s is not None
        start_s = max(0.0, task.core_s[0] - overlap_s)
        stop_s = task.core_s[1] + overlap_s
        row = np.zeros(4)
        for path in (task.left, task.right):
            wall_before, cpu_before, want = _read_window(path, start_s, stop_s, seek=False)
            wall_after, cpu_after, got = _read_window(path, start_s, stop_s, seek=True)
            if got != want:
                raise RuntimeError(f"{path}: the seek delivered frames {got[:3]}… instead of {want[:3]}…")
            row += (wall_before, cpu_before, wall_after, cpu_after)
        totals += row
        print(f"{k:6d} {start_s:6.1f} {row[0]:21.2f} {row[1]:6.2f} {row[2]:12.2f} {row[3]:6.2f} "
              f"{row[1] / row[3]:7.2f}")
    print(f"{'all':>6s} {'':6s} {totals[0]:21.2f} {totals[1]:6.2f} {totals[2]:12.2f} {totals[3]:6.2f} "
          f"{totals[1] / totals[3]:7.2f}  (the same frames delivered both ways)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--segments", type=int, default=3, help="segments per camera pair")
    parser.add_argument("--segment-s", type=float, default=2.0, help="length of a segment, s")
    parser.add_argument("--long-s", type=float, default=32.0, help="length of the long recording, s")
    parser.add_argument("--window-s", type=float, default=4.0, help="window of the long recording, s")
    parser.add_argument("--windows-only", action="store_true", help="only the long recording's windows")
    args = parser.parse_args(argv)
    print(f"load average {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    if args.windows_only:
        with tempfile.TemporaryDirectory(prefix="rig-batch-windows-") as tmp:
            windows_benchmark(Path(tmp), args.long_s, args.window_s)
        return 0
    batch_archive.SEGMENT_S = args.segment_s
    batch_archive.PAIRS = {"p1": (5.0, args.segments, 11), "p2": (7.0, args.segments, 12)}
    with tempfile.TemporaryDirectory(prefix="rig-batch-bench-") as tmp:
        root = Path(tmp)
        archive = batch_archive.write_archive(root / "archive")
        tasks, _ = plan(load_manifest(archive.manifest))
        print(f"archive: {len(tasks)} segment pairs of {args.segment_s:g} s (960 × 540, 60 FPS)")
        loop_wall, loop_cpu, video_s = _loop(tasks, root / "loop")
        one_wall, _ = _dask(archive.manifest, root / "dask1", 1)
        two_wall, _ = _dask(archive.manifest, root / "dask2", 2)
        t0 = time.perf_counter()
        with dask_client(None, 1):
            pass
        start_s = time.perf_counter() - t0  # a LocalCluster of one worker started and stopped
    rows = (("loop (baseline)", loop_wall), ("dask×1", one_wall), ("dask×2", two_wall))
    print(f"{'way':16s} {'wall s':>8s} {'× real time':>12s}")
    for name, wall in rows:
        print(f"{name:16s} {wall:8.1f} {video_s / wall:12.2f}")
    cpu_per_video_s = loop_cpu / video_s
    efficiency = (video_s / two_wall) / (2 * video_s / one_wall)
    print(f"loop CPU: {cpu_per_video_s:.2f} CPU-s per s of video (960 × 540)")
    print(f"scaling efficiency 1 → 2 workers: {efficiency:.2f}; dask×1 / loop = {one_wall / loop_wall:.2f}")
    # a worker is one single-threaded process (Dask sets its BLAS/OpenCV threads to 1), while the loop's
    # task decodes its two videos on two threads: dask×1 − loop is that parallelism plus the engine's cost
    print(f"dask×1 − loop per task: {(one_wall - loop_wall) / len(tasks):+.2f} s with the cluster's start, "
          f"{(one_wall - start_s - loop_wall) / len(tasks):+.2f} s without (a 1-worker LocalCluster starts "
          f"and stops in {start_s:.1f} s; the loop used {loop_cpu / loop_wall:.2f} cores, a worker uses 1)")
    print(f"dask×2 / loop (both using the two cores): {two_wall / loop_wall:.2f}")
    per_core_1080 = 1.0 / (cpu_per_video_s * FULL_HD_PIXEL_RATIO)  # s of 1080p video per CPU-s
    print("sizing (1080p60 around the clock; per-core cost scaled ×4 by pixels, efficiency as measured):")
    print(f"{'camera pairs':>12s} {'cores to keep up':>17s}")
    for pairs in (1, 2, 5, 10, 20):
        cores = pairs / (per_core_1080 * max(min(efficiency, 1.0), 0.1))
        print(f"{pairs:12d} {cores:17.1f}")
    with tempfile.TemporaryDirectory(prefix="rig-batch-windows-") as tmp:
        windows_benchmark(Path(tmp), args.long_s, args.window_s)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
