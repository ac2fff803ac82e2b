"""Fuzz every mock server: runs ``fuzz(n_packets, seed)`` of each ``benchmarks/fuzz_*.py`` module and prints
one table.

    .venv/bin/python benchmarks/fuzz.py [--packets N] [--seed S] [--only NAME]

Each module's ``fuzz`` returns ``packets, crashes, hangs, bad_replies, rss_growth_mb, seconds``. Target:
0 crashes, 0 hangs, RSS growth < 5 MB per 10⁵ packets (5 MB for shorter runs, where the warm-up
dominates; scaled up for longer ones). Exit code 1 when a server misses the target.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
if str(HERE.parent) not in sys.path:  # the fuzz modules import the project's packages
    sys.path.insert(0, str(HERE.parent))
KEYS = ("packets", "crashes", "hangs", "bad_replies", "rss_growth_mb", "seconds")
RSS_LIMIT_MB_PER_1E5 = 5.0


def fuzz_modules() -> dict[str, Path]:
    """name (``modbus`` for ``fuzz_modbus.py``) → path, sorted."""
    return {p.stem.removeprefix("fuzz_"): p for p in sorted(HERE.glob("fuzz_*.py"))}


def run_one(path: Path, n_packets: int, seed: int) -> dict[str, float]:
    spec = importlib.util.spec_from_file_location(f"benchmarks_{path.stem}", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the class is built
    spec.loader.exec_module(module)
    result = module.fuzz(n_packets, seed)
    missing = [k for k in KEYS if k not in result]
    if missing:
        raise RuntimeError(f"{path.name}: fuzz() result lacks {missing}")
    return {k: float(result[k]) for k in KEYS}


def meets_target(result: dict[str, float]) -> bool:
    limit_mb = RSS_LIMIT_MB_PER_1E5 * max(result["packets"], 1e5) / 1e5  # a short run: warm-up dominates
    return result["crashes"] == 0 and result["hangs"] == 0 and result["rss_growth_mb"] < limit_mb


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--packets", type=int, default=100_000, help="packets per server (default 100000)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--only", action="append", help="run only this server (repeatable), e.g. modbus")
    args = parser.parse_args(argv)
    modules = {n: p for n, p in fuzz_modules().items() if not args.only or n in args.only}
    if not modules:
        parser.error(f"no fuzz module matches {args.only}; have {sorted(fuzz_modules())}")
    header = f"{'server':<10}" + "".join(f"{k:>15}" for k in KEYS) + "  target"
    rows, ok = [header], True
    for name, path in modules.items():
        result = run_one(path, args.packets, args.seed)
        passed = meets_target(result)
        ok &= passed
        rows.append(f"{name:<10}" + "".join(f"{result[k]:>15.2f}" if k in ("rss_growth_mb", "seconds")
                                            else f"{result[k]:>15.0f}" for k in KEYS)
                    + ("  met" if passed else "  MISSED"))
        print(rows[-1] if len(rows) > 2 else "\n".join(rows), flush=True)
    print(f"target: 0 crashes, 0 hangs, RSS growth < {RSS_LIMIT_MB_PER_1E5:g} MB per 1e5 packets")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
