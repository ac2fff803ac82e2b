"""Benchmark: N-view triangulation speed and accuracy on a synthetic stereo pair (prints figures only).

Same run, same 10^5 noisy observations (σ = 0.5 px) of points inside a 480 × 360 × 200 mm volume seen by
two 1920×1080 cameras 1.5 m away (projected with cv2.projectPoints):
  - ours, linear (normalized homogeneous LS, vectorized), and with refinement (+ covariance);
  - cv2.triangulatePoints (2-view linear DLT, unnormalized);
  - the obvious per-point loop with numpy SVD (timed on 5,000 points, scaled).
Run: ``.venv/bin/python benchmarks/stereo_triangulate.py``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from stereo_scene import noise_floor_mm, stereo_pair, volume_points  # noqa: E402

from rig.stereo import DLTCamera, triangulate  # noqa: E402

N_POINTS = 100_000
N_LOOP = 5_000
SIGMA_PX = 0.5


def best_of(fn, repeat: int = 3) -> tuple[float, object]:
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def loop_svd(P, uv_a, uv_b):
    out = np.empty((len(uv_a), 3))
    for k in range(len(uv_a)):
        A = np.array(
            [
                uv_a[k, 0] * P[0][2] - P[0][0],
                uv_a[k, 1] * P[0][2] - P[0][1],
                uv_b[k, 0] * P[1][2] - P[1][0],
                uv_b[k, 1] * P[1][2] - P[1][1],
            ]
        )
        X = np.linalg.svd(A)[2][-1]
        out[k] = X[:3] / X[3]
    return out


def rms_mm(xyz, truth):
    return float(np.sqrt(np.mean(np.sum((xyz - truth) ** 2, axis=1))))


def main() -> None:
    rng = np.random.default_rng(0)
    true = stereo_pair()
    cams = [DLTCamera(c.K @ np.hstack([cv2.Rodrigues(c.rvec)[0], c.tvec])) for c in true]
    X = volume_points(N_POINTS, rng)
    uv = [c.project(X) + rng.normal(0, SIGMA_PX, (N_POINTS, 2)) for c in true]
    P = [c.P for c in cams]
    floor = noise_floor_mm(list(true), X, SIGMA_PX)

    t_lin, lin = best_of(lambda: triangulate(cams, uv))
    t_ref, ref = best_of(lambda: triangulate(cams, uv, refine=True, pixel_sigma_px=SIGMA_PX))

    def cv2_tri():
        h = cv2.triangulatePoints(P[0], P[1], uv[0].T, uv[1].T)
        return (h[:3] / h[3]).T

    t_cv, xyz_cv = best_of(cv2_tri)
    t_loop, xyz_loop = best_of(lambda: loop_svd(P, uv[0][:N_LOOP], uv[1][:N_LOOP]), repeat=1)
    t_loop_scaled = t_loop * N_POINTS / N_LOOP

    print(
        f"triangulation of {N_POINTS:,} points, 2 cameras, σ = {SIGMA_PX} px; noise floor {floor:.3f} mm RMS"
    )
    rows = [
        ("ours linear (vectorized)", t_lin, rms_mm(lin.xyz_mm, X)),
        ("ours refined + covariance", t_ref, rms_mm(ref.xyz_mm, X)),
        ("cv2.triangulatePoints", t_cv, rms_mm(xyz_cv, X)),
        (
            f"per-point SVD loop (×{N_POINTS // N_LOOP} from {N_LOOP:,})",
            t_loop_scaled,
            rms_mm(xyz_loop, X[:N_LOOP]),
        ),
    ]
    print(f"{'method':45s} {'ms total':>10s} {'µs/point':>9s} {'vs loop':>8s} {'RMS mm':>8s}")
    for name, t, err in rows:
        print(f"{name:45s} {t * 1e3:10.1f} {t / N_POINTS * 1e6:9.2f} {t_loop_scaled / t:7.1f}× {err:8.3f}")


if __name__ == "__main__":
    main()
