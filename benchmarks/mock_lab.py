"""What `rig mock lab` costs: CPU seconds of the lab process per second of streaming both cameras.

For each setting (frame rate, scale) a `rig mock lab` subprocess is started; its CPU time (utime + stime
from /proc) is read over ``--seconds`` with no client (the baseline: the idle lab, the same run), then over
``--seconds`` with one OpenCV/FFmpeg client per camera reading the stream the lab names (time-stamped
Matroska by default) in this process. Printed per
setting: the lab's CPU-s per second idle and streaming, their ratio, the frames each client received per
second (of the camera's fps) and the frames the lab skipped because rendering fell behind.

Figures depend on the machine's load (the lab skips frames rather than fall behind): run it on a quiet
machine for the cost, on a loaded one for the delivery. Run:
``PYTHONPATH=. .venv/bin/python benchmarks/mock_lab.py [--seconds 10] [--setting 60:0.5 --setting 30:0.5]``
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2

ROOT = Path(__file__).resolve().parents[1]
TICK_S = 1.0 / os.sysconf("SC_CLK_TCK")


def _cpu_s(pid: int) -> float:
    """utime + stime of process ``pid`` (all its threads), s."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) * TICK_S


def _read_stream(url: str, stop: threading.Event, counts: dict[str, int]) -> None:
    cap = cv2.VideoCapture(url, cv2.CAP_FFMPEG)
    while not stop.is_set() and cap.grab():
        counts[url] = counts.get(url, 0) + 1
    cap.release()


def measure(fps: float, scale: float, seconds: float) -> None:
    proc = subprocess.Popen([sys.executable, "-m", "rig.cli", "mock", "lab", "--fps", f"{fps:g}", "--scale",
                             f"{scale:g}", "--write-config", os.devnull], cwd=ROOT,
                            env={**os.environ, "PYTHONPATH": str(ROOT)}, stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    assert proc.stdout is not None
    urls = []
    for line in proc.stdout:
        found = re.match(r"lab cameras\.\w+: (\S+)", line)
        if found:
            urls.append(found.group(1))
        if line.startswith("lab ready"):
            break
    try:
        c0 = _cpu_s(proc.pid)
        time.sleep(seconds)
        idle = (_cpu_s(proc.pid) - c0) / seconds
        stop, counts = threading.Event(), {}
        readers = [threading.Thread(target=_read_stream, args=(url, stop, counts)) for url in urls]
        for reader in readers:
            reader.start()
        time.sleep(2.0)  # the clients connected and probed the streams
        c0, counted0, w0 = _cpu_s(proc.pid), dict(counts), time.monotonic()
        time.sleep(seconds)
        streaming = (_cpu_s(proc.pid) - c0) / (time.monotonic() - w0)
        received = {u: (counts.get(u, 0) - counted0.get(u, 0)) / (time.monotonic() - w0) for u in urls}
        stop.set()
        for reader in readers:
            reader.join()
    finally:
        proc.send_signal(signal.SIGTERM)
        tail, _ = proc.communicate(timeout=60)
    skipped = re.findall(r"(\d+) frames sent, (\d+) skipped", tail)
    print(f"{fps:g} fps, scale {scale:g}: lab CPU {streaming:.2f} CPU-s/s streaming 2 cameras, "
          f"{idle:.3f} idle (ratio {streaming / max(idle, 1e-3):.0f}×); received "
          + ", ".join(f"{r:.1f}/s" for r in received.values())
          + f" of {fps:g}; lab totals (sent, skipped): {skipped}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--setting", action="append", default=None, metavar="FPS:SCALE")
    args = parser.parse_args()
    print(f"load average before: {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs", flush=True)
    for setting in args.setting or ["60:0.5", "30:0.5", "60:1"]:
        fps, scale = (float(v) for v in setting.split(":"))
        measure(fps, scale, args.seconds)


if __name__ == "__main__":
    main()
