"""``rig --help`` and ``rig list`` (the procedures' parameters) start without the heavy libraries, and a dry
run (or a refused one) without any but numpy: checked on ``sys.modules`` of a fresh interpreter
(deterministic; the start times themselves are in benchmarks/cli_start.py)."""

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
print(json.dumps({"code": code, "heavy": sorted(m for m in HEAVY if m in sys.modules),
                  "stereo": sorted(m for m in sys.modules if m.startswith("rig.stereo"))}))
""".replace("HEAVY", repr(HEAVY))


NUMPY_ONLY_STEREO = ["rig.stereo", "rig.stereo.errors"]  # the package and its exceptions: no SciPy, no OpenCV


def _imported(*args: str) -> dict:
    done = subprocess.run([sys.executable, "-c", PROBE, *args], env={**os.environ, "PYTHONPATH": str(ROOT)},
                          capture_output=True, text=True, timeout=300, check=True)
    return json.loads(done.stdout.splitlines()[-1])


@pytest.mark.parametrize("args", [("--help",), ("certify", "--help"), ("run", "--help"),
                                  ("measure", "--help"), ("runs", "--help"), ("list", "--help"), ("list",),
                                  ()])
def test_help_and_list_import_no_heavy_library(args: tuple[str, ...]) -> None:
    assert _imported(*args) == {"code": 0, "heavy": [], "stereo": []}


@pytest.mark.parametrize(("args", "code"), [(("certify", "--dry-run"), 0),
                                            (("run", "sweep", "--dry-run", "--set", "max_hz=50"), 4)])
def test_a_dry_run_imports_numpy_only(args: tuple[str, ...], code: int) -> None:
    """A plan is printed and checked (or refused) with numpy alone: loading the procedures (``rig run`` loads
    every one, certify's steps included) imports neither the stereo core (SciPy, OpenCV; its exceptions
    only) nor pandas/pyarrow nor numba (≈ 1 CPU-s of imports in all), which only a recording and its analysis
    use."""
    assert _imported(*args) == {"code": code, "heavy": ["numpy"], "stereo": NUMPY_ONLY_STEREO}


def test_a_run_refused_before_connecting_imports_numpy_only(tmp_path: Path) -> None:
    """The runner and its record writer load without pandas/pyarrow (≈ 0.3 CPU-s), which the observations
    need only once a recording writes them: a plan the runner refuses is refused with numpy alone."""
    imported = _imported("run", "calibrate", "--no-dashboard", "--runs-dir", str(tmp_path / "runs"),
                         "--set", "slide_positions_mm=[0.0, 300.0]")
    assert imported == {"code": 4, "heavy": ["numpy"], "stereo": NUMPY_ONLY_STEREO}
    assert not (tmp_path / "runs").exists()  # refused before its run folder
