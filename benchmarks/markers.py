"""Benchmark of marker detection on synthetic 1920×1080 frames: speed and centroid error vs truth.

Frames: 12 or 30 bright discs of radius 7.5–8.5 px, contrast 150 DN over a 20 DN background, Gaussian
blur σ = 0.8 px, noise σ = 2 DN (rendered by tests/marker_images.py: supersampled ×8 coverage). Two scenes:
"drift", markers moving up to 3 px per axis from frame to frame; "vibration", markers oscillating ≤ 0.5 px
about fixed positions at 1–12 Hz, 60 frames/s (a structure under monitoring). Tracking is fed the
previous frame's result.

Methods, timed in the same run:
  ours/full      rig.stereo.detect_markers on the whole frame (threads: 1 in the CPU pass, every core —
                 --ours-threads — in the wall pass: one frame's work split over them)
  ours/track     rig.stereo.track_markers around the previous frame's centres, one call per frame (threads
                 as ours/full)
  ours/full@1, ours/track@1  (wall pass only, when ours runs on more than one thread there) the same on
                 one thread: what the threads gain
  ours/track1    ours/track of the first marker alone: the fixed cost of a call, whatever the markers
  ours/binarize  ours/full's binarization stage alone (candidate windows, integer px, not measured; threads
                 as ours/full)
  sbd/default    cv2.SimpleBlobDetector, OpenCV's default thresholds (50..220 step 10); bright blobs,
                 area 50..2000 px², circularity ≥ 0.6 (in all three sbd variants)
  sbd/tuned      thresholds tuned to these markers (peak 170 DN): 50..170 step 10
  sbd/coarse     50..170 step 20: half the thresholds, faster and less accurate
  thr+cc         cv2.threshold at the mid level (95 DN) + cv2.connectedComponentsWithStats centroids

By default every frame is processed by all methods one right after the other (in a rotating order), so a
change in the machine's load hits them alike (--order blocked runs each method through all frames, as a
pipeline that only measures markers would). Prints ms per frame (median over the frames of a round; best
and worst round), the speed-up over each SimpleBlobDetector variant (median of the per-frame paired
ratios), and the centroid RMS error per axis vs truth (first round, matched within 3 px). Two passes by
default: CPU time of this thread with OpenCV on one thread (insensitive to other processes), then wall
time with each method free to use every core (OpenCV's SimpleBlobDetector uses the second core; a quiet
machine's wall figures are the reference; ours splits a frame over every core too, and the header
says on how many threads). Whether the wall figures are honest: each case prints the CPU
that other processes used while it ran (/proc/stat, this process's own CPU time deducted; above 0.1 core
the case is flagged "NOT a quiet machine"), and the wall pass prints the cores each method used (its
process CPU time / wall time: ≈ 1 for ours, up to 2 for SimpleBlobDetector when its second thread gets
the second core; less than that when other processes take it).
Run: .venv/bin/python benchmarks/markers.py [--rounds N] [--frames N] [--clock both|cpu|wall]
[--scene both|drift|vibration] [--markers 12 30] [--ours-threads N]
Both clocks on a quiet machine (under 3 minutes; check that no case says "NOT a quiet machine"):
  PYTHONPATH=. .venv/bin/python benchmarks/markers.py --rounds 3 --frames 20

Figures: README.md ("Marker extraction"). Quiet machine, 2026-12-02 morning (two runs, other processes
≤ 0.01 core, before the changes below): CPU on one thread, 30 markers, full frame 11.3–11.5× sbd/default,
tracking 31.7–32.9× sbd/tuned; wall, interleaved, ours on one thread: full frame 11.1–11.6× sbd/default,
tracking 25.5–27.4× sbd/tuned (not met); on two threads (then a static split) tracking 27.0–30.7×.
Since: a window inside the frame is read in place; tracking's Python-level wrapper is a few operations
(after SBD, caches cold, it cost ≈ 130 µs of a 30-marker call, now ≈ 50); a helper thread
working from the back, never waited for, was tried and not kept (its hand-over relied on x86 store
order without atomics; at load 9–13 it and the static split were alike, slower than one thread).
A/B of base and branch at the same load (cpu, 30 markers):
tracking 27.3–29.2× → 35.2–39.6× sbd/tuned, full frame unchanged. Measured only on a loaded machine
(load 11–13, other processes 1.4–1.6 cores): CPU one thread, 30 markers, full frame 10.8–10.9×
sbd/default, tracking 31.3–34.9× sbd/tuned, RMS 0.0065–0.0072 px; its wall figures are not the reference.
What limits tracking now: after other work has flushed the caches, a call costs ≈ 0.1 ms more than warm
(the compiled call's dispatch and work arrays ≈ 35 µs, the windows' pixels ≈ 20 µs, the Python wrapper
≈ 50 µs) — Python-level operations each cost microseconds then, not the ≈ 50 ns of a warm loop.
Branch markers16 (2026-12-02 evening; a loaded machine, load 10–13, other processes 1.4–1.7 cores: not the
quiet reference): the support of a window of ≤ 64 columns through 64-bit row masks, the per-window stages
and measure_one compiled into their callers, band_runs' per-row stages inlined with two bounds vectorized
(measure_one and _measure_retrying were then compiled separately again: inlined into every caller they took
rig.warm_kernels' compile from 41 to 132 CPU-s for 2–5 % of a tracking call; 47 CPU-s after; quiet figures
after that in README.md).
Base and branch alternated twice, --clock cpu --markers 30 --rounds 3 --frames 20 (drift, vibration): full
frame 12.0–12.9× → 13.8–14.5× sbd/default, tracking 36.2–40.0× → 42.3–47.1× sbd/tuned (medians: 12 % and
15 % less CPU per frame relative to SBD in the same run), RMS unchanged (0.0067, 0.0065 px; rows byte-equal on
the benchmark's frames). Per window (warm, one 33-px window, CPU): the support 1.8 µs → masks 0.25 + region
0.3 + moments 0.9; a 30-marker track_frame call 0.88 of the base kernel (interleaved in one process). What
still costs in a window: the moments of the support (float64 sums, four serial chains, ≈ 3 ns a support
pixel), the ring histogram (≈ 0.5 µs), the signal above the plane (≈ 0.4 µs), the plateau (≈ 0.4). Tried,
not kept: two interleaved ring histograms (slower: 0.75 against 0.49 µs); moments by column accumulators
(vectorized, but slower over the whole window than the row runs: 1.33 against 1.0 µs).
Tried and measured before, not kept: cv2.adaptiveThreshold for blur + offset + compare (2× slower); the
local mean on a further-reduced frame; cv2.resize INTER_NEAREST_EXACT for the subsample; speculative
tracking of many frames in one call (1.1–3× slower than one call per frame); the kernel's work arrays
kept per thread and passed to the compiled call (dispatching a tuple of 16 arrays costs ≈ 4 µs warm,
more than allocating them in the call).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from functools import partial
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from marker_images import Disc, render  # noqa: E402

from rig.stereo import detect_markers, track_markers  # noqa: E402
from rig.stereo.markers_binarize import find_candidates  # noqa: E402

SHAPE = (1080, 1920)
CLOCKS = {"wall": time.perf_counter, "cpu": time.thread_time}  # cpu: this thread's CPU time
DETECT_KW = {"min_area_px": 80.0, "max_area_px": 2000.0, "min_contrast": 40.0}
TRACK_WINDOW_PX = 33
QUIET_CORES = 0.1  # other processes using more than this (cores, on average) make the machine not quiet


def make_sequence(n_markers: int, n_frames: int, seed: int, scene: str = "drift"):
    """Frames (uint8) and truth (n_frames, n_markers, 2) of markers drifting ≤ 3 px per frame (scene
    "drift") or vibrating about fixed positions, ≤ 0.5 px amplitude at 1–12 Hz and 60 frames/s (scene
    "vibration": a structure under monitoring)."""
    rng = np.random.default_rng(seed)
    centres: list[tuple[float, float]] = []
    while len(centres) < n_markers:
        u, v = rng.uniform(60, SHAPE[1] - 60), rng.uniform(60, SHAPE[0] - 60)
        if all((u - a) ** 2 + (v - b) ** 2 > 80**2 for a, b in centres):
            centres.append((u, v))
    base = np.array(centres)
    radius = rng.uniform(7.5, 8.5, n_markers)
    step = rng.uniform(-3, 3, (n_markers, 2))
    amplitude = rng.uniform(0.1, 0.5, (n_markers, 2))
    freq_hz, phase = rng.uniform(1, 12, (n_markers, 1)), rng.uniform(0, 2 * np.pi, (n_markers, 2))
    frames, truth = [], []
    for f in range(n_frames):
        if scene == "drift":
            uv = base + f * step
        else:
            uv = base + amplitude * np.sin(2 * np.pi * freq_hz * f / 60.0 + phase)
        discs = [Disc(u, v, r) for (u, v), r in zip(uv, radius, strict=True)]
        frames.append(render(SHAPE, discs, background_dn=20.0, blur_sigma_px=0.8, noise_sigma_dn=2.0,
                             seed=seed * 1000 + f))
        truth.append(uv)
    return frames, np.array(truth)


def sbd(params: dict):
    p = cv2.SimpleBlobDetector_Params()
    p.filterByColor, p.blobColor = True, 255
    p.filterByArea, p.minArea, p.maxArea = True, 50, 2000
    p.filterByCircularity, p.minCircularity = True, 0.6
    for key, value in params.items():
        setattr(p, key, value)
    detector = cv2.SimpleBlobDetector_create(p)

    def run(img, _prev):
        return np.array([k.pt for k in detector.detect(img)]).reshape(-1, 2)
    return run


def thr_cc(img, _prev):
    _, binary = cv2.threshold(img, 95, 255, cv2.THRESH_BINARY)
    _, _, stats, centroids = cv2.connectedComponentsWithStats(binary, connectivity=8)
    keep = (stats[1:, cv2.CC_STAT_AREA] >= 50) & (stats[1:, cv2.CC_STAT_AREA] <= 2000)
    return centroids[1:][keep]


def ours_full(img, _prev, threads: int = 1):
    r = detect_markers(img, threads=threads, **DETECT_KW)
    return np.stack([r["u_px"], r["v_px"]], axis=1)


def ours_track(img, prev, threads: int = 1):
    r = track_markers(img, prev, window_px=TRACK_WINDOW_PX, threads=threads, **DETECT_KW)
    return np.stack([r["u_px"], r["v_px"]], axis=1)


def ours_track_one(img, prev):
    """Tracking of the first marker alone: the fixed cost of a call, whatever the number of markers."""
    return ours_track(img, prev[:1])


def ours_binarize(img, _prev, threads: int = 1):
    """The binarization stage of ours/full alone: candidate window centres (integer px, not measured)."""
    limits = {k: DETECT_KW[k] for k in ("min_area_px", "max_area_px", "min_contrast")}
    rows, cols, _ = find_candidates(img, dark=False, threshold=None, factor=4, min_roundness=0.5,
                                    threads=threads, **limits)
    return np.stack([cols, rows], axis=1).astype(np.float64)


ONE = "ours/track1"  # one marker tracked (its errors are against that marker's truth alone)
REFERENCES = {
    "sbd/default": sbd({}),
    "sbd/tuned": sbd({"minThreshold": 50, "maxThreshold": 170}),
    "sbd/coarse": sbd({"minThreshold": 50, "maxThreshold": 170, "thresholdStep": 20}),
    "thr+cc": thr_cc,
}


def methods(threads: int) -> dict:
    """The methods timed, ours on ``threads`` threads (and on one as well, @1, when that is more)."""
    ours = {"ours/full": partial(ours_full, threads=threads),
            "ours/track": partial(ours_track, threads=threads)}
    if threads > 1:
        ours |= {"ours/full@1": ours_full, "ours/track@1": ours_track}
    binarize = partial(ours_binarize, threads=threads)
    return {**ours, ONE: ours_track_one, "ours/binarize": binarize, **REFERENCES}


def is_tracker(name: str) -> bool:
    """Whether the method is fed its own previous result (a tracker following its markers)."""
    return name.startswith("ours/track") and name != ONE


def errors(found: np.ndarray, truth: np.ndarray):
    """Errors (matched, 2) of detections within 3 px of a true centre, misses and false detections."""
    found = found[np.isfinite(found).all(axis=1)]
    if len(found) == 0:
        return np.zeros((0, 2)), len(truth), 0
    dist = np.linalg.norm(found[:, None, :] - truth[None, :, :], axis=2)
    nearest = dist.argmin(axis=1)
    ok = dist[np.arange(len(found)), nearest] < 3.0
    matched = found[ok] - truth[nearest[ok]]
    return matched, len(truth) - len(set(nearest[ok].tolist())), int((~ok).sum())


def schedule(names: list[str], r: int, n_frames: int, order: str) -> list[tuple[int, str]]:
    """The (frame, method) steps of round r."""
    if order == "interleaved":  # each frame through every method, in a rotating order
        return [(f, name) for f in range(1, n_frames + 1)
                for name in names[(r + f) % len(names):] + names[: (r + f) % len(names)]]
    # blocked: each method through every frame, methods in a rotating order per round
    return [(f, name) for name in names[r % len(names):] + names[: r % len(names)]
            for f in range(1, n_frames + 1)]


def busy_s() -> float | None:
    """CPU seconds every process of the machine has used since boot (Linux /proc/stat), or None."""
    try:
        with open("/proc/stat", encoding="ascii") as f:
            fields = [int(x) for x in f.readline().split()[1:]]
    except (OSError, ValueError):
        return None
    idle = fields[3] + (fields[4] if len(fields) > 4 else 0)  # idle + iowait
    return (sum(fields[:8]) - idle) / os.sysconf("SC_CLK_TCK")


def run(n_markers: int, n_frames: int, rounds: int, *, clock=time.perf_counter,
        order: str = "interleaved", scene: str = "drift", threads: int = 1) -> None:
    frames, truth = make_sequence(n_markers, n_frames + 1, seed=n_markers, scene=scene)
    timed = methods(threads)
    names = list(timed)
    for name in names:  # warm-up (caches, first-call costs, the threads' start)
        timed[name](frames[0], truth[0])
    # times[name][round, frame]; speed-ups are medians of the ratios paired by (round, frame); cpu: this
    # process's CPU time (every thread) of the same calls: cores used = cpu / wall in the wall pass
    times = {name: np.zeros((rounds, n_frames)) for name in names}
    cpu = {name: np.zeros((rounds, n_frames)) for name in names}
    results: dict[str, list[np.ndarray]] = {name: [] for name in names}
    load_start, busy_start, own_start, wall_start = os.getloadavg()[0], busy_s(), time.process_time(), \
        time.perf_counter()
    for r in range(rounds):
        prev_track = {name: truth[0] for name in names if is_tracker(name)}
        for f, name in schedule(names, r, n_frames, order):
            prev = prev_track[name] if is_tracker(name) else truth[f - 1]
            c0 = time.process_time()
            t0 = clock()
            found = timed[name](frames[f], prev)
            times[name][r, f - 1] = clock() - t0
            cpu[name][r, f - 1] = time.process_time() - c0
            if is_tracker(name):
                prev_track[name] = found
            if r == 0:
                results[name].append(found)
    wall_s, busy_end = time.perf_counter() - wall_start, busy_s()
    others = (None if busy_start is None or busy_end is None
              else (busy_end - busy_start - (time.process_time() - own_start)) / wall_s)
    report(times, results, truth,
           f"{n_markers} markers, {scene}, {n_frames} frames 1920×1080, {rounds} rounds, {order}, ours on "
           f"{threads} thread(s); "
           f"load average {load_start:.1f} at the start, {os.getloadavg()[0]:.1f} at the end",
           cores={name: cpu[name] / times[name] for name in names} if clock is time.perf_counter else None)
    if others is not None:
        print(f"other processes used {others:.2f} of the {os.cpu_count()} cores during this case "
              f"(/proc/stat, this process's CPU time deducted)"
              + (": NOT a quiet machine — the wall figures are not the quiet-machine reference"
                 if clock is time.perf_counter and others > QUIET_CORES else ""))


def report(times: dict[str, np.ndarray], results: dict[str, list[np.ndarray]], truth: np.ndarray,
           title: str, cores: dict[str, np.ndarray] | None = None) -> None:
    """Print ms/frame, paired speed-ups over the SimpleBlobDetector variants and centroid errors; with
    ``cores`` (the wall pass) the median cores each method used (its process CPU time / wall time)."""
    per_round = {name: np.median(t, axis=1) * 1e3 for name, t in times.items()}
    print(f"\n{title}")
    refs = ("sbd/default", "sbd/tuned", "sbd/coarse")
    print(f"{'method':<13} {'ms/frame':>8} {'(worst)':>8} " + " ".join(f"{'×' + r[4:]:>15}" for r in refs)
          + f" {'RMS px':>7} {'bias u,v px':>16} {'missed':>6} {'false':>5}" + (" cores" if cores else ""))
    for name, t in times.items():
        ms = per_round[name]
        # median of all paired ratios, and the range of the per-round medians (the spread over repeats)
        ratios = [f"{np.median(times[r] / t):5.1f} ({np.median(times[r] / t, axis=1).min():4.1f}–"
                  f"{np.median(times[r] / t, axis=1).max():4.1f})" for r in refs]
        errs, missed, false = [], 0, 0
        for f, found in enumerate(results[name], start=1):
            e, m, fa = errors(found, truth[f][:1] if name == ONE else truth[f])
            errs.append(e)
            missed += m
            false += fa
        e = np.concatenate(errs)
        rms = np.sqrt((e**2).sum(axis=1).mean() / 2) if len(e) else np.nan
        bias = e.mean(axis=0) if len(e) else (np.nan, np.nan)
        print(f"{name:<13} {ms.min():8.3f} {ms.max():8.3f} " + " ".join(f"{r:>15}" for r in ratios)
              + f" {rms:7.4f} {bias[0]:+7.4f},{bias[1]:+7.4f} {missed:6d} {false:5d}"
              + (f" {np.median(cores[name]):5.2f}" if cores else ""))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--threads", type=int, default=None,
                        help="cv2.setNumThreads for every method in the wall-clock pass (default: OpenCV's "
                             "own choice, every core); the CPU-time pass always runs on one thread")
    parser.add_argument("--ours-threads", type=int, default=None,
                        help="threads ours splits a frame over in the wall-clock pass (default: every core); "
                             "the CPU-time pass (this thread's CPU time) always runs ours on one thread")
    parser.add_argument("--clock", choices=("both", "wall", "cpu"), default="both",
                        help="cpu: time.thread_time, the CPU time of this thread with OpenCV on one thread "
                             "(insensitive to other processes); wall: time.perf_counter, each method free to "
                             "use every core; both (default): a cpu pass, then a wall pass")
    parser.add_argument("--scene", choices=("both", "drift", "vibration"), default="both")
    parser.add_argument("--markers", type=int, nargs="+", default=[12, 30])
    parser.add_argument("--order", choices=("interleaved", "blocked"), default="interleaved",
                        help="interleaved: every frame through all methods in turn (each method finds its "
                             "caches cold, as after other work); blocked: each method through all frames "
                             "(as in a pipeline that only detects markers)")
    args = parser.parse_args()
    all_cores = cv2.getNumThreads() if args.threads is None else args.threads
    ours_cores = (os.cpu_count() or 1) if args.ours_threads is None else args.ours_threads
    print(f"OpenCV {cv2.__version__}, numpy {np.__version__}, {os.cpu_count()} cores, "
          f"load average {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    print("ms/frame: median over frames, best (and worst) round; ×: speed-up, median of per-frame paired "
          "ratios; RMS: per-axis centroid error vs truth")
    scenes = ("drift", "vibration") if args.scene == "both" else (args.scene,)
    for clock in (("cpu", "wall") if args.clock == "both" else (args.clock,)):
        cv2.setNumThreads(1 if clock == "cpu" else all_cores)
        ours = 1 if clock == "cpu" else ours_cores
        print(f"\n=== clock: {clock} ({'CPU time of this thread' if clock == 'cpu' else 'wall time'}), "
              f"OpenCV on {cv2.getNumThreads()} thread(s), ours on {ours} ===")
        for scene in scenes:
            for n in args.markers:
                run(n, args.frames, args.rounds, clock=CLOCKS[clock], order=args.order, scene=scene,
                    threads=ours)


if __name__ == "__main__":
    main()
