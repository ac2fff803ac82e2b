"""The quadratic growth of amplitude error: e(f) = c0 + c2·f², weighted least squares.

Weights are w_i = 1/u_i² from the per-bin standard uncertainties. The uncertainties are treated as
*relative* (their common scale unknown): the parameter covariance is (XᵀWX)⁻¹ scaled by the reduced
chi-square s² = Σw·r²/(n − 2), and confidence intervals use Student's t with n − 2 degrees of freedom.
Under Gaussian errors whose variances are proportional to u_i², these intervals cover the true
parameters at exactly the stated level. R² is the weighted coefficient of determination.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special

from reports.errors import FitError


@dataclass(frozen=True)
class QuadraticFit:
    """Result of :func:`fit_quadratic`; coefficients in the units of e (e.g. %) and e/Hz²."""

    c0: float
    c2: float
    cov: np.ndarray  # 2×2 covariance of (c0, c2)
    dof: int
    r2: float
    chi2_reduced: float
    confidence: float
    n_points: int
    f_min_hz: float
    f_max_hz: float

    @property
    def t_factor(self) -> float:
        """Student-t quantile for the two-sided ``confidence`` interval with ``dof`` degrees of freedom."""
        # what scipy.stats.t.ppf computes (its _ppf), without importing scipy.stats (≈ 0.8 CPU-s)
        return float(special.stdtrit(self.dof, 0.5 + self.confidence / 2))

    @property
    def u_c0(self) -> float:
        return float(np.sqrt(self.cov[0, 0]))

    @property
    def u_c2(self) -> float:
        return float(np.sqrt(self.cov[1, 1]))

    def ci(self, name: str) -> tuple[float, float]:
        """Confidence interval of ``"c0"`` or ``"c2"`` at the fit's ``confidence`` level."""
        if name not in ("c0", "c2"):
            raise FitError(f"parameter must be 'c0' or 'c2', got {name!r}")
        value, u = (self.c0, self.u_c0) if name == "c0" else (self.c2, self.u_c2)
        return value - self.t_factor * u, value + self.t_factor * u

    def predict(self, f_hz: np.ndarray | float) -> np.ndarray:
        f = np.asarray(f_hz, float)
        return self.c0 + self.c2 * f**2

    def u_predict(self, f_hz: np.ndarray | float) -> np.ndarray:
        """Standard uncertainty of the fitted mean e(f) (not of a new observation)."""
        f2 = np.asarray(f_hz, float) ** 2
        return np.sqrt(self.cov[0, 0] + 2 * f2 * self.cov[0, 1] + f2**2 * self.cov[1, 1])

    def to_dict(self) -> dict[str, float | int | list[float]]:
        lo0, hi0 = self.ci("c0")
        lo2, hi2 = self.ci("c2")
        return {
            "c0": self.c0,
            "c2": self.c2,
            "u_c0": self.u_c0,
            "u_c2": self.u_c2,
            "c0_ci": [lo0, hi0],
            "c2_ci": [lo2, hi2],
            "confidence": self.confidence,
            "dof": self.dof,
            "t_factor": self.t_factor,
            "r2": self.r2,
            "chi2_reduced": self.chi2_reduced,
            "n_points": self.n_points,
            "f_min_hz": self.f_min_hz,
            "f_max_hz": self.f_max_hz,
        }


def fit_quadratic(
    f_hz: np.ndarray, e: np.ndarray, u_e: np.ndarray, *, confidence: float = 0.95
) -> QuadraticFit:
    """Weighted LS fit of e(f) = c0 + c2·f² (see module docstring). Needs ≥ 3 points and u_e > 0."""
    f = np.asarray(f_hz, float).ravel()
    y = np.asarray(e, float).ravel()
    u = np.asarray(u_e, float).ravel()
    if not (len(f) == len(y) == len(u)):
        raise FitError(f"f_hz, e and u_e must have equal lengths, got {len(f)}, {len(y)}, {len(u)}")
    if not 0 < confidence < 1:
        raise FitError(f"confidence must be in (0, 1), got {confidence!r}")
    ok = np.isfinite(f) & np.isfinite(y) & np.isfinite(u)
    f, y, u = f[ok], y[ok], u[ok]
    if len(f) < 3:
        raise FitError(f"the quadratic fit needs ≥ 3 finite points, got {len(f)}")
    if np.any(u <= 0):
        raise FitError(f"u_e must be > 0 (weights 1/u²), got min {u.min()!r}")
    if np.ptp(f**2) <= 0:
        raise FitError("the quadratic fit needs at least two distinct frequencies")
    w = 1 / u**2
    X = np.column_stack([np.ones_like(f), f**2])
    sw = np.sqrt(w)
    coef, *_ = np.linalg.lstsq(X * sw[:, None], y * sw, rcond=None)
    resid = y - X @ coef
    dof = len(f) - 2
    rss_w = float(np.sum(w * resid**2))
    s2 = rss_w / dof
    cov = s2 * np.linalg.inv(X.T @ (X * w[:, None]))
    y_bar = float(np.sum(w * y) / np.sum(w))
    tss_w = float(np.sum(w * (y - y_bar) ** 2))
    r2 = 1 - rss_w / tss_w if tss_w > 0 else float("nan")
    return QuadraticFit(
        c0=float(coef[0]),
        c2=float(coef[1]),
        cov=cov,
        dof=dof,
        r2=float(r2),
        chi2_reduced=s2,
        confidence=confidence,
        n_points=len(f),
        f_min_hz=float(f.min()),
        f_max_hz=float(f.max()),
    )


