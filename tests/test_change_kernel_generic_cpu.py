"""The duplicate test's compiled kernels give the same bytes when compiled for this host's CPU and for a
generic x86-64 (``NUMBA_CPU_NAME=generic``): a vectorising miscompilation for the host (one was found in
the marker kernel on AVX-512) would show here as a difference on random frames."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from drivers.camera import change_kernel

ROOT = Path(__file__).resolve().parents[1]

# the child computes every kernel's output on the same seeded inputs and saves them (npz)
_CHILD = """
import sys
import numpy as np
sys.path.insert(0, sys.argv[2])
from tests.test_change_kernel_generic_cpu import kernel_outputs
np.savez(sys.argv[1], **kernel_outputs())
"""


def _frames(rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray]]:
    """Pairs of frames: random sizes (multiples of 8, odd block counts included), unrelated, nearly equal
    (small changes in some pixels), and the extremes 0 / 255."""
    out = []
    for k in range(40):
        h, w = 8 * int(rng.integers(1, 40)), 8 * int(rng.integers(1, 40))
        a = rng.integers(0, 256, (h, w), dtype=np.uint8)
        if k % 3 == 0:
            b = rng.integers(0, 256, (h, w), dtype=np.uint8)
        else:
            step = rng.integers(-4, 5, (h, w)) * (rng.random((h, w)) < 0.3)
            b = np.clip(a.astype(int) + step, 0, 255).astype(np.uint8)
        out.append((a, b))
    out.append((np.full((136, 240), 255, np.uint8), np.zeros((136, 240), np.uint8)))
    out.append((np.zeros((1080, 1920), np.uint8), rng.integers(0, 256, (1080, 1920), dtype=np.uint8)))
    return out


def kernel_outputs() -> dict[str, np.ndarray]:
    """Every kernel's output on the seeded frame pairs, by name (the largest and median as 1-element
    arrays)."""
    out: dict[str, np.ndarray] = {}
    for i, (a, b) in enumerate(_frames(np.random.default_rng(20261202))):
        half, change, max_dn, floor_dn = change_kernel.half_change_stats(a, change_kernel.half_only(b))
        sampled, sampled_map, s_max, s_floor = change_kernel.sampled_stats(a, change_kernel.sampled_half(b))
        rows, cols = np.divmod(np.flatnonzero(change >= np.median(change)), change.shape[1])
        region = change_kernel.region_changes((a, b), rows, cols, np.array([[0, 1], [1, 0]]))
        moved = change_kernel.motion_region(sampled_map, sampled_map[::-1], s_max / 4, s_floor, change.shape)
        out.update({f"{i}_half": half, f"{i}_change": change, f"{i}_stats": np.array([max_dn, floor_dn]),
                    f"{i}_sampled": sampled, f"{i}_sampled_map": sampled_map,
                    f"{i}_sampled_stats": np.array([s_max, s_floor]), f"{i}_region": region,
                    f"{i}_motion_region": np.stack(moved)})
    return out


@pytest.mark.slow
def test_host_and_generic_cpu_code_give_the_same_bytes(tmp_path: Path) -> None:
    env = {**os.environ, "NUMBA_CPU_NAME": "generic", "NUMBA_CACHE_DIR": str(tmp_path / "cache"),
           "PYTHONPATH": str(ROOT)}
    subprocess.run([sys.executable, "-c", _CHILD, str(tmp_path / "generic.npz"), str(ROOT)], env=env,
                   check=True, timeout=600)
    host = kernel_outputs()
    with np.load(tmp_path / "generic.npz") as generic:
        assert sorted(generic.files) == sorted(host)
        for name, value in host.items():
            assert generic[name].dtype == value.dtype and generic[name].tobytes() == value.tobytes(), name
