"""The sweep's plan is checked against the limits of the device that drives the sweep column.

On the simulated rig, through the real ``rig`` command, with ``targets.sweep_column.body = "shaker"``:
the generator's (shaker's) limits apply, not the exciter's; a plan above them, or beyond the shaker's
sensitivity table (no extrapolation), is refused with exit 4 before any device is connected (no run folder).
Shaker sweeps that run are in ``tests/test_procedures_shaker.py``.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

from tests.certify_support import write_config

ROOT = Path(__file__).resolve().parents[1]


def _shaker_config(tmp_path: Path, generator_max_hz: float) -> Path:
    path = write_config(tmp_path)
    text = path.read_text()
    text, n_body = re.subn(r'(\[targets\.sweep_column\]\nbody = )"exciter"', r'\1"shaker"', text)
    text, n_lim = re.subn(r'(\[limits\.generator\][^\n]*\nmax_frequency_hz = )[0-9.]+',
                          rf"\g<1>{generator_max_hz}", text)
    assert n_body == 1 and n_lim == 1
    path.write_text(text)
    return path


def _run_sweep(tmp_path: Path, config: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "rig.cli", "run", "sweep", "--config", str(config)],
                          cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True,
                          text=True, timeout=240, check=False)


def _nothing_built(tmp_path: Path) -> None:
    assert not (tmp_path / "runs").exists()  # refused before the run folder and the station


def test_shaker_column_is_checked_against_the_generator_limits(tmp_path: Path) -> None:
    # 30 Hz is within the exciter's 32 Hz but above the 20 Hz given to the shaker
    proc = _run_sweep(tmp_path, _shaker_config(tmp_path, 20.0))
    assert proc.returncode == 4, proc.stderr
    assert "sweep.max_hz = 30 Hz" in proc.stderr and "exceeds the generator's limit 20 Hz" in proc.stderr
    assert "(limits.generator.max_frequency_hz)" in proc.stderr and "Traceback" not in proc.stderr
    _nothing_built(tmp_path)


def test_shaker_sweep_beyond_the_sensitivity_table_is_refused_before_motion(tmp_path: Path) -> None:
    config = _shaker_config(tmp_path, 100.0)
    text, n = re.subn(r"^sensitivity_mm_per_v = .*$", "sensitivity_mm_per_v = [[1.0, 0.5], [20.0, 0.5]]",
                      config.read_text(), flags=re.M)
    assert n == 1
    config.write_text(text)
    proc = _run_sweep(tmp_path, config)  # to 30 Hz: the table stops at 20 Hz (no extrapolation)
    assert proc.returncode == 4, proc.stderr
    assert "devices.generator.sensitivity_mm_per_v" in proc.stderr and "1..20 Hz" in proc.stderr, proc.stderr
    _nothing_built(tmp_path)
