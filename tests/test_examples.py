"""The example script renders every target to PNG files a person can look at."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def test_render_targets_writes_a_non_blank_png_of_every_scene(tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, str(ROOT / "examples" / "render_targets.py"), str(tmp_path)],
                          check=False, capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    names = {p.stem for p in tmp_path.glob("*.png")}
    for scene in ("calibration_plate", "single_marker", "marker_frame", "plate", "rotor", "sweep_column"):
        assert any(n.startswith(scene) for n in names), (scene, sorted(names))
    for path in tmp_path.glob("*_zoom.png"):
        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        assert img is not None and int(np.ptp(img)) > 50, path.name  # markers visible against the background