@dataclass(frozen=True)
class UsableLimit:
    """The highest frequency at which the fitted |e(f)| stays within the tolerance.

    ``limit_hz`` is min(solution, highest tested frequency) — the report never trusts beyond what was
    tested; ``reached`` tells whether the tolerance is crossed inside the tested range; ``u_limit_hz`` is the
    standard uncertainty of the crossing from the fit covariance (delta method; NaN when not reached).
    """

    tolerance: float
    limit_hz: float
    crossing_hz: float
    u_limit_hz: float
    reached: bool
    f_max_tested_hz: float
    source: str = "fit"  # "fit" | "bins beyond the fit" | "tested range"


def usable_limit(fit: QuadraticFit, tolerance: float, f_max_tested_hz: float | None = None) -> UsableLimit:
    """Solve |c0 + c2·f²| = tolerance for the smallest f ≥ 0 (same units as e, e.g. %)."""
    if not tolerance > 0:
        raise FitError(f"tolerance must be > 0, got {tolerance!r}")
    f_max = fit.f_max_hz if f_max_tested_hz is None else float(f_max_tested_hz)
    c0, c2 = fit.c0, fit.c2
    if abs(c0) >= tolerance:
        crossing, u_cross = 0.0, float("nan")
    elif c2 == 0:
        crossing, u_cross = float("inf"), float("nan")
    else:
        bound = tolerance if c2 > 0 else -tolerance  # the side of the band e(f) runs into
        crossing = float(np.sqrt((bound - c0) / c2))
        grad = np.array([-1 / (2 * crossing * c2), -crossing / (2 * c2)])
        u_cross = float(np.sqrt(grad @ fit.cov @ grad))
    reached = crossing <= f_max
    return UsableLimit(
        tolerance=tolerance,
        limit_hz=min(crossing, f_max),
        crossing_hz=crossing,
        u_limit_hz=u_cross if reached else float("nan"),
        reached=bool(reached),
        f_max_tested_hz=f_max,
    )


def usable_limit_with_bins(
    fit: QuadraticFit,
    f_bins_hz: np.ndarray,
    e_bins: np.ndarray,
    tolerance: float,
    *,
    u_bins: np.ndarray | None = None,
    guard_k: float = 0.0,
) -> UsableLimit:
    """The usable limit over the whole tested range: the fit inside its range, the bins beyond it.

    Inside the fitted range the crossing of the fit is used (:func:`usable_limit`). Beyond it (the fit
    stops short of Nyquist on purpose) the quadratic model is not trusted: the limit is the last bin
    frequency before the first bin whose |e| + ``guard_k``·u exceeds the tolerance (``source`` "bins
    beyond the fit", no uncertainty: bin resolution), else the highest tested frequency ("tested range").
    ``guard_k`` = 2 applies the guarded decision rule to the bins (standard uncertainties ``u_bins``);
    0 is simple acceptance.
    """
    f = np.asarray(f_bins_hz, float)
    e = np.asarray(e_bins, float)
    u = np.zeros_like(f) if u_bins is None else np.nan_to_num(np.asarray(u_bins, float))
    if not f.shape == e.shape == u.shape:
        raise FitError(f"f_bins_hz, e_bins and u_bins need equal shapes, got {f.shape}, {e.shape}, {u.shape}")
    ok = np.isfinite(f) & np.isfinite(e)
    f, e, u = f[ok], e[ok], u[ok]
    f_max_tested = float(f.max()) if len(f) else fit.f_max_hz
    inside = usable_limit(fit, tolerance, fit.f_max_hz)
    if inside.reached:
        return UsableLimit(
            tolerance, inside.limit_hz, inside.crossing_hz, inside.u_limit_hz, True, f_max_tested
        )
    order = np.argsort(f)
    last_ok = fit.f_max_hz
    for fi, ei, ui in zip(f[order], e[order], u[order], strict=True):
        if fi <= fit.f_max_hz:
            continue
        if abs(ei) + guard_k * ui > tolerance:
            return UsableLimit(
                tolerance,
                last_ok,
                float("nan"),
                float("nan"),
                True,
                f_max_tested,
                source="bins beyond the fit",
            )
        last_ok = float(fi)
    return UsableLimit(
        tolerance,
        max(f_max_tested, fit.f_max_hz),
        inside.crossing_hz,
        float("nan"),
        False,
        max(f_max_tested, fit.f_max_hz),
        source="tested range",
    )
