"""The quadratic growth fit e(f) = c0 + c2·f²: recovery, interval coverage, usable frequency limit."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from reports.errors import FitError
from reports.quadfit import fit_quadratic, usable_limit

F_HZ = np.arange(1.0, 21.0)  # 20 bins, 1–20 Hz
C0, C2 = 0.3, -0.08
SIGMA = 0.2 * (1 + F_HZ / 5)  # heteroscedastic: the error scatter grows with frequency


def test_exact_data_recover_the_coefficients() -> None:
    fit = fit_quadratic(F_HZ, C0 + C2 * F_HZ**2, SIGMA)
    assert fit.c0 == pytest.approx(C0, abs=1e-10)
    assert fit.c2 == pytest.approx(C2, abs=1e-12)
    assert fit.r2 == pytest.approx(1.0)
    assert fit.dof == len(F_HZ) - 2


def test_weighted_estimate_matches_the_closed_form() -> None:
    rng = np.random.default_rng(5)
    e = C0 + C2 * F_HZ**2 + rng.normal(0, SIGMA)
    fit = fit_quadratic(F_HZ, e, SIGMA)
    X = np.column_stack([np.ones_like(F_HZ), F_HZ**2])
    W = np.diag(1 / SIGMA**2)
    beta = np.linalg.solve(X.T @ W @ X, X.T @ W @ e)
    r = e - X @ beta
    s2 = (r @ W @ r) / (len(e) - 2)
    np.testing.assert_allclose([fit.c0, fit.c2], beta, rtol=1e-10)
    np.testing.assert_allclose(fit.cov, s2 * np.linalg.inv(X.T @ W @ X), rtol=1e-8)
    assert fit.ci("c2")[1] - fit.c2 == pytest.approx(stats.t.ppf(0.975, 18) * np.sqrt(fit.cov[1, 1]))


@pytest.mark.parametrize("confidence", [0.95, 0.68])
def test_intervals_cover_the_truth_at_the_stated_rate(confidence: float) -> None:
    """Monte-Carlo coverage with a fixed seed; tolerance = 4 binomial standard deviations."""
    rng = np.random.default_rng(20261122)
    trials = 2000
    scale = 3.7  # the uncertainties are relative: an unknown common factor must not change coverage
    hits_c0 = hits_c2 = 0
    for _ in range(trials):
        e = C0 + C2 * F_HZ**2 + rng.normal(0, scale * SIGMA)
        fit = fit_quadratic(F_HZ, e, SIGMA, confidence=confidence)
        lo, hi = fit.ci("c2")
        hits_c2 += lo <= C2 <= hi
        lo, hi = fit.ci("c0")
        hits_c0 += lo <= C0 <= hi
    tol = 4 * np.sqrt(confidence * (1 - confidence) / trials)
    assert hits_c2 / trials == pytest.approx(confidence, abs=tol)
    assert hits_c0 / trials == pytest.approx(confidence, abs=tol)


def test_usable_limit_solves_the_tolerance_crossing() -> None:
    fit = fit_quadratic(F_HZ, C0 + C2 * F_HZ**2, SIGMA)
    lim = usable_limit(fit, 5.0)
    expected = np.sqrt((-5.0 - C0) / C2)  # e falls to −5 % at √(5.3/0.08) ≈ 8.14 Hz
    assert lim.reached
    assert lim.limit_hz == pytest.approx(expected, rel=1e-9)
    # positive growth runs into +tolerance instead
    up = fit_quadratic(F_HZ, 0.3 + 0.02 * F_HZ**2, SIGMA)
    assert usable_limit(up, 5.0).limit_hz == pytest.approx(np.sqrt(4.7 / 0.02), rel=1e-9)


def test_usable_limit_is_capped_at_the_highest_tested_frequency() -> None:
    fit = fit_quadratic(F_HZ, 0.1 - 0.001 * F_HZ**2, SIGMA)
    lim = usable_limit(fit, 5.0)
    assert not lim.reached
    assert lim.crossing_hz == pytest.approx(np.sqrt(5.1 / 0.001))
    assert lim.limit_hz == F_HZ.max()
    assert np.isnan(lim.u_limit_hz)
    assert usable_limit(fit, 5.0, f_max_tested_hz=23.5).limit_hz == 23.5


def test_usable_limit_zero_when_the_offset_already_exceeds_tolerance() -> None:
    fit = fit_quadratic(F_HZ, -6.0 + C2 * F_HZ**2, SIGMA)
    assert usable_limit(fit, 5.0).limit_hz == 0.0


def test_usable_limit_uncertainty_by_the_delta_method_matches_monte_carlo() -> None:
    rng = np.random.default_rng(7)
    limits, u_pred = [], []
    for _ in range(800):
        fit = fit_quadratic(F_HZ, C0 + C2 * F_HZ**2 + rng.normal(0, SIGMA), SIGMA)
        lim = usable_limit(fit, 5.0)
        limits.append(lim.limit_hz)
        u_pred.append(lim.u_limit_hz)
    # the scatter of the estimated limit matches its predicted standard uncertainty (within ≈ 10 %)
    assert np.std(limits) == pytest.approx(np.median(u_pred), rel=0.12)


@pytest.mark.parametrize(
    ("f", "e", "u", "match"),
    [
        ([1, 2], [0, 0], [1, 1], "≥ 3"),
        ([1, 2, 3], [0, 0, 0], [1, 0, 1], "u_e must be > 0"),
        ([2, 2, 2], [0, 1, 2], [1, 1, 1], "distinct"),
        ([1, 2, 3], [0, 1], [1, 1, 1], "equal lengths"),
    ],
)
def test_bad_fit_inputs_raise(f, e, u, match) -> None:
    with pytest.raises(FitError, match=match):
        fit_quadratic(np.array(f, float), np.array(e, float), np.array(u, float))


def test_bad_tolerance_raises() -> None:
    fit = fit_quadratic(F_HZ, C0 + C2 * F_HZ**2, SIGMA)
    with pytest.raises(FitError, match="tolerance"):
        usable_limit(fit, 0.0)


@settings(max_examples=40, deadline=None)
@given(
    scale=st.floats(1e-3, 1e3),
    shift_c0=st.floats(-10, 10),
    seed=st.integers(0, 2**16),
)
def test_fit_is_invariant_to_a_common_uncertainty_scale(scale: float, shift_c0: float, seed: int) -> None:
    """Relative weights: multiplying every u by one factor changes nothing; the fit is linear in e."""
    rng = np.random.default_rng(seed)
    e = C0 + C2 * F_HZ**2 + rng.normal(0, SIGMA)
    a = fit_quadratic(F_HZ, e, SIGMA)
    b = fit_quadratic(F_HZ, e, SIGMA * scale)
    np.testing.assert_allclose([b.c0, b.c2], [a.c0, a.c2], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(b.cov, a.cov, rtol=1e-7, atol=1e-18)
    c = fit_quadratic(F_HZ, e + shift_c0, SIGMA)
    assert c.c0 == pytest.approx(a.c0 + shift_c0, abs=1e-9)
    assert c.c2 == pytest.approx(a.c2, abs=1e-12)


def test_usable_limit_beyond_the_fit_comes_from_the_bins() -> None:
    from reports.quadfit import usable_limit_with_bins

    fit = fit_quadratic(F_HZ, 0.1 - 0.001 * F_HZ**2, SIGMA)  # |e| ≤ 0.5 % up to 20 Hz
    f_bins = np.arange(1.0, 30.0)
    e_bins = np.where(f_bins <= 24.0, -1.0, -7.0)  # beyond the fit, bins exceed 5 % from 25 Hz
    lim = usable_limit_with_bins(fit, f_bins, e_bins, 5.0)
    assert lim.reached and lim.source == "bins beyond the fit"
    assert lim.limit_hz == 24.0 and lim.f_max_tested_hz == 29.0
    # every bin within tolerance: the whole tested range, not reached
    lim = usable_limit_with_bins(fit, f_bins, np.full_like(f_bins, -1.0), 5.0)
    assert not lim.reached and lim.limit_hz == 29.0 and lim.source == "tested range"
    # a crossing inside the fitted range wins, with the fit's uncertainty
    steep = fit_quadratic(F_HZ, C0 + C2 * F_HZ**2, SIGMA)
    lim = usable_limit_with_bins(steep, f_bins, e_bins, 5.0)
    assert lim.source == "fit" and lim.limit_hz == pytest.approx(np.sqrt(5.3 / 0.08))
    assert np.isfinite(lim.u_limit_hz)


def test_guarded_bins_beyond_the_fit_count_their_uncertainty() -> None:
    from reports.quadfit import usable_limit_with_bins

    fit = fit_quadratic(F_HZ, 0.1 - 0.001 * F_HZ**2, SIGMA)
    f_bins = np.array([21.0, 22.0, 23.0])
    e_bins = np.array([-2.0, -3.0, -4.0])
    u_bins = np.array([1.0, 1.0, 1.0])  # |e| + 2u: 4, 5, 6 → the 23 Hz bin fails when guarded
    assert usable_limit_with_bins(fit, f_bins, e_bins, 5.0, u_bins=u_bins, guard_k=2.0).limit_hz == 22.0
    assert not usable_limit_with_bins(fit, f_bins, e_bins, 5.0, u_bins=u_bins, guard_k=0.0).reached
    with pytest.raises(FitError, match="equal shapes"):
        usable_limit_with_bins(fit, f_bins, e_bins, 5.0, u_bins=u_bins[:2])
