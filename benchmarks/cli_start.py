"""Start time of ``rig --help``, ``rig list`` and ``rig run --help`` against ``python -c pass``.

    .venv/bin/python benchmarks/cli_start.py [--repeat N]

Each command runs N times in a fresh interpreter; the median wall time and the median CPU time (user + system
of the child, from ``resource.getrusage``) are printed, with their ratio to the baseline measured in the same
run. CPU time is the figure to read on a loaded machine (the wall time waits for the cores); the target is
``rig --help`` and ``rig list`` under 0.3 s. Also printed: how many modules each imports, and which heavy
libraries (the test tests/test_cli_start.py asserts ``--help`` imports none).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("numpy", "pandas", "cv2", "scipy", "matplotlib", "dask", "pyarrow")
COMMANDS = {
    "python -c pass": [sys.executable, "-c", "pass"],
    "rig --help": [sys.executable, "-m", "rig.cli", "--help"],
    "rig list": [sys.executable, "-m", "rig.cli", "list"],
    "rig run --help": [sys.executable, "-m", "rig.cli", "run", "--help"],
}
MODULES = """\
import contextlib, io, json, sys
from rig.cli import main
with contextlib.redirect_stdout(io.StringIO()):
    try:
        main(sys.argv[1:])
    except SystemExit:
        pass
print(json.dumps([len(sys.modules), sorted(m for m in HEAVY if m in sys.modules)]))
""".replace("HEAVY", repr(HEAVY))


def _once(command: list[str], env: dict[str, str]) -> tuple[float, float]:
    """(wall s, CPU s) of one run of ``command``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(command, env=env, cwd=ROOT, stdout=subprocess.DEVNULL, check=True)  # -m/-c: cwd first
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5, help="runs of each command (the median is printed)")
    args = ap.parse_args(argv)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; median of {args.repeat} runs")
    base_wall = base_cpu = None
    for name, command in COMMANDS.items():
        runs = [_once(command, env) for _ in range(args.repeat)]
        wall, cpu = statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs)
        if base_wall is None:
            base_wall, base_cpu = wall, max(cpu, 1e-3)
            extra = ""
        else:
            done = subprocess.run([sys.executable, "-c", MODULES, *command[3:]], env=env, cwd=ROOT,
                                  capture_output=True, text=True, check=True)
            count, heavy = json.loads(done.stdout.splitlines()[-1])
            extra = f"  {count} modules, heavy: {', '.join(heavy) or 'none'}"
        print(f"{name:16s} wall {wall:6.3f} s ({wall / base_wall:5.1f}×)  CPU {cpu:6.3f} s "
              f"({cpu / base_cpu:5.1f}×){extra}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
