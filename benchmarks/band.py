"""Amplitude beyond one camera's Nyquist limit: the pair's interleaved fit against one-camera-rate methods.

Prints figures only. Twin (tests/timing_twin.py): the simulated rig's default camera pair (60 fps each,
13.9 µs line time, lens distortion off), the crank column's marker at 4 mm along z, exact centres at exact
row times plus σ = 0.1 px, times on the world clock (the timing is not under test: the pair's offset is
known to ~5 µs, 1.6 mrad at 50 Hz). The second camera's start is set so that the instants the marker is
seen at (rolling-shutter rows included) are α of a frame apart: ½, ¼ and near 0 (0.002).

Per frequency and α, over ``SEEDS`` 1-s records (one 1 Hz bin of a sweep at 1 Hz/s), the amplitude error
(mean ± std over seeds, %) of:

- ``interleaved line``: :func:`rig.stereo.band.fit_bin` along the measured line of motion (the report's
  method; the line from the default 3-D track of the same marker at 10 Hz), with the alias test; a refused
  bin is printed as such (the reason below);
- ``interleaved free``: the same with a free 3-D ellipse (needs each camera to see both quadratures);
- baseline, measured in the same run — what a track at one camera's instants (60 Hz) gives: ``spline``
  (the default sync ``trajectory``: B-spline knots at 0.75 frame, evaluated at the left camera's instants)
  and ``linear`` (the paper's: right camera linearly interpolated to the left's instants), each then fitted
  with the frequency known (3-parameter fit along z), as the report's bins do; ``peak Hz`` is the
  spectral peak of those 60 Hz tracks (median): the frequency a one-camera-rate measurement would report.

Run: ``.venv/bin/python benchmarks/band.py`` (about a minute).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from timing_twin import TwinRecord, twin_record  # noqa: E402

from rig.stereo import fit_sine, fit_spline_trajectory, resample, spectrum, triangulate  # noqa: E402
from rig.stereo.band import fit_bin, instants_alpha, pair_band  # noqa: E402

CRANK_MM = 4.0
FS_HZ = 60.0
AXIS = np.array([0.0, 0.0, 1.0])
FREQUENCIES_HZ = (30.0, 40.0, 45.0, 50.0)
ALPHAS = (0.5, 0.25, 0.002)
SEEDS = (0, 1, 2, 3, 4)
DIRECTION_HZ = 10.0
TARGETS = {40.0: "target ≤ 1 % (α = ½)", 50.0: "target ≤ 5 % (α = ½)"}


def record(f_hz: float, alpha: float, seed: int) -> TwinRecord:
    def make(offset_s: float) -> TwinRecord:
        return twin_record("sweep_column", "col2", sigma_px=0.1, duration_s=1.0, seed=seed,
                           right_start_offset_s=offset_s, setup=lambda w: w.exciter.set_frequency(0.0, f_hz))

    base = make(0.0)
    return make((alpha - instants_alpha(base.true_left, base.true_right, FS_HZ)) / FS_HZ)


def interleaved(rec: TwinRecord, f_hz: float, direction: np.ndarray | None) -> tuple[float, str, float]:
    """(error %, refusal reason, α measured) of the interleaved fit."""
    phase = [rec.world.exciter.phase_rad(rec.true_left), rec.world.exciter.phase_rad(rec.true_right)]
    alpha = instants_alpha(rec.true_left, rec.true_right, FS_HZ)
    b = fit_bin([rec.P_left, rec.P_right], [rec.true_left, rec.true_right], [rec.uv_left, rec.uv_right],
                phase, AXIS, f_ref_hz=f_hz, direction=direction, identify=pair_band(FS_HZ, alpha / FS_HZ))
    return 100 * (b.amplitude / CRANK_MM - 1), b.refused, alpha


def measured_direction(alpha: float, seed: int) -> np.ndarray:
    """The line of motion as the report measures it: the principal axis of the default (spline) 3-D track
    where it is well sampled — here a 1-s record of the same marker at 10 Hz (in a sweep: its bins up to
    fs/3)."""
    xyz = one_rate_xyz(record(DIRECTION_HZ, alpha, seed), "spline")[1]
    return np.linalg.svd(xyz - xyz.mean(0), full_matrices=False)[2][0]


def one_rate_xyz(rec: TwinRecord, method: str) -> tuple[np.ndarray, np.ndarray]:
    """3-D positions at the left camera's instants (interior), by ``linear`` interpolation or ``spline``."""
    t_l, t_r = rec.true_left, rec.true_right
    keep = (t_l > t_r[2]) & (t_l < t_r[-3])
    if method == "linear":
        uv_r = resample(t_r, rec.uv_right, t_l[keep], "linear")
        return t_l[keep], triangulate([rec.P_left, rec.P_right], [rec.uv_left[keep], uv_r]).xyz_mm
    traj = fit_spline_trajectory([rec.P_left, rec.P_right], [t_l, t_r], [rec.uv_left, rec.uv_right],
                                 knot_spacing_s=0.75 / FS_HZ)
    return t_l[keep], traj.position(t_l[keep])


