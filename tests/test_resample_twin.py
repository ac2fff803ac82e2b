"""The paper's alignment by linear interpolation on the twin at 25 Hz: its loss follows the exact formula,
while band-limited resampling keeps the amplitude (known truth, derived tolerances)."""

from __future__ import annotations

import numpy as np
import pytest
from timing_twin import twin_record

from rig.stereo.resample import resample
from rig.stereo.sinefit import fit_sine

SIGMA_PX = 0.1
F_HZ = 25.0


def _gain_linear(alpha, f_hz, fs_hz):
    return np.sqrt(1 - 4 * alpha * (1 - alpha) * np.sin(np.pi * f_hz / fs_hz) ** 2)


@pytest.fixture(scope="module")
def record():
    return twin_record(
        "sweep_column", "col2", sigma_px=SIGMA_PX, setup=lambda w: w.exciter.set_frequency(0.0, F_HZ)
    )


def _aligned(record, method):
    """Right camera's image row brought to the left camera's instants (true timing, left clock)."""
    t_src = record.left_clock_of_world(record.true_right)
    t_dst = record.left_clock_of_world(record.true_left)
    keep = (t_dst > t_src[40]) & (t_dst < t_src[-40])  # away from the kernel's truncated ends
    y = resample(t_src, record.uv_right[:, 1], t_dst[keep], method)
    return t_src, t_dst[keep], y


def test_linear_interpolation_loses_what_the_formula_says_at_25_hz(record):
    t_src, t_dst, y = _aligned(record, "linear")
    own = fit_sine(t_src, record.uv_right[:, 1], frequency_hz=F_HZ)
    k = np.searchsorted(t_src, t_dst) - 1
    alpha = (t_dst - t_src[k]) / (t_src[k + 1] - t_src[k])
    fs = 1.0 / float(np.median(np.diff(t_src)))
    predicted = float(np.mean(_gain_linear(alpha, F_HZ, fs)))
    measured = fit_sine(t_dst, y, frequency_hz=F_HZ).amplitude / own.amplitude
    assert measured == pytest.approx(predicted, rel=0.10)  # the criterion
    # Noise floor of the ratio: interpolated noise ≤ σ, √(2/N) per amplitude → far inside the 10 %.
    assert measured == pytest.approx(
        predicted, abs=5 * SIGMA_PX * np.sqrt(4 / t_dst.size) / own.amplitude + 0.01
    )
    assert predicted < 0.75  # a real loss at this α and frequency, not a trivial pass


def test_bandlimited_alignment_keeps_the_amplitude_within_one_percent(record):
    t_src, t_dst, y = _aligned(record, "bandlimited")
    own = fit_sine(t_src, record.uv_right[:, 1], frequency_hz=F_HZ)
    ratio = fit_sine(t_dst, y, frequency_hz=F_HZ).amplitude / own.amplitude
    assert ratio == pytest.approx(1.0, abs=0.01)
