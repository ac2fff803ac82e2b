"""Cost of writing results atomically (``rig.record.atomic``: temporary name, fsync, rename, fsync of the
folder).

    .venv/bin/python benchmarks/atomic.py [--files N] [--kib K] [--dir DIR]

A report writes about 20 files (tables, figures, report.html, certificate.json) of 1–200 KiB; ``rig
measure`` about 12. Baseline measured in the same run: the same bytes through ``Path.write_bytes`` (no
fsync: fast, but a crash or a full disk can leave a 0-byte or half-written file under the final name).
The figure that matters is the extra time per file against the seconds a report takes to compute.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from rig.record import atomic


def _time(write, folder: Path, n: int, data: bytes) -> float:
    t0 = time.perf_counter()
    for i in range(n):
        write(folder / f"table_{i:03d}.csv", data)
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--files", type=int, default=40, help="files written per method")
    ap.add_argument("--kib", type=int, default=64, help="size of each file, KiB")
    ap.add_argument("--dir", type=Path, help="where (default: a temporary folder; use the runs disk)")
    args = ap.parse_args(argv)
    data = bytes(range(256)) * (args.kib * 4)
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        folder = Path(tmp)
        (folder / "plain").mkdir()
        (folder / "atomic").mkdir()
        _time(atomic.write_bytes, folder / "atomic", 2, data)  # warm up
        plain = _time(lambda p, d: p.write_bytes(d), folder / "plain", args.files, data)
        safe = _time(atomic.write_bytes, folder / "atomic", args.files, data)
    n = args.files
    print(f"{n} files of {args.kib} KiB in {folder.parent}")
    print(f"  Path.write_bytes (baseline)   {plain / n * 1e3:8.3f} ms/file")
    print(f"  atomic.write_bytes            {safe / n * 1e3:8.3f} ms/file   = {safe / plain:6.1f} × baseline")
    print(f"  extra for a 20-file report    {(safe - plain) / n * 20:8.3f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
