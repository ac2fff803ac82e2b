"""The marker kernels compiled for this host's CPU give the bytes of the same kernels compiled unoptimised for
a generic x86-64 (``NUMBA_CPU_NAME=generic``: no AVX-512 or AVX2; ``NUMBA_OPT=0``: no vectorizer at all,
and a quarter less compile CPU than the optimised generic build, whose bytes are the same): a vectorizer
miscompilation on one host (an AVX-512 VM once lost eight columns of a marker's support) shows here as a
difference. The kernels use no fast-math, so no optimisation level may change a result."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from marker_images import Disc, render

from rig.stereo import detect_markers, track_markers

ROOT = Path(__file__).resolve().parents[1]


def scene_outputs(n_scenes: int = 24) -> dict[str, np.ndarray]:
    """Detection and tracking rows of random scenes: markers of 3–12 px radius anywhere (across the frame's
    edge too), both polarities, some saturated, 1 and 2 threads, four tracking window sizes, the
    outline fit."""
    out: dict[str, np.ndarray] = {}
    rng = np.random.default_rng(16)
    for s in range(n_scenes):
        shape = (int(rng.integers(40, 240)), int(rng.integers(40, 320)))
        discs = [Disc(rng.uniform(-5, shape[1] + 5), rng.uniform(-5, shape[0] + 5), rng.uniform(3, 12))
                 for _ in range(int(rng.integers(1, 12)))]
        img = render(shape, discs, background_dn=float(rng.uniform(10, 80)),
                     blur_sigma_px=float(rng.uniform(0.5, 1.5)), noise_sigma_dn=float(rng.uniform(0.5, 4)),
                     seed=s)
        if s % 5 == 0:  # clipped at 255
            img = np.clip(img.astype(np.int64) * 2, 0, 255).astype(np.uint8)
        polarity = "dark" if s % 3 == 0 else "bright"
        if polarity == "dark":
            img = 255 - img
        pred = np.array([[d.u_px, d.v_px] for d in discs]) + rng.normal(0, 1.5, (len(discs), 2))
        for threads in (1, 2):
            out[f"detect{s}_{threads}"] = detect_markers(img, polarity=polarity, threads=threads)
            for window_px in (9, 21, 33, 61):
                out[f"track{s}_{threads}_{window_px}"] = track_markers(img, pred, window_px=window_px,
                                                                       polarity=polarity, threads=threads)
        out[f"ellipse{s}"] = track_markers(img, pred, window_px=25, polarity=polarity, centre="ellipse")
    return out


@pytest.mark.slow
@pytest.mark.timeout(1800)  # the generic compile in a subprocess: ≈ 45 CPU-s, over 300 s of wall at load ≈ 20
def test_host_and_generic_code_give_the_same_bytes(tmp_path: Path) -> None:
    generic = tmp_path / "generic.npz"
    probe = ("import sys, numpy as np; sys.path.insert(0, 'tests'); "
             "from test_stereo_markers_generic import scene_outputs; "
             f"np.savez({str(generic)!r}, **scene_outputs())")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NUMBA_CPU_NAME": "generic", "NUMBA_OPT": "0",
           "NUMBA_CACHE_DIR": str(tmp_path / "numba_cache")}  # compiled apart from the host's cache
    subprocess.run([sys.executable, "-c", probe], cwd=ROOT, env=env, check=True, timeout=1800)
    host = scene_outputs()
    with np.load(generic) as stored:
        assert sorted(stored.files) == sorted(host)
        differ = [key for key in host if stored[key].tobytes() != host[key].tobytes()]
    assert not differ, f"host and generic code differ in {differ}"
