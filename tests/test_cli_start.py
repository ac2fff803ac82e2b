"""``rig --help`` and ``rig list`` (the procedures' parameters) start without the heavy libraries: checked on
``sys.modules`` of a fresh interpreter (deterministic; the start times themselves are in
benchmarks/cli_start.py)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("numpy", "pandas", "cv2", "scipy", "matplotlib", "dask", "distributed", "pyarrow", "numba")
PROBE = """\
import contextlib, io, json, sys
from rig.cli import main
with contextlib.redirect_stdout(io.StringIO()):
    try:
        code = main(sys.argv[1:])
    except SystemExit as exc:
        code = exc.code
print(json.dumps({"code": code, "heavy": sorted(m for m in HEAVY if m in sys.modules)}))
""".replace("HEAVY", repr(HEAVY))


def _imported(*args: str) -> dict:
    done = subprocess.run([sys.executable, "-c", PROBE, *args], env={**os.environ, "PYTHONPATH": str(ROOT)},
                          capture_output=True, text=True, timeout=300, check=True)
    return json.loads(done.stdout.splitlines()[-1])


@pytest.mark.parametrize("args", [("--help",), ("certify", "--help"), ("run", "--help"),
                                  ("measure", "--help"), ("runs", "--help"), ("list", "--help"), ("list",),
                                  ()])
def test_help_and_list_import_no_heavy_library(args: tuple[str, ...]) -> None:
    assert _imported(*args) == {"code": 0, "heavy": []}


def test_a_dry_run_imports_no_frame_reduction() -> None:
    """A plan is checked without the frame reduction's compiled kernels: loading the procedures (``rig run``
    loads every one, certify's steps included) does not import numba (≈ 0.4 CPU-s), which only a recording
    uses."""
    imported = _imported("run", "sweep", "--dry-run")
    assert imported["code"] == 0 and "numba" not in imported["heavy"], imported
