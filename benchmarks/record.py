"""Throughput of the crash-safe run record (events/s) and observation writer (rows/s).

    .venv/bin/python benchmarks/record.py [--events N] [--frames N]

Record: ``RunRecord.event`` writes one strict-JSON line per event with one ``write`` call, flushes it at
once and fsyncs every 2 s (the durability DESIGN.md asks for). Baseline measured in the same run: the
same documents through ``json.dumps`` appended to a buffered file with no flush and no fsync (fast, but a
``kill -9`` loses the buffer). Observations: ``ObservationWriter.append`` of one frame's detections
(12 markers) per call, flushed to atomic Parquet part files every 50,000 rows; baseline: the same rows
collected in memory and written once with ``pyarrow.parquet.write_table`` at the end.
A 60 s sweep at 60 FPS with two cameras is 7,200 frames and ~100 events/s at most: the figures below
say how much headroom the durable path leaves.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from rig.record.writer import RunRecord


class _Clock:
    is_virtual = True

    def __init__(self) -> None:
        self.t = 0.0

    def now_s(self) -> float:
        self.t += 0.001
        return self.t


def _event(i: int) -> dict:
    return {"frequency_hz": 10.0 + i * 1e-4, "setpoint_hz": 10.0, "status": "running",
            "pose": [420.0, 0.0, 300.0, 90.0, 0.0, 90.0]}


def bench_events(root: Path, n: int) -> tuple[float, float]:
    rec = RunRecord.create(root, "bench", {}, {}, _Clock(), versions={})
    t0 = time.perf_counter()
    for i in range(n):
        rec.event("exciter", _event(i))
    rec.close()
    durable = n / (time.perf_counter() - t0)
    t0 = time.perf_counter()
    with open(root / "baseline.jsonl", "w") as fh:
        for i in range(n):
            fh.write(json.dumps({"type": "event", "time_s": i * 1e-3, "stream": "exciter", "seq": i,
                                 "data": _event(i)}) + "\n")
    baseline = n / (time.perf_counter() - t0)
    return durable, baseline


def bench_observations(root: Path, frames: int, markers: int = 12) -> tuple[float, float]:
    rng = np.random.default_rng(0)
    det = {"u_px": rng.uniform(0, 1920, markers), "v_px": rng.uniform(0, 1080, markers),
           "area_px": np.full(markers, 300.0), "roundness": np.full(markers, 0.97),
           "contrast": np.full(markers, 190.0), "flags": np.zeros(markers, np.uint8)}
    rec = RunRecord.create(root, "obs", {}, {}, _Clock(), versions={})
    t0 = time.perf_counter()
    with rec.observation_writer("left") as writer:
        for i in range(frames):
            writer.append(det, frame_index=i, timestamp_s=i / 60.0, segment="sweep")
    rec.close()
    durable = frames * markers / (time.perf_counter() - t0)
    t0 = time.perf_counter()
    frames_ = [pd.DataFrame({**det, "frame_index": i, "timestamp_s": i / 60.0}) for i in range(frames)]
    pq.write_table(pa.Table.from_pandas(pd.concat(frames_, ignore_index=True)), root / "baseline.parquet")
    baseline = frames * markers / (time.perf_counter() - t0)
    return durable, baseline


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=20_000)
    parser.add_argument("--frames", type=int, default=7_200)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        durable, baseline = bench_events(Path(tmp), args.events)
        print(f"record events:        {durable:10.0f} events/s durable   {baseline:10.0f} events/s baseline "
              f"(ratio {durable / baseline:.2f})")
        durable, baseline = bench_observations(Path(tmp), args.frames)
        print(f"observation rows:     {durable:10.0f} rows/s durable     {baseline:10.0f} rows/s baseline "
              f"(ratio {durable / baseline:.2f})")


if __name__ == "__main__":
    main()
