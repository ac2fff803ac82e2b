"""Regression on real DLT data (vaila test set, cameras c01 and c02; see shared/data/vaila_dlt/README.md).

Tolerances: the stored coefficients are printed with 6 decimals, so the L12 = 1 least squares is compared
to 2e-5 relative (README: ~1e-5; measured 7.2e-6 c01, 8.9e-6 c02). Figures the README gives to one
decimal (RMS 5.0 / 6.5 px) are checked to ±0.05 px, those given to the millimetre (38 / 81 mm) to ±1 mm.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from rig.stereo import DLTCamera, P_from_dlt11, calibrate_dlt, dlt11_from_P, solve_dlt11
from rig.stereo.triangulate import triangulate

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "vaila_dlt"
CAMERAS = ("c01", "c02")

if not DATA.is_dir():
    # CI runs with ../shared beside the clone: there a missing folder is a failure, not a silent skip.
    if os.environ.get("CI"):
        raise RuntimeError(f"real data folder {DATA} is missing (CI expects ../shared/data beside the repo)")
    pytestmark = pytest.mark.skip(reason=f"real data folder {DATA} is missing")


def load(cam: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """xyz in mm (the file is in metres), pixel picks (25, 2), stored L1…L11 (metre units)."""
    xyz_mm = np.loadtxt(DATA / "ref3d_realworld.csv", delimiter=",") * 1000.0
    uv = np.loadtxt(DATA / f"{cam}_pixels.csv", delimiter=",", skiprows=1)[1:].reshape(-1, 2)
    L = np.loadtxt(DATA / f"{cam}_dlt11.csv", delimiter=",", skiprows=1)
    return xyz_mm, uv, L


@pytest.mark.parametrize("cam", CAMERAS)
def test_l12_least_squares_reproduces_stored_coefficients(cam: str) -> None:
    xyz_mm, uv, L = load(cam)
    ours = solve_dlt11(xyz_mm / 1000.0, uv)
    np.testing.assert_allclose(ours, L, rtol=2e-5)
    # The same through mm units and the 3×4 P.
    P = P_from_dlt11(solve_dlt11(xyz_mm, uv))
    np.testing.assert_allclose(dlt11_from_P(P, length_unit_mm=1000.0), L, rtol=2e-5)


def test_paper_homogeneous_svd_close_to_stored_c01() -> None:
    """README: the homogeneous SVD rescaled by b12 differs by at most ~0.3 % per coefficient (c01).

    That figure is for the paper's raw (unnormalized) solve; measured 0.33 % in mm, 0.32 % in metres.
    (For c02 the same comparison gives up to 1.0 %, so the README's 0.3 % is a c01 figure only.)
    """
    xyz_mm, uv, L = load("c01")
    raw = calibrate_dlt(xyz_mm, uv, normalize=False)
    rel = np.abs(raw.dlt11(length_unit_mm=1000.0) - L) / np.abs(L)
    assert rel.max() <= 0.0035, rel


@pytest.mark.parametrize("cam", CAMERAS)
def test_normalized_svd_predicts_same_pixels_as_stored(cam: str) -> None:
    """Hartley-normalized SVD minimises another algebraic error: coefficients near zero (L10 ≈ −0.003)
    differ by a few %, so compare what matters — the predicted pixels (well under the 1-px pick quantum)
    and the reprojection RMS (within 3 % of the stored solution's)."""
    xyz_mm, uv, L = load(cam)
    ours = calibrate_dlt(xyz_mm, uv)
    stored = DLTCamera.from_dlt11(L, length_unit_mm=1000.0)
    assert np.abs(ours.project(xyz_mm) - stored.project(xyz_mm)).max() < 1.0
    stored_rms = np.sqrt(np.mean(np.sum((stored.project(xyz_mm) - uv) ** 2, axis=1)))
    assert abs(ours.rms_px - stored_rms) <= 0.03 * stored_rms


@pytest.mark.parametrize(("cam", "rms_px"), [("c01", 5.0), ("c02", 6.5)])
def test_reprojection_rms_as_readme(cam: str, rms_px: float) -> None:
    xyz_mm, uv, L = load(cam)
    stored = DLTCamera.from_dlt11(L, length_unit_mm=1000.0)
    rms = np.sqrt(np.mean(np.sum((stored.project(xyz_mm) - uv) ** 2, axis=1)))
    assert rms == pytest.approx(rms_px, abs=0.05)
    assert calibrate_dlt(xyz_mm, uv).rms_px == pytest.approx(rms_px, abs=0.1)
    # Refinement minimises exactly this figure, so it cannot be worse.
    assert calibrate_dlt(xyz_mm, uv, refine=True).rms_px <= calibrate_dlt(xyz_mm, uv).rms_px


def test_triangulation_with_stored_coefficients_as_readme() -> None:
    loaded = [load(c) for c in CAMERAS]
    xyz_mm = loaded[0][0]
    cams = [DLTCamera.from_dlt11(L, length_unit_mm=1000.0) for _, _, L in loaded]
    result = triangulate(cams, [uv for _, uv, _ in loaded])
    err = np.linalg.norm(result.xyz_mm - xyz_mm, axis=1)
    assert np.sqrt(np.mean(err**2)) == pytest.approx(38.0, abs=1.0)
    assert err.max() == pytest.approx(81.0, abs=1.0)
    assert (result.n_views == 2).all()


def test_decomposition_of_real_camera_is_consistent() -> None:
    xyz_mm, uv, _ = load("c01")
    cam = calibrate_dlt(xyz_mm, uv)
    K, R, centre = cam.decompose()
    assert K[0, 0] > 0 and K[1, 1] > 0 and K[2, 2] == pytest.approx(1.0)
    assert np.allclose(np.tril(K, -1), 0.0)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    # Rebuilding P from K, R, C reproduces it up to scale.
    P = K @ np.hstack([R, (-R @ centre)[:, None]])
    np.testing.assert_allclose(P / np.linalg.norm(P), cam.P / np.linalg.norm(cam.P), atol=1e-12)
    # The control points lie in front of the camera.
    assert (np.hstack([xyz_mm, np.ones((len(xyz_mm), 1))]) @ cam.P[2] > 0).all()
