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
Run: .venv/bin/python benchmarks/batch.py [--segments 3] [--segment-s 2]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import batch_archive  # noqa: E402

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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--segments", type=int, default=3, help="segments per camera pair")
    parser.add_argument("--segment-s", type=float, default=2.0, help="length of a segment, s")
    args = parser.parse_args(argv)
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
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
