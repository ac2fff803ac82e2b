"""``rig measure``'s cost against decoding, in instructions executed: a figure this VM's load cannot move.

CPU time on a shared VM drifts by ± 30 % within minutes (benchmarks/measure.py measures its ratio 9 times
and states an interval). Instructions do not: this script runs three fresh processes under Valgrind's
cachegrind (``--cache-sim=no``: it counts the instructions of every thread, the decoder's included) on the
videos ``benchmarks/measure.py --keep DIR`` wrote, and differences their totals:

- *base*: the interpreter, the imports, and a warm-up ``rig measure`` of the first ``WARM_S`` seconds (the
  numba kernels loaded from their cache, the lazy imports done);
- *decode*: base, then the decode-only baseline of the first ``--seconds`` of both videos (two threads, as
  ``rig measure`` decodes: :func:`measure.decode_until`);
- *measure*: base, then ``rig measure --timing`` and its report on the same stretch
  (:func:`measure.measure_once`).

The ratio (measure − base) / (decode − base) is ``rig measure``'s instructions per decoded instruction,
for that length of record; two lengths (``--seconds 5 20``) also give the marginal ratio (what one more
second of video costs) and the fixed part. Instructions are not CPU seconds: the decoder's SIMD code does
more per instruction than Python does, so the CPU ratio runs higher (benchmarks/measure.py). Under Valgrind
the code is what the CPU it emulates gets (no AVX-512: FFmpeg's and numba's dispatch choose AVX2 paths;
numba compiles for it into ``DIR/numba-valgrind`` — about 30 min under Valgrind, once, and again for a kernel
edited since — in a first, uncounted base process). The children run
with ``OPENBLAS_NUM_THREADS=1``: OpenBLAS's idle worker threads spin, and under Valgrind's
one-thread-at-a-time scheduling their spinning counts as long as the other threads take — the same 20-s
``rig measure`` counted 56.9 and 71.3 × 10⁹ with its default threads (alone, and beside four other runs),
48.1 with one. Each process takes minutes (≈ 35× its native time); the three run at once on ``--jobs``
cores.

Run: ``.venv/bin/python benchmarks/measure_instructions.py --keep DIR [--seconds 5 20] [--jobs 2]``.
"""

from __future__ import annotations

import argparse
import itertools
import os
import re
import shutil
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
WARM_S = 2.0  # the warm-up run's length, s (every process runs it first)
KINDS = ("base", "decode", "measure")


def child(kind: str, folder: Path, seconds: float) -> None:
    """One measured process (``--child``): the imports, the warm-up, then ``kind``'s work."""
    sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]
    import cv2
    import measure as bench  # benchmarks/measure.py: the same decode-only loop and rig measure run

    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    paths = folder / "left.mp4", folder / "right.mp4"
    own = Path(tempfile.mkdtemp(prefix=f"instructions-{kind}-"))  # its own out/: the children run at once
    (own / "timing.json").symlink_to((folder / "timing.json").resolve())

    def run_measure(length_s: float) -> None:
        opts = bench.MeasureOptions(window_s=(0.6, length_s - 0.1),
                                    extract=bench.ExtractOptions(stop_s=length_s))
        bench.measure_once(own, paths, folder / "calibration.json", opts)

    try:
        run_measure(WARM_S)
        if kind == "decode":
            with ThreadPoolExecutor(2) as pool:
                list(pool.map(lambda p: bench.decode_until(p, stop_s=seconds), paths))
        elif kind == "measure":
            run_measure(seconds)
    finally:
        shutil.rmtree(own)


