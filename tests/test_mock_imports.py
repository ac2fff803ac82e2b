"""The stand-alone mock servers of the drives and the generator serve without SciPy: their world's arm (whose
orientations need ``scipy.spatial.transform``, ≈ 0.5 CPU-s of imports per process) is never turned there.
Checked on the imports of the real ``rig mock`` process (``python -X importtime``) once it serves."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _modules_imported_by_a_serving_mock(device: str) -> set[str]:
    argv = [sys.executable, "-X", "importtime", "-m", "rig.cli", "mock", device, "--port", "0"]
    proc = subprocess.Popen(argv, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        assert "tcp://127.0.0.1:" in proc.stdout.readline()  # its world built, serving
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    # "import time: self [us] | cumulative | imported package"
    return {line.rpartition("|")[2].strip() for line in err.splitlines() if line.startswith("import time:")}


@pytest.mark.parametrize("device", ["exciter", "generator"])
def test_the_drive_and_generator_mocks_serve_without_scipy(device: str) -> None:
    imported = _modules_imported_by_a_serving_mock(device)
    assert "drivers.sim.world" in imported  # the probe sees the mock's own imports
    assert sorted(m for m in imported if m.split(".")[0] == "scipy") == []
