"""The report's Lomb–Scargle peak, flat-top spectrum and Student-t factor are SciPy's own numbers computed
without importing scipy.signal or scipy.stats (≈ 1 CPU-s in every process that writes a report)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import scipy
import scipy.signal
import scipy.stats
from hypothesis import given, settings
from hypothesis import strategies as st

from reports.frequency import lomb_scargle_power
from reports.quadfit import fit_quadratic

ROOT = Path(__file__).resolve().parents[1]
# SciPy ≥ 1.15 computes the periodogram in numpy with the operations lomb_scargle_power repeats; older SciPy
# in compiled code, equal only to rounding
_SAME_OPERATIONS = tuple(int(p) for p in scipy.__version__.split(".")[:2]) >= (1, 15)


@settings(max_examples=40, deadline=None)
@given(n=st.integers(8, 400), seed=st.integers(0, 2**32 - 1), f_hz=st.floats(0.2, 30.0))
def test_the_periodogram_is_scipys(n: int, seed: int, f_hz: float) -> None:
    rng = np.random.default_rng(seed)
    t = np.sort(rng.uniform(0.0, n / 60.0, n))  # irregular instants, as a track's row-corrected ones
    x = np.sin(2 * np.pi * f_hz * t + rng.uniform(0, 6)) + rng.normal(0, 0.3, n)
    y = x - x.mean()
    omega = 2 * np.pi * np.arange(0.05, 31.0, 0.05)
    ours, theirs = lomb_scargle_power(t, y, omega), scipy.signal.lombscargle(t, y, omega)
    if _SAME_OPERATIONS:
        np.testing.assert_array_equal(ours, theirs)
    else:
        np.testing.assert_allclose(ours, theirs, rtol=1e-9, atol=1e-12 * float(np.max(theirs)))


def test_the_t_factor_is_scipy_stats_t_ppf() -> None:
    rng = np.random.default_rng(3)
    for n in (3, 4, 5, 9, 40, 400):
        f = np.linspace(1.0, 30.0, n)
        err = -0.01 * f**2 + rng.normal(0, 0.05, n)
        for confidence in (0.68, 0.9, 0.95, 0.99):
            fit = fit_quadratic(f, err, np.full(n, 0.05), confidence=confidence)
            assert fit.t_factor == float(scipy.stats.t.ppf(0.5 + confidence / 2, fit.dof)), (n, confidence)


_CALLS = """
import json, sys
import numpy as np
from reports.frequency import _peak_frequency_hz
from reports.motion import amplitude_spectrum
from reports.quadfit import fit_quadratic
t = np.arange(600) / 60.0
x = 2.0 * np.sin(2 * np.pi * 5.0 * t)
assert abs(_peak_frequency_hz(t, x, 2.5, 7.5) - 5.0) < 0.01
spectrum = amplitude_spectrum(t, x)
assert abs(float(spectrum["amplitude_mm"].max()) - 2.0) < 0.01
f = np.linspace(1.0, 30.0, 12)
assert fit_quadratic(f, -0.01 * f**2 + 0.01 * np.sin(f), np.full(12, 0.01)).ci("c2")[0] < -0.009
heavy = (["scipy", "signal"], ["scipy", "stats"])
print(json.dumps(sorted(m for m in sys.modules if m.split(".")[:2] in heavy)))
"""


def test_the_report_computations_import_neither_scipy_signal_nor_scipy_stats() -> None:
    done = subprocess.run([sys.executable, "-c", _CALLS], cwd=ROOT, capture_output=True, text=True,
                          check=True, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert json.loads(done.stdout.strip().splitlines()[-1]) == []
