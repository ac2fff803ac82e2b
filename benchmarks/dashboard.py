"""What the live dashboard costs the run: record events/s with and without the dashboard observing them
(and a client streaming them), and the acquisition's per-frame cost of the frame tap.

    .venv/bin/python benchmarks/dashboard.py [--events N] [--frames N]

Record: ``RunRecord.event`` of an ``exciter`` sample, baseline = the same record with no observer,
measured in the same run; then with ``DashboardState.on_document`` observing, then with that and one SSE
client reading ``/events`` on 127.0.0.1. Frame tap: ``FRAMES.offer`` per frame (a 1280 × 1024 image and 12
markers) enabled, against the attribute test it costs when disabled; and the on-request JPEG encoding
(downscale to 480 px, draw, encode), paid in the client's thread once per delivered frame; with the live
stereo preview's marker queue on (``keep_markers``). The live stereo preview's work per window (its own
thread): 12 markers over 120 frames of two cameras paired, triangulated and fitted
(:func:`rig.analysis.live_estimate.paired_paths` and ``vibration_estimate`` per marker), against the
window's duration of camera time.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rig.dashboard.server import DashboardServer
from rig.dashboard.state import DashboardState
from rig.record.writer import RunRecord
from rig.run.frame_tap import FrameTap


class _Clock:
    is_virtual = True

    def __init__(self) -> None:
        self.t = 0.0

    def now_s(self) -> float:
        self.t += 0.001
        return self.t


def _events_per_s(root: Path, n: int, observe: bool, client: bool) -> float:
    rec = RunRecord.create(root, "bench", {}, {}, _Clock(), versions={})
    state = DashboardState("bench")
    server = DashboardServer(state) if client else None
    stop = threading.Event()
    if observe:
        rec.add_observer(state.on_document)
    if server is not None:
        server.start()

        def read() -> None:
            with urllib.request.urlopen(server.url + "events", timeout=60) as stream:
                while not stop.is_set() and stream.readline():
                    pass
        threading.Thread(target=read, daemon=True).start()
        time.sleep(0.3)
    t0 = time.perf_counter()
    for i in range(n):
        rec.event("exciter", {"frequency_hz": 10.0 + i * 1e-4, "setpoint_hz": 10.0, "status": "running"})
    rate = n / (time.perf_counter() - t0)
    rec.close()
    stop.set()
    if server is not None:
        server.close(linger_s=0.0)
    return rate


def _frame_costs(frames: int) -> tuple[float, float, float]:
    image = np.random.default_rng(0).integers(0, 255, (1024, 1280), dtype=np.uint8)
    uv, ids = np.random.default_rng(1).uniform(0, 1000, (12, 2)), np.arange(12)
    tap = FrameTap(min_interval_s=0.0)
    t0 = time.perf_counter()
    for i in range(frames):
        tap.offer("left", i, image, uv, ids)
    disabled_us = (time.perf_counter() - t0) / frames * 1e6
    tap.enabled = True
    t0 = time.perf_counter()
    for i in range(frames):
        tap.offer("left", i, image, uv, ids)
    enabled_us = (time.perf_counter() - t0) / frames * 1e6
    t0 = time.perf_counter()
    n = 50
    for i in range(n):
        tap.offer("left", frames + i, image, uv, ids)
        tap.jpeg("left")
    jpeg_ms = (time.perf_counter() - t0) / n * 1e3
    tap.keep_markers = True
    t0 = time.perf_counter()
    for i in range(frames):
        tap.offer("left", i, image, uv, ids, timestamp_s=i / 60, segment="sweep")
        if i % 600 == 0:
            tap.drain_markers()
    markers_us = (time.perf_counter() - t0) / frames * 1e6
    return disabled_us, enabled_us, jpeg_ms, markers_us


def _look_at(eye_mm: np.ndarray, target_mm: np.ndarray, f_px: float = 2400.0) -> np.ndarray:
    """A pinhole P (3 × 4) at ``eye_mm`` looking at ``target_mm``, 1920 × 1080."""
    z = (target_mm - eye_mm) / np.linalg.norm(target_mm - eye_mm)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    K = np.array([[f_px, 0, 959.5], [0, f_px, 539.5], [0, 0, 1]])
    return K @ np.hstack([R, (-R @ eye_mm)[:, None]])


def _window_ms(repeat: int) -> tuple[float, float]:
    """(ms of the preview's work per window, the window's camera time in ms)."""
    from rig.analysis.live_estimate import paired_paths, vibration_estimate
    from rig.stereo import DLTCamera

    target = np.array([420.0, 0.0, 300.0])
    cams = tuple(DLTCamera(_look_at(np.array([1900.0, y, 420.0]), target)) for y in (-300.0, 300.0))
    rng = np.random.default_rng(2)
    base = target + rng.uniform(-150, 150, (12, 3))
    t = np.arange(120) / 60.0
    tracks = []
    for cam, delay in zip(cams, (0.0, 0.004), strict=True):
        xyz = base[:, None, :] + np.array([4.0, 0, 0]) * np.sin(2 * np.pi * 5.0 * (t + delay))[None, :, None]
        uv = cam.project(xyz.reshape(-1, 3)).reshape(12, len(t), 2) + rng.normal(0, 0.05, (12, len(t), 2))
        tracks.append({k: (t + delay, uv[k]) for k in range(12)})
    t0 = time.perf_counter()
    for _ in range(repeat):
        for path in paired_paths(cams, (tracks[0], tracks[1])):
            vibration_estimate(path)
    return (time.perf_counter() - t0) / repeat * 1e3, t[-1] * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--events", type=int, default=20000)
    parser.add_argument("--frames", type=int, default=20000)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        base = _events_per_s(root / "a", args.events, observe=False, client=False)
        observed = _events_per_s(root / "b", args.events, observe=True, client=False)
        streamed = _events_per_s(root / "c", args.events, observe=True, client=True)
    print(f"record events/s: no dashboard {base:,.0f}; observed {observed:,.0f} ({observed / base:.2f}×); "
          f"observed + 1 SSE client {streamed:,.0f} ({streamed / base:.2f}×)")
    disabled_us, enabled_us, jpeg_ms, markers_us = _frame_costs(args.frames)
    print(f"frame tap per frame: disabled {disabled_us:.2f} µs, enabled {enabled_us:.2f} µs, with the live "
          f"stereo marker queue {markers_us:.2f} µs (a 60 FPS frame period is 16,667 µs); JPEG on request "
          f"{jpeg_ms:.1f} ms per delivered frame (client thread)")
    window_ms, span_ms = _window_ms(20)
    print(f"live stereo preview per window (12 markers × 120 frames × 2 cameras; its own thread): "
          f"{window_ms:.1f} ms for {span_ms:.0f} ms of camera time ({window_ms / span_ms:.3f}×)")


if __name__ == "__main__":
    main()
