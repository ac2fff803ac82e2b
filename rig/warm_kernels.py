"""Compile the numba kernels into their on-disk cache once, at install time (``make``'s install step).

Without the cache the first use of a kernel compiles it: ≈ 30 CPU-s on a 2-core VM (marker detection and
tracking, the duplicate test's change map) — a newcomer's first ``rig calibrate`` would pay it. With it, a
process loads the compiled code in ≈ 0.6 CPU-s. The cache lives next to the kernels' sources (numba's
``__pycache__``) and numba invalidates it when a kernel's source changes. Run: ``python -m rig.warm_kernels``.
"""

from __future__ import annotations

import time

import numpy as np
import pandas as pd

from drivers.camera import change_kernel
from rig.analysis.frame_reduction import ReduceOptions, warm_up
from rig.analysis.tracks2d import tracks_2d
from rig.stereo import detect_markers
from rig.stereo.fiducial import DriveEdges, mean_levels
from rig.stereo.fiducial_kernel import grid_sse
from rig.stereo.resample import bandlimited


def warm_all() -> float:
    """Load or compile every kernel (markers: detection and tracking, and the joining of row bands a
    detection on several threads uses; video: the change map and a duplicate candidate's region kernels;
    the band-limited reconstruction's kernel rows; 2-D tracking's usual frames; the timing fiducial's
    levels and offset search).

    Returns the CPU seconds spent."""
    start_s = time.process_time()
    warm_up(ReduceOptions())
    yy, xx = np.mgrid[0:320, 0:96]
    disc = np.where((xx - 48.0) ** 2 + (yy - 160.0) ** 2 <= 64.0, 220, 30).astype(np.uint8)
    detect_markers(disc, threads=2)  # two row bands: the disc straddles their edge
    image = np.zeros((16, 16), np.uint8)
    change_kernel.half_change_stats(image, change_kernel.half_only(image))  # every block's change map
    change_kernel.sampled_stats(image, change_kernel.sampled_half(image))  # the duplicate test's per frame
    # a duplicate candidate's region: where the markers moved, and its four change maps
    zero_map = np.zeros((1, 1), np.float32)
    rows, cols = change_kernel.motion_region(zero_map, zero_map, 0.0, 0.0, (2, 2))
    pairs = np.array([[0, 1], [2, 3], [1, 2], [0, 3]], np.int64)
    change_kernel.region_changes((image,) * 4, rows, cols, pairs)
    t_s = np.arange(80) / 60.0 + 0.002 * np.sin(np.arange(80))  # jittered instants: the sparse solve's rows
    bandlimited(t_s, np.sin(t_s), t_s[10:20] + 0.004, noise_gain=True)  # and the noise gain's kernels
    rows_s, edges = np.arange(4) * 1e-3, DriveEdges(np.array([1e-3, 2e-3]), np.array([True, False]))
    mean_levels(rows_s, 1e-4, edges, 1e-5)  # the fiducial's levels and offset search
    grid_sse(rows_s, rows_s, 1e-4, edges.times_s, edges.signs, edges.states, 1e-5, rows_s)
    steps = np.arange(6.0)  # two markers over six frames: tracks start, then the compiled frames carry them
    tracks_2d(pd.DataFrame({"frame_index": np.repeat(steps, 2), "timestamp_s": np.repeat(steps / 60.0, 2),
                            "u_px": np.tile([100.0, 400.0], 6) + np.repeat(steps, 2), "v_px": 200.0}))
    return time.process_time() - start_s


def main() -> None:
    print(f"numba kernels compiled or loaded from their cache in {warm_all():.1f} CPU-s")


if __name__ == "__main__":
    main()
