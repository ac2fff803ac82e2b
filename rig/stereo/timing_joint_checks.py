"""Checks and diagnostics of the joint timing fit (:mod:`rig.stereo.timing_joint`).

``check_line_time`` refuses a rolling-shutter line time the motion cannot determine, ``check_ambiguity``
refuses an offset that another local minimum fits as well (periodic motion), and ``fit_details`` is the
``details`` record of the fit (residual RMS, σ, parameter correlation, the coarse cost curve).
Units: seconds, pixels.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import optimize

from rig.stereo.errors import AmbiguousOffsetError, LineTimeNotObservableError


def check_line_time(tracks, line_s, std_s, *, bound_s, at_bound, period_s, offset_s) -> None:
    """Raise LineTimeNotObservableError when the estimated line time is on its bound or less certain than
    the largest physical line time (frame period / largest observed row); see the module doc."""
    max_row = max(float(np.max(np.concatenate([tr[2], tr[5]]))) for tr in tracks)
    limit_s = period_s / max(max_row, 1.0)
    if not at_bound and std_s <= limit_s:
        return
    diff = np.concatenate([np.interp(ta, tb + offset_s, rb) - ra for ta, _, ra, tb, _, rb in tracks])
    spread = float(np.std(diff))
    why = (f"it ran to the bound ±{bound_s * 1e6:.1f} µs of the fit" if at_bound else
           f"its uncertainty exceeds the largest physical line time {limit_s * 1e6:.2f} µs "
           "(frame period / largest row)")
    raise LineTimeNotObservableError(
        f"the rolling-shutter line time is not observable from this motion: estimate {line_s * 1e6:+.2f} ± "
        f"{std_s * 1e6:.2f} µs, and {why}; the two cameras' rows change by only {spread:.2f} px (std) "
        "relative to each other (markers moving along their rows), so the line time trades against the "
        "offset. Pass line_time_s (the cameras' known line time, or 0 for a global shutter)",
        estimate_s=float(line_s), uncertainty_s=float(std_s), limit_s=limit_s, at_bound=at_bound,
        row_difference_spread_px=spread)


def check_ambiguity(prob, grid, cost, k, *, line, drift, best_cost, s2, threshold) -> None:
    """Raise AmbiguousOffsetError if a separate local minimum of the cost fits as well as the best."""
    step = grid[1] - grid[0]
    is_min = np.r_[False, (cost[1:-1] <= cost[:-2]) & (cost[1:-1] <= cost[2:]), False]
    for j in np.flatnonzero(is_min):
        if abs(j - k) <= 3:
            continue
        refined = optimize.minimize_scalar(
            lambda d: float(np.sum(prob.residuals(d, line, drift, weighted=False) ** 2)),
            bounds=(grid[j] - step, grid[j] + step),
            method="bounded",
        )
        if (refined.fun - best_cost) / s2 < threshold:
            raise AmbiguousOffsetError(
                f"offsets {grid[k]:+.6f} s and {refined.x:+.6f} s fit equally well "
                f"(Δχ² = {(refined.fun - best_cost) / s2:.1f}); the motion repeats within the search range: "
                "narrow search_half_width_s around a better offset_guess_s, or use a non-periodic motion"
            )


def fit_details(r, s2, cov, free, *, grid, cost) -> dict[str, Any]:
    names = [n for n, f in zip(("offset", "line_time", "drift"), free, strict=True) if f]
    sd = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
    corr = cov / np.outer(sd, sd)
    return {
        "residual_rms_px": float(np.sqrt(np.mean(r**2))),
        "n_residuals": int(r.size),
        "sigma_px": float(np.sqrt(s2)),
        "parameters": names,
        "correlation": corr.tolist(),
        "coarse_offset_s": grid.tolist(),
        "coarse_cost_px2": cost.tolist(),
    }