def instructions(kind: str, seconds: float, folder: Path) -> int:
    """Instructions executed by a ``kind`` process (cachegrind's ``I refs``, all threads)."""
    cmd = ["valgrind", "--tool=cachegrind", "--cache-sim=no", "--cachegrind-out-file=/dev/null",
           sys.executable, __file__, "--child", kind, "--keep", str(folder), "--seconds", f"{seconds:g}"]
    env = {**os.environ, "NUMBA_CACHE_DIR": str(folder / "numba-valgrind"),  # built for Valgrind's CPU
           "OPENBLAS_NUM_THREADS": "1"}  # idle BLAS threads spin: counted, by how long the others take
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    found = re.search(r"I\s+refs:\s+([\d,]+)", done.stderr)
    if done.returncode != 0 or not found:
        raise RuntimeError(f"{kind} ({seconds:g} s) under valgrind failed (exit {done.returncode}):\n"
                           f"{done.stderr[-2000:]}")
    return int(found.group(1).replace(",", ""))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--keep", type=Path, required=True,
                    help="the folder of benchmarks/measure.py --keep (left.mp4, right.mp4, calibration.json, "
                         "timing.json)")
    ap.add_argument("--seconds", type=float, nargs="+", default=[5.0, 20.0],
                    help=f"record lengths measured, s (each > {WARM_S:g} and within the videos)")
    ap.add_argument("--jobs", type=int, default=2, help="processes under Valgrind at once")
    ap.add_argument("--child", choices=KINDS, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        child(args.child, args.keep, args.seconds[0])
        return 0
    missing = [f for f in ("left.mp4", "right.mp4", "calibration.json", "timing.json")
               if not (args.keep / f).is_file()]
    if missing:
        ap.error(f"--keep {args.keep} lacks {missing}: run benchmarks/measure.py --keep {args.keep} first")
    if any(s <= WARM_S for s in args.seconds):
        ap.error(f"--seconds {args.seconds}: each must be longer than the {WARM_S:g}-s warm-up")
    if shutil.which("valgrind") is None:
        print("valgrind is not installed (e.g. apt-get install valgrind): no instruction counts")
        return 2
    # one base process first, not counted: it compiles the kernels for Valgrind's CPU where their cache is
    # missing or stale (a kernel edited since), which a counted process must not pay (a base run that did:
    # 118.8 × 10⁹ instructions, above the decode and measure runs that loaded its cache)
    warm = instructions("base", WARM_S, args.keep)
    print(f"kernels for Valgrind's CPU ready ({args.keep / 'numba-valgrind'}): {warm / 1e9:.3f} × 10^9 "
          "instructions, not counted", flush=True)
    runs = [("base", WARM_S)] + [(kind, s) for s in args.seconds for kind in ("decode", "measure")]
    with ThreadPoolExecutor(args.jobs) as pool:
        totals = pool.map(lambda run: instructions(run[0], run[1], args.keep), runs)
        counts = dict(zip(runs, totals, strict=True))
    report(counts, args.seconds)
    return 0


def report(counts: dict[tuple[str, float], int], lengths: list[float]) -> None:
    """Print each length's instructions (10⁹) and ratio, and the marginal ratio between the lengths."""
    base = counts[("base", WARM_S)]
    print(f"instructions (10^9), cachegrind; base (imports + {WARM_S:g}-s warm-up) {base / 1e9:.3f}")
    added = {s: (counts[("decode", s)] - base, counts[("measure", s)] - base) for s in lengths}
    if min(min(pair) for pair in added.values()) <= 0:
        raise RuntimeError(f"a run counted no more than the base ({counts}): the base paid work the others "
                           "did not (a compilation?); run again")
    for s, (dec, mea) in added.items():
        print(f"  {s:5.1f} s of video: decode-only {dec / 1e9:7.3f}, rig measure + report {mea / 1e9:7.3f}"
              f"  → ratio {mea / dec:.3f}   (target ≤ 1.3 in CPU seconds, benchmarks/measure.py)")
    ordered = sorted(added)
    for short, long in itertools.pairwise(ordered):
        d_dec = added[long][0] - added[short][0]
        d_mea = added[long][1] - added[short][1]
        fixed = added[short][1] - d_mea / (long - short) * short
        print(f"  {short:g} → {long:g} s: marginal ratio {d_mea / d_dec:.3f} (per second of video: decode "
              f"{d_dec / (long - short) / 1e9:.3f}, rig measure {d_mea / (long - short) / 1e9:.3f}); "
              f"rig measure's fixed part {fixed / 1e9:.3f}")


if __name__ == "__main__":
    sys.exit(main())
