"""Phase of the measured sweep motion against the excitation: a time delay with its uncertainty budget.

The drive does not report the crank's angle, only its frequency, so the excitation's phase is known up to a
constant (the angle at the sweep's start): what the sweep fixes is how the phase of the measured motion
against the reference φ(t) = 2π∫f dt changes with frequency. A track delayed by τ against the controller's
clock shows p(f) = c − 360°·f·τ; the weighted line through the bins' phases (:func:`phase_of_sweep`)
gives τ, the constant c and, per bin, the phase error p − c (°) and the delay −(p − c)/(360 f) (ms).

Uncertainty budget of τ (standard, ms):

* the line fit (Type A, the bins' scatter about the line);
* the controller↔camera clock (Type B, the analysis' ``u_offset_s`` of the sweep's segment: µs with the
  timing fiducial, ±½ frame with the start events) — every instant of the tracks carries it;
* the excitation's reference phase (Type B): the polled frequency is read back with the drive's resolution
  q (0.01 Hz on a Delta VFD); its rounding errors, uniform ±q/2 at each poll Δ apart, integrate into a
  random walk of the reference phase with variance (360°)²·(q²/12)·Δ per second of the sweep. Its effect on
  τ is propagated exactly through the line fit's weights (covariance min(t_i, t_j) between bins). A
  generator's frequency law (the shaker) is exact: no component.

A delay whose expanded uncertainty reaches the limit cannot be decided (the certificate's rule for every upper
limit, :func:`reports.certificate.beyond_resolution`): without the
fiducial the start events leave the clock to ±½ frame (u ≈ 4.8 ms at 60 fps), and the criterion says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

PHASE_COLUMNS = ["frequency_hz", "t_mid_s", "n_tracks", "phase_deg", "u_phase_deg", "delay_ms", "u_delay_ms"]


@dataclass(frozen=True)
class ReferenceResolution:
    """How finely the excitation's frequency is known: read-back step ``q_hz`` every ``poll_s`` seconds
    (q = 0: an exact frequency law), and where that came from."""

    q_hz: float
    poll_s: float
    source: str

    def walk_deg2_per_s(self) -> float:
        """Variance rate (deg²/s) of the reference phase's random walk."""
        return (360.0**2) * (self.q_hz**2 / 12.0) * self.poll_s


@dataclass
class PhaseResult:
    """The sweep's delay τ (ms) with its budget, and the phase of every bin (``PHASE_COLUMNS``)."""

    sync_method: str
    delay_ms: float
    budget: list[tuple[str, str, float]]
    bins: pd.DataFrame
    clock_source: str
    reference: ReferenceResolution
    notes: list[str] = field(default_factory=list)
    intercept_deg: float = float("nan")  # the line's constant c (°) against each track's first bin
    u_intercept_deg: float = float("nan")

    @property
    def u_delay_ms(self) -> float:
        return math.sqrt(sum(c[2] ** 2 for c in self.budget))

    def phase_at_deg(self, f_hz: float) -> tuple[float, float]:
        """(phase error, standard uncertainty) in degrees that the delay means at ``f_hz``."""
        return -360.0 * f_hz * self.delay_ms / 1000.0, 360.0 * f_hz * self.u_delay_ms / 1000.0


def reference_resolution(polled: list[dict], reference_source: str) -> ReferenceResolution:
    """The read-back step of the polled frequency (the coarsest decimal step 1, 0.1, …, 1e-6 Hz of which
    every reading is a multiple) and the poll interval (median); q = 0 when the reference is not the polled
    frequency (a generator's exact law)."""
    if not reference_source.startswith("polled"):
        return ReferenceResolution(0.0, 0.0, reference_source)
    rows = [(float(p["t_s"]), float(p["frequency_hz"])) for p in polled
            if isinstance(p.get("t_s"), int | float) and isinstance(p.get("frequency_hz"), int | float)]
    t = np.array(sorted(r[0] for r in rows))
    f = np.array([r[1] for r in rows])
    steps = (10.0**-k for k in range(7))
    q = next((d for d in steps if np.all(np.abs(f / d - np.round(f / d)) <= 1e-3)), 0.0)
    poll = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    found = f"read back in steps of {q:g} Hz" if q else "read back without a step found (≤ 1e-6 Hz)"
    return ReferenceResolution(q, poll, f"polled frequency {found} every {poll:.3g} s")


