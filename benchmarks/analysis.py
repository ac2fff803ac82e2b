"""Benchmark: the analysis of a 30 s sweep (1 → 30 Hz, the twin's sweep column + 4 references, two 60 fps
cameras, σ = 0.1 px) — speed of each stage and amplitude error per frequency band for every sync method.

Prints: seconds per stage and observations per second; for each sync method the relative amplitude
error (%) of the column's vertical motion in 1 Hz bands (3-parameter sine fit at the twin's exact phase),
and the wall time of triangulation relative to the paper's ``linear`` (the baseline, same run).
Run: ``.venv/bin/python benchmarks/analysis.py [duration_s]``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from analysis_twin import twin  # noqa: E402

from rig.analysis.sync_tracks import SYNC_METHODS, pair_all, prepare_observations, triangulate_tracks  # noqa: E402

BANDS_HZ = (2, 6, 10, 14, 18, 22, 26, 28)


def _amplitude_errors(tw, tracks) -> list[float]:
    out = []
    for _, g in tracks.groupby("track_id"):
        w = tw.world_time(g["time_s"].to_numpy())
        X = g[["x_mm", "y_mm", "z_mm"]].to_numpy()
        truth = tw.world.positions(["col2"], w)[0]
        if np.sqrt(np.mean(np.sum((truth - X) ** 2, axis=1))) > 5.0:
            continue
        f = tw.world.exciter.frequency_hz(w)
        phase = tw.world.exciter.phase_rad(w)
        for lo in BANDS_HZ:
            sel = (f >= lo) & (f < lo + 1)
            A = np.column_stack([np.ones(sel.sum()), np.cos(phase[sel]), np.sin(phase[sel])])
            got = np.linalg.lstsq(A, X[sel, 2], rcond=None)[0]
            ref = np.linalg.lstsq(A, truth[sel, 2], rcond=None)[0]
            out.append(100.0 * (np.hypot(*got[1:]) / np.hypot(*ref[1:]) - 1.0))
    return out


def main() -> None:
    duration_s = float(sys.argv[1]) if len(sys.argv) > 1 else 30.0
    tw = twin("sweep_column", setup=lambda w: w.exciter.sweep(1.0, 1.0, 30.0, duration_s, "linear"),
              t_start_s=1.0, t_stop_s=1.0 + duration_s, sigma_px=0.1, seed=1)
    n_obs = sum(len(o) for o in tw.observations.values())
    print(f"sweep 1 → 30 Hz over {duration_s:.0f} s: {n_obs} observations (2 cameras, 9 markers)")
    t0 = time.perf_counter()
    obs = {c: prepare_observations(tw.observations[c], tw.timing, c) for c in tw.observations}
    t_track = time.perf_counter() - t0
    t0 = time.perf_counter()
    pairs, _ = pair_all(obs, tw.cameras, "left")
    t_pair = time.perf_counter() - t0
    print(f"2-D tracking: {t_track:.2f} s ({n_obs / t_track:,.0f} obs/s); pairing: {t_pair:.2f} s")
    times = {}
    print(f"{'sync':12s} {'time s':>7s} {'× linear':>9s}  amplitude error % in bands {BANDS_HZ} Hz")
    for sync in ("linear", *[m for m in SYNC_METHODS if m != "linear"]):
        t0 = time.perf_counter()
        tracks = triangulate_tracks(obs, tw.cameras, tw.timing, sync=sync, pairs=pairs)
        times[sync] = time.perf_counter() - t0
        errs = _amplitude_errors(tw, tracks)
        ratio = times[sync] / times["linear"]
        print(f"{sync:12s} {times[sync]:7.2f} {ratio:9.1f}  " + " ".join(f"{e:6.2f}" for e in errs))


if __name__ == "__main__":
    main()