def one_rate(rec: TwinRecord, f_hz: float, method: str) -> tuple[float, float]:
    """(amplitude error % with the frequency known, the track's spectral peak Hz: what it would report)."""
    t, xyz = one_rate_xyz(rec, method)
    x = xyz @ AXIS
    return (100 * (fit_sine(t, x, frequency_hz=f_hz).amplitude / CRANK_MM - 1),
            spectrum(t[0] + np.arange(t.size) / FS_HZ, x).peak_frequency_hz)  # the track's frame grid


def cell(values: list[float]) -> str:
    return f"{np.mean(values):+7.3f} ± {np.std(values):5.3f}"


def main() -> None:
    print(__doc__.split("\n\n")[0])
    print(f"amplitude error % (mean ± std over {len(SEEDS)} seeds of 1 s, σ = 0.1 px, 4 mm ≈ 6.4 px)\n")
    head = (f"{'α':>6s} {'f Hz':>5s} {'interleaved line':>18s} {'interleaved free':>18s} "
            f"{'spline (60 Hz)':>18s} {'linear (60 Hz)':>18s} {'peak Hz':>8s}")
    print(head)
    reasons: set[str] = set()
    for alpha in ALPHAS:
        for f_hz in FREQUENCIES_HZ:
            rows: dict[str, list[float]] = {"line": [], "free": [], "spline": [], "linear": []}
            refused = 0
            measured_alpha = []
            peaks: list[float] = []
            for seed in SEEDS:
                rec = record(f_hz, alpha, seed)
                e, why, a = interleaved(rec, f_hz, measured_direction(alpha, seed))
                measured_alpha.append(a)
                rows["line"].append(e)
                refused += bool(why)
                if why:
                    reasons.add(why.split(" (")[0])
                rows["free"].append(interleaved(rec, f_hz, None)[0])
                for method in ("spline", "linear"):
                    e_one, peak = one_rate(rec, f_hz, method)
                    rows[method].append(e_one)
                    peaks.append(peak)
            line = cell(rows["line"]) + (f" REFUSED×{refused}" if refused else "")
            print(f"{np.mean(measured_alpha):6.3f} {f_hz:5.0f} {line:>18s} {cell(rows['free']):>18s} "
                  f"{cell(rows['spline']):>18s} {cell(rows['linear']):>18s} {np.median(peaks):8.2f}   "
                  f"{TARGETS.get(f_hz, '') if alpha == 0.5 else ''}")
    for alpha in ALPHAS:
        band = pair_band(FS_HZ, alpha / FS_HZ)
        print(f"α = {alpha:g}: one camera's Nyquist {band.single_nyquist_hz:g} Hz, the pair's combined rate "
              f"{band.combined_rate_hz:g} Hz (Nyquist {band.combined_nyquist_hz:g} Hz), |sin πα| = "
              f"{band.alias_separation:.3f}")
    for why in sorted(reasons):
        print(f"refused: {why}")


if __name__ == "__main__":
    main()
