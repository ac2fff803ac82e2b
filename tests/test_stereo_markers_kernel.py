"""The compiled marker kernel: loaded only by a measurement, and usable where its cache cannot be written."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from rig.stereo import markers_kernel

ROOT = Path(__file__).resolve().parents[1]


def test_a_function_without_a_cache_location_is_compiled_in_the_process() -> None:
    # a function defined by exec has no source file: numba has no location to cache it and refuses cache=True
    namespace: dict[str, object] = {}
    exec("def twice(x):\n    return 2 * x\n", namespace)
    with pytest.warns(RuntimeWarning, match="not cached on disk"):
        twice = markers_kernel._jit(namespace["twice"])
    assert twice(21) == 42
    assert twice(np.float32(1.5)) == 3.0


def test_importing_the_stereo_core_does_not_load_numba() -> None:
    probe = textwrap.dedent("""
        import sys
        import numpy as np
        from rig.stereo import track_markers
        loaded_at_import = "numba" in sys.modules
        img = np.zeros((64, 64), np.uint8)
        img[28:36, 28:36] = 200
        row = track_markers(img, np.array([[31.5, 31.5]]))
        print(loaded_at_import, "numba" in sys.modules, row["u_px"][0], row["v_px"][0])
    """)
    done = subprocess.run([sys.executable, "-c", probe], env={**os.environ, "PYTHONPATH": str(ROOT)},
                          capture_output=True, text=True, timeout=600, check=True)
    at_import, after_measuring, u_px, v_px = done.stdout.split()
    assert (at_import, after_measuring) == ("False", "True")
    assert (float(u_px), float(v_px)) == (31.5, 31.5)  # an 8×8 flat square centred between pixels
