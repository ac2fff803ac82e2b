"""Throughput of ``rig measure`` on two 1080p60 videos written by the twin.

Prints, for ``--seconds`` of video per camera (default 5 s, MP4 'mp4v'):

- decoding alone, per video: the naive path (BGR frames, then ``cvtColor`` to grey) and ours (the decoder's
  luma plane, :class:`drivers.camera.video_file.VideoFile`), in frames per second;
- ``rig measure`` with a given timing.json: wall time, seconds of video per second of processing (both
  videos together: target ≥ 2× real time on this 2-core machine), the share of time spent decoding and
  marker extraction as a fraction of decoding (target < 1/3);
- the one-off cost of ``--estimate-timing`` (the joint timing estimate) separately.

Run: ``.venv/bin/python benchmarks/measure.py [--seconds 5] [--keep DIR] [--reuse]`` (``--reuse``: the
videos already in ``--keep``). Figures depend on what else runs on the machine: compare the ratios.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import cv2

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import measure_twin as mt  # noqa: E402

from drivers.camera.video_file import VideoFile  # noqa: E402
from rig.measure import MeasureOptions, measure_videos  # noqa: E402
from rig.onsite_calibration import calibrate_from_videos, write_calibration  # noqa: E402
from rig.video_markers import extract_video  # noqa: E402


def decode_naive(path: Path) -> tuple[int, float]:
    cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    n, t0 = 0, time.perf_counter()
    while True:
        ok, img = cap.read()
        if not ok:
            break
        cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        n += 1
    cap.release()
    return n, time.perf_counter() - t0


def decode_ours(path: Path) -> tuple[int, float]:
    t0 = time.perf_counter()
    n = sum(1 for _ in VideoFile(path).frames())
    return n, time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=5.0, help="video length per camera, s")
    ap.add_argument("--keep", type=Path, help="write the videos and outputs here (default: a temp folder)")
    ap.add_argument("--reuse", action="store_true", help="reuse the videos and calibration in --keep")
    args = ap.parse_args(argv)
    folder = args.keep or Path(tempfile.mkdtemp(prefix="bench-measure-"))
    folder.mkdir(parents=True, exist_ok=True)

    t0 = time.perf_counter()
    world = mt.measurement_world()
    left, right = mt.camera_pair(world, scale=1.0)
    paths = folder / "left.mp4", folder / "right.mp4"
    calibration = folder / "calibration.json"
    if not (args.reuse and calibration.is_file() and all(p.is_file() for p in paths)):
        write_videos(folder, args.seconds)
    print(f"twin videos ready in {time.perf_counter() - t0:.1f} s ({folder})")
    (folder / "timing.json").write_text(json.dumps(mt.truth_timing(left, right, 0.0, 0.15)))
    return run(folder, paths, calibration, args.seconds, left=left, right=right)


def write_videos(folder: Path, seconds: float) -> None:
    """Calibration videos → calibration.json, and the measurement videos (1080p60, MP4)."""
    world, truth, t_end = mt.calibration_world()
    left, right = mt.camera_pair(world, scale=1.0)
    left.write_video(folder / "cal_left.mp4", 0.0, t_end)
    right.write_video(folder / "cal_right.mp4", 0.0, t_end)
    cal = calibrate_from_videos({"left": folder / "cal_left.mp4", "right": folder / "cal_right.mp4"},
                                mt.write_target(folder / "target.toml", truth))
    write_calibration(cal, folder / "calibration.json")
    world = mt.measurement_world()
    left, right = mt.camera_pair(world, scale=1.0)
    mt.write_pair(left, right, folder, t_left_s=(0.0, seconds), t_right_s=(0.15, 0.15 + seconds))


def run(folder: Path, paths: tuple[Path, Path], calibration: Path, seconds: float, *, left: object,
        right: object) -> int:
    """Decode and measure; print the figures."""
    print("\ndecoding one 1080p video (frames/s, single thread)")
    for name, fn in (("naive BGR + cvtColor", decode_naive), ("luma plane (ours)", decode_ours)):
        n, dt = fn(paths[0])
        print(f"  {name:<22} {n / dt:7.1f} fps  ({n} frames in {dt:.2f} s)")

    vo = extract_video(paths[0], "left")
    n = vo.timings_s["frames"]
    print(f"  one video, one thread: decoding {vo.timings_s['decode'] / n * 1e3:.2f} ms/frame, marker "
          f"extraction {vo.timings_s['extract'] / n * 1e3:.2f} ms/frame = "
          f"{vo.timings_s['extract'] / vo.timings_s['decode']:.2f} × decoding   (target < 0.33)")

    video_s = 2 * seconds
    opts = MeasureOptions(make_figures=True, window_s=(0.6, seconds - 0.1))
    t0 = time.perf_counter()
    res = measure_videos({"left": paths[0], "right": paths[1]}, calibration, folder / "out",
                         timing=folder / "timing.json", options=opts)
    wall = time.perf_counter() - t0
    decode = sum(res.timings_s[f"{c}_decode"] for c in ("left", "right"))
    extract = sum(res.timings_s[f"{c}_extract"] for c in ("left", "right"))
    thread_s = sum(res.timings_s[f"{c}_total"] for c in ("left", "right"))
    print(f"\nrig measure --timing ({video_s:.0f} s of 1080p60 video: 2 cameras × {seconds:g} s)")
    print(f"  wall time                 {wall:7.2f} s")
    print(f"  video s per processing s  {video_s / wall:7.2f} ×   (target ≥ 2×)")
    print(f"  decoding (thread time)    {decode:7.2f} s = {decode / wall:5.1%} of wall "
          f"(2 threads; {decode / thread_s:5.1%} of the reading threads' time)")
    print(f"  marker extraction         {extract:7.2f} s = {extract / decode:5.2f} × decoding")
    steps = {k[5:]: v for k, v in res.timings_s.items() if k.startswith("step_")}
    print("  steps: " + ", ".join(f"{k} {v:.2f} s" for k, v in steps.items()))
    targets = res.summary[res.summary["role"] == "target"]
    print(f"  amplitudes {targets['amplitude_mm'].round(4).tolist()} mm (truth {mt.CRANK_MM}), "
          f"frequencies {targets['frequency_hz'].round(4).tolist()} Hz (truth {mt.FREQUENCY_HZ})")

    t0 = time.perf_counter()
    res2 = measure_videos({"left": paths[0], "right": paths[1]}, calibration, folder / "out_est",
                          options=MeasureOptions(make_figures=False, window_s=opts.window_s))
    wall2 = time.perf_counter() - t0
    print(f"\nrig measure --estimate-timing: wall {wall2:.2f} s = {video_s / wall2:.2f} × real time; "
          f"offset {res2.timing['offset_s']['right']:+.6f} s "
          f"(truth {mt.truth_timing(left, right, 0.0, 0.15)['offset_s']['right']:+.6f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
