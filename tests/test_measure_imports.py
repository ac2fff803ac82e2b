"""`rig measure`'s modules load no heavy library that a measurement with a given timing does not use:
scipy.signal and scipy.stats (≈ 1 CPU-s of imports in every fresh process) are imported where they are
called (the timing estimate, the rig's own reports), not by importing the command's modules."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# what rig.cli_measure.cmd_measure imports before it measures
_IMPORTS = """
import json, sys
from drivers.camera.video_file import VideoFileError
from reports.measurement import write_measurement_report
from rig.deploy.measure import MeasureError, MeasureOptions, measure_videos
from rig.deploy.video_markers import ExtractOptions
from rig.record.out_guard import OutputRefusedError
heavy = (["scipy", "signal"], ["scipy", "stats"])
print(json.dumps(sorted(m for m in sys.modules if m.split(".")[:2] in heavy)))
"""


def test_measure_command_imports_neither_scipy_signal_nor_scipy_stats():
    done = subprocess.run([sys.executable, "-c", _IMPORTS], cwd=ROOT, capture_output=True, text=True,
                          check=True, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert json.loads(done.stdout.strip().splitlines()[-1]) == []