def _bin_phases(bins: pd.DataFrame, method: str) -> pd.DataFrame:
    """Per bin of one method: mean frequency, time, phase (° relative to each track's first bin) and its
    fit uncertainty (from the amplitude's: u_φ = u_A/A rad), over the tracks."""
    b = bins[bins["sync_method"] == method].copy()
    b["u_phase_fit_deg"] = np.rad2deg(b["u_amplitude_mm"] / b["amplitude_meas_mm"])
    g = b.groupby("bin", sort=True)
    out = g[["frequency_hz", "t_mid_s", "phase_deg", "u_phase_fit_deg"]].mean()
    out["n_tracks"] = g.size()
    return out.reset_index(drop=True)


def _walk_u_delay_ms(t_s: np.ndarray, weights: np.ndarray, reference: ReferenceResolution) -> float:
    """u(τ) (ms) from the reference phase's random walk (deg) through the line fit's weights (s/deg)."""
    rate = reference.walk_deg2_per_s()
    if rate <= 0:
        return 0.0
    elapsed = t_s - t_s.min()
    cov = rate * np.minimum.outer(elapsed, elapsed)
    return float(1000.0 * math.sqrt(max(weights @ cov @ weights, 0.0)))


def phase_of_sweep(bins: pd.DataFrame, method: str, *, u_clock_s: float, clock_source: str,
                   reference: ReferenceResolution) -> PhaseResult | None:
    """The delay and the phase per bin of ``method`` (module docstring); None with fewer than 3 bins."""
    p = _bin_phases(bins, method)
    if len(p) < 3 or p["frequency_hz"].nunique() < 3:
        return None
    f, t = p["frequency_hz"].to_numpy(float), p["t_mid_s"].to_numpy(float)
    phase = np.rad2deg(np.unwrap(np.deg2rad(p["phase_deg"].to_numpy(float))))
    X = np.column_stack([np.ones_like(f), -360.0 * f])
    coef, *_ = np.linalg.lstsq(X, phase, rcond=None)
    resid = phase - X @ coef
    xtx_inv = np.linalg.inv(X.T @ X)
    s2 = float(resid @ resid) / (len(f) - 2)
    tau_s = float(coef[1])
    slope_weights = (xtx_inv @ X.T)[1]  # τ = Σ w_i p_i
    budget = [
        ("line fit of the bins' phases", "A", 1000.0 * math.sqrt(s2 * xtx_inv[1, 1])),
        ("controller↔camera clock", "B", 1000.0 * u_clock_s),
        ("excitation's reference phase (drive read-back resolution)", "B",
         _walk_u_delay_ms(t, slope_weights, reference)),
    ]
    c = float(coef[0])
    err = phase - c
    u_c = math.sqrt(s2 * xtx_inv[0, 0])
    u_walk = np.sqrt(reference.walk_deg2_per_s() * (t - t.min()))
    u_phase = np.sqrt(p["u_phase_fit_deg"].to_numpy(float) ** 2 + u_c**2 + u_walk**2
                      + (360.0 * f * u_clock_s) ** 2)
    table = pd.DataFrame({
        "frequency_hz": f, "t_mid_s": t, "n_tracks": p["n_tracks"].to_numpy(int), "phase_deg": err,
        "u_phase_deg": u_phase, "delay_ms": -err / (360.0 * f) * 1000.0,
        "u_delay_ms": u_phase / (360.0 * f) * 1000.0})
    return PhaseResult(method, 1000.0 * tau_s, budget, table[PHASE_COLUMNS], clock_source, reference,
                       intercept_deg=c, u_intercept_deg=u_c)


def phase_section(result: PhaseResult | None) -> dict[str, Any] | None:
    """The certificate's ``phase`` section: the delay, its budget, the phase per bin (plain JSON types)."""
    if result is None:
        return None
    p10, u10 = result.phase_at_deg(10.0)
    p25, u25 = result.phase_at_deg(25.0)
    return {
        "sync_method": result.sync_method,
        "delay_ms": result.delay_ms,
        "u_delay_ms": result.u_delay_ms,
        "budget": [{"component": c[0], "type": c[1], "u_ms": c[2]} for c in result.budget],
        "phase_at_10_hz_deg": {"value": p10, "u": u10},
        "phase_at_25_hz_deg": {"value": p25, "u": u25},
        "clock_source": result.clock_source,
        "reference": result.reference.source,
        "model": "phase(f) = c − 360°·f·τ against φ(t) = 2π∫f dt of the excitation; c (the crank's angle at "
                 "the sweep's start) is not reported by the drive and is fitted",
        "bins": result.bins.to_dict("records"),
    }
