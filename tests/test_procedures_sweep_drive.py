"""The sweep's plan is checked against the limits of the device that drives the sweep column.

On the simulated rig, through the real ``rig`` command, with ``targets.sweep_column.body = "shaker"``:
the generator's (shaker's) limits apply, not the exciter's; a plan above them exits 3 before anything is
sent; a plan beyond the shaker's sensitivity table is refused (exit 4, nothing sent: no extrapolation).
Shaker sweeps that run are in ``tests/test_procedures_shaker.py``.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

from rig.catalogue import run_folders
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


def _run_sweep(tmp_path: Path, config: Path) -> tuple[subprocess.CompletedProcess, list[dict]]:
    proc = subprocess.run([sys.executable, "-m", "rig.cli", "run", "sweep", "--config", str(config)],
                          cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True,
                          text=True, timeout=240, check=False)
    (run_dir,) = run_folders(tmp_path / "runs")
    lines = (run_dir / "record.jsonl").read_text().splitlines()
    return proc, [json.loads(line) for line in lines if line.strip()]


def _nothing_sent(docs: list[dict]) -> None:
    assert not [d for d in docs if d["type"] == "step"]
    assert [d["stream"] for d in docs if d["type"] == "event"] == ["devices"]


def test_shaker_column_is_checked_against_the_generator_limits(tmp_path: Path) -> None:
    # 30 Hz is within the exciter's 32 Hz but above the 20 Hz given to the shaker
    proc, docs = _run_sweep(tmp_path, _shaker_config(tmp_path, 20.0))
    assert proc.returncode == 3, proc.stderr
    reason = next(d for d in docs if d["type"] == "interlock")["reason"]
    assert "shaker sweep" in reason and "exceeds the limit 20 Hz" in reason
    _nothing_sent(docs)
    assert docs[-1]["type"] == "stop" and docs[-1]["exit_code"] == 3


def test_shaker_sweep_beyond_the_sensitivity_table_is_refused_before_motion(tmp_path: Path) -> None:
    config = _shaker_config(tmp_path, 100.0)
    text, n = re.subn(r"^sensitivity_mm_per_v = .*$", "sensitivity_mm_per_v = [[1.0, 0.5], [20.0, 0.5]]",
                      config.read_text(), flags=re.M)
    assert n == 1
    config.write_text(text)
    proc, docs = _run_sweep(tmp_path, config)  # to 30 Hz: the table stops at 20 Hz (no extrapolation)
    assert proc.returncode == 4, proc.stderr
    reason = docs[-1]["reason"]
    assert "devices.generator.sensitivity_mm_per_v" in reason and "1..20 Hz" in reason, reason
    _nothing_sent(docs)
