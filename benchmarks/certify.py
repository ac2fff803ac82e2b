"""Benchmark: wall time of the full ``rig certify`` on the simulated rig, and frames processed per second.

Runs ``rig certify`` (full preset, figures included) as a subprocess on the built-in simulated rig with
its run folder in a temporary directory, then reads the record: the frames the cameras delivered (the
``camera`` stop events), the wall time of the acquisition (start → report step) and of the report
(analysis twice — the primary sync method and the paper's — tables, figures, certificate).

Baseline measured in the same run: the naive per-frame reduction (render a frame, search it whole with
``detect_markers``, one thread) over 120 frames of the sweep scene; the ratio is the pipeline's frames per
second of acquisition over the naive rate. Target (issue 7): the whole certification under 2 minutes on
a 2-core machine.
"""

from __future__ import annotations

import datetime as dt
import json
import re
import subprocess
import sys
import tempfile
import time
from importlib import resources
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

def _config_text(runs_dir: Path) -> str:
    """The built-in simulated rig, with its run folders under ``runs_dir``."""
    text = resources.files("rig").joinpath("data/sim.toml").read_text()
    return re.sub(r"^runs_dir = .*$", f'runs_dir = "{runs_dir.as_posix()}"', text, flags=re.M)


def _naive_fps(n_frames: int = 120) -> float:
    from drivers.sim.clock import VirtualClock
    from drivers.sim.stereo_rig import default_stereo_pair
    from drivers.sim.world import World
    from rig.stereo import detect_markers

    clock = VirtualClock()
    world = World(clock)
    world.set_scene("sweep_column", 0.0)
    world.exciter.set_frequency(0.0, 10.0)
    left, _ = default_stereo_pair(world)
    clock.advance_to(n_frames / 60.0 + 1.0)
    t0 = time.perf_counter()
    for i in range(n_frames):
        detect_markers(left.render(i))
    return n_frames / (time.perf_counter() - t0)


def _wall(doc: dict) -> float:
    return dt.datetime.fromisoformat(doc["wall_utc"]).timestamp()


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        text = _config_text(tmp_path / "runs")
        config = tmp_path / "rig.toml"
        config.write_text(text)
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "rig.cli", "certify", "--config", str(config)], cwd=tmp,
                              capture_output=True, text=True, check=False)
        wall_s = time.perf_counter() - t0
        runs = sorted((tmp_path / "runs").iterdir())
        if not runs:
            print(proc.stderr[-2000:])
            return 1
        docs = [json.loads(line) for line in (runs[0] / "record.jsonl").read_text().splitlines() if line]
    start = next(d for d in docs if d["type"] == "start")
    report = next((d for d in docs if d["type"] == "step" and d["name"] == "report"), None)
    stop = next(d for d in docs if d["type"] == "stop")
    frames = sum(d["data"].get("n_frames") or 0 for d in docs
                 if d["type"] == "event" and d["stream"] == "camera" and d["data"]["action"] == "stop")
    acquire_s = (_wall(report) if report else _wall(stop)) - _wall(start)
    report_s = _wall(stop) - _wall(report) if report else float("nan")
    virtual_s = stop["time_s"] - start["time_s"]
    naive = _naive_fps()
    fps = frames / acquire_s
    print(f"rig certify (full preset, simulated rig): exit {proc.returncode} "
          f"({stop.get('outcome')}: {stop.get('reason')})")
    print(f"  wall time total            {wall_s:7.1f} s   (target < 120 s; rig time simulated "
          f"{virtual_s:.1f} s)")
    print(f"  acquisition (procedures)   {acquire_s:7.1f} s   {frames} frames of 2 cameras → "
          f"{fps:.0f} frames/s")
    print(f"  report (analysis ×2, figures, certificate) {report_s:5.1f} s")
    print(f"  naive baseline (render + whole-frame detect, 1 thread) {naive:.0f} frames/s; "
          f"ratio {fps / naive:.2f}")
    return 0 if proc.returncode in (0, 1) else proc.returncode


if __name__ == "__main__":
    raise SystemExit(main())
