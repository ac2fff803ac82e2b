"""Joint estimate of time offset, rolling-shutter line time and clock drift from any moving marker (ours).

For parameters θ = (offset δ, line time ℓ, drift d) the observations of both cameras get row-corrected
instants (:func:`rig.stereo.timing.corrected_times`; the line time is common to both cameras unless fixed
per camera), camera B's track is reconstructed band-limited at camera A's instants
(:func:`rig.stereo.resample.bandlimited`, exact for irregular row times), and the signed Sampson epipolar
distance of each pair is the residual, normalised by its own noise: the interpolation's noise gain and the
row noise that also moves each observation's row-corrected instant (velocity × line time) both depend on
the parameters, and left out they would bias them in proportion to σ² (on the twin's rotor at σ = 0.3 px
the offset by +0.9 σ and the line time by −1.1 σ over 12 seeds; weighted: +0.2 σ and −0.4 σ, both within
their ±0.23 σ standard errors to 2 σ). A coarse search over the offset range (step ≤ a tenth of a frame)
finds the basin; local least squares (scipy ``least_squares``, finite-difference Jacobian) refines all
parameters; the covariance s²·(JᵀJ)⁻¹ gives standard uncertainties.

What the residual can see: only motion **out of the epipolar plane** constrains the offset (metrology notes
§3), the line time only through the spread of the row difference v_B − v_A (with a common line time the
effective delay is δ + ℓ·(v_B − v_A)), and the drift only over records long enough for δ to change
measurably. A periodic motion repeats its cost every period: when another offset inside the search range
fits as well (Δχ² < 25 + 10·√n, n residuals: the fluctuation of the cost between offsets that interpolate
different noise samples), AmbiguousOffsetError is raised instead of picking one; a cost curve flatter than
that over the whole range raises NoCommonMotionError.

**Line time not observable** (estimated, but the two cameras' rows barely change relative to each other, e.g.
markers moving along their rows: ℓ·(v_B − v_A) is then a near-constant delay the offset absorbs): when the
solution lies on the line-time bound, or its standard uncertainty exceeds the largest physical line time
(frame period / largest observed row), LineTimeNotObservableError is raised. The estimator does not fix ℓ
itself: the offset then shifts by (true − assumed ℓ) × row difference, so the caller, who knows the cameras
(datasheet, an earlier rotor sync, 0 for a global shutter), must pass ``line_time_s``.

Units: seconds, pixels; drift in ppm (1e-6 s/s) of camera B's clock relative to camera A's.
"""

from __future__ import annotations

import numpy as np
from scipy import optimize

from rig.stereo._series import as_times
from rig.stereo.errors import (
    DelayOutOfRangeError,
    InputArrayError,
    NoCommonMotionError,
    TooFewSamplesError,
)
from rig.stereo.resample import bandlimited
from rig.stereo.timing import TimingResult, projection_matrix
from rig.stereo.timing_joint_checks import check_ambiguity, check_line_time, fit_details

MIN_OBSERVATIONS = 30
CHI2_DISTINCT = 25.0  # Δχ² (5 σ) that separates a real minimum from an equally good one
GAP_GUARD = 32  # frames of B either side of a dropped frame whose reconstruction is not trusted


def fundamental_matrix(P_a: np.ndarray, P_b: np.ndarray) -> np.ndarray:
    """F with x_bᵀ F x_a = 0 for image points of the same 3D point (pixels, homogeneous)."""
    _, _, vt = np.linalg.svd(P_a)
    centre_a = vt[-1]
    e_b = P_b @ centre_a
    ex = np.array([[0, -e_b[2], e_b[1]], [e_b[2], 0, -e_b[0]], [-e_b[1], e_b[0], 0]])
    F = ex @ P_b @ np.linalg.pinv(P_a)
    return F / np.linalg.norm(F)


def sampson_px(
    F: np.ndarray,
    uv_a: np.ndarray,
    uv_b: np.ndarray,
    *,
    gain_b: np.ndarray | None = None,
    shift_a: np.ndarray | None = None,
    shift_b: np.ndarray | None = None,
) -> np.ndarray:
    """Signed first-order (Sampson) epipolar distance of each pair, normalised to unit-σ pixel noise.

    Optional noise model (default: independent equal noise on both points): ``gain_b`` (N,) variance factor
    of ``uv_b``'s noise (an interpolation's noise gain); ``shift_a``/``shift_b`` (N, 2): how far a pixel of
    noise in the row moves the point through its own row-corrected time (velocity × line time; for A it moves
    where B is evaluated, for B it moves B's sample instants).
    """
    xa = np.column_stack([uv_a, np.ones(len(uv_a))])
    xb = np.column_stack([uv_b, np.ones(len(uv_b))])
    Fxa = xa @ F.T
    Ftxb = xb @ F
    num = np.sum(xb * Fxa, axis=1)
    w_b = Fxa[:, :2].copy()  # ∂e/∂uv_b
    w_a = Ftxb[:, :2].copy()  # ∂e/∂uv_a
    if shift_a is not None:  # row noise of A also moves the instant at which B is read
        w_a[:, 1] += np.sum(w_b * shift_a, axis=1)
    if shift_b is not None:  # row noise of B's samples also moves their instants
        w_b[:, 1] -= np.sum(w_b * shift_b, axis=1)
    var = np.sum(w_a**2, axis=1) + (1.0 if gain_b is None else gain_b) * np.sum(w_b**2, axis=1)
    return num / np.sqrt(var)


def _pairs(observations: object, name: str) -> list[tuple[object, ...]]:
    """One (t, uv[, rows]) track or a list of them → list of tracks."""
    if isinstance(observations, list):
        pairs = observations
    elif isinstance(observations, tuple) and len(observations) in (2, 3):
        pairs = [observations]
    else:
        raise InputArrayError(
            f"{name} must be a pair (timestamp_s, uv_px), a triple (timestamp_s, uv_px, rows_px) "
            "or a list of them"
        )
    for i, pair in enumerate(pairs):
        if not (isinstance(pair, tuple | list) and len(pair) in (2, 3)):
            raise InputArrayError(
                f"{name}[{i}] must be a pair (timestamp_s, uv_px) or a triple (timestamp_s, uv_px, rows_px)"
            )
    return [tuple(p) for p in pairs]


def as_tracks(observations_a: object, observations_b: object) -> list[tuple[np.ndarray, ...]]:
    """Validate both cameras' tracks → [(tau_a, uv_a, rows_a, tau_b, uv_b, rows_b), ...].

    ``rows`` are the image rows (px) at which the sensor exposed each observation — the *observed*, lens-
    distorted v — which set the rolling-shutter instant; ``uv`` are the undistorted centres for the epipolar
    geometry. A track given as ``(t, uv)`` uses ``uv[:, 1]`` as its rows (exact without lens distortion)."""
    pa, pb = _pairs(observations_a, "observations_a"), _pairs(observations_b, "observations_b")
    if len(pa) != len(pb) or not pa:
        raise InputArrayError(
            f"observations_a has {len(pa)} tracks, observations_b {len(pb)}; they must match"
        )
    tracks = []
    for i, (track_a, track_b) in enumerate(zip(pa, pb, strict=True)):
        out: list[np.ndarray] = []
        for name, track in ((f"observations_a[{i}]", track_a), (f"observations_b[{i}]", track_b)):
            tt = as_times(track[0], f"{name} timestamp_s", min_count=MIN_OBSERVATIONS)
            uu = np.asarray(track[1], dtype=float)
            if uu.shape != (tt.size, 2) or not np.all(np.isfinite(uu)):
                raise InputArrayError(
                    f"{name} uv_px must be finite with shape ({tt.size}, 2), got {uu.shape}"
                )
            rows = uu[:, 1] if len(track) == 2 else np.asarray(track[2], dtype=float)
            if rows.shape != (tt.size,) or not np.all(np.isfinite(rows)):
                raise InputArrayError(
                    f"{name} rows_px must be finite with shape ({tt.size},), got {rows.shape}"
                )
            out += [tt, uu, rows]
        tracks.append(tuple(out))
    return tracks


class _Problem:
    """Residuals of the joint timing model for fixed data (one or more tracks)."""

    def __init__(self, F, tracks, *, epoch_b, margin_s, guess_s, half_width_s, line_a, line_b):
        self.F, self.epoch_b = F, epoch_b
        self.line_a, self.line_b = line_a, line_b  # None → the common estimated line time
        self.data = []
        self.n_near_gaps = 0
        for ta, ua, ra, tb, ub, rb in tracks:
            lo = tb[0] + guess_s + half_width_s + margin_s
            hi = tb[-1] + guess_s - half_width_s - margin_s
            sel = (ta >= lo) & (ta <= hi)
            # A dropped frame of B cannot be reconstructed; its error reaches the band-limited values through
            # the sinc's 1/d tail, so A's instants within the kernel half-width of a gap are left out.
            steps = np.diff(tb)
            period = float(np.median(steps))
            for k in np.flatnonzero(steps > 1.5 * period):
                near = (ta >= tb[k] + guess_s - half_width_s - GAP_GUARD * period) & (
                    ta <= tb[k + 1] + guess_s + half_width_s + GAP_GUARD * period
                )
                self.n_near_gaps += int(np.count_nonzero(sel & near))
                sel &= ~near
            if np.count_nonzero(sel) >= 4:
                self.data.append((ta[sel], ua[sel], ra[sel], tb, ub, rb))
        self.n = sum(len(d[0]) for d in self.data)

    def residuals(
        self, delta_s: float, line_s: float, drift_ppm: float, *, weighted: bool = True
    ) -> np.ndarray:
        """Sampson residuals; ``weighted=False`` skips the noise model (faster; for the coarse search)."""
        la = line_s if self.line_a is None else self.line_a
        lb = line_s if self.line_b is None else self.line_b
        out = []
        for ta, ua, ra, tb, ub, rb in self.data:
            t_dst = ta + la * ra
            t_src = tb + delta_s + drift_ppm * 1e-6 * (tb - self.epoch_b) + lb * rb
            if not weighted:
                out.append(sampson_px(self.F, ua, bandlimited(t_src, ub, t_dst)))
                continue
            # Weight by the interpolated noise's own variance: it depends on the parameters (the line time
            # changes how irregular B's instants are), and unweighted it would bias them by O(σ²).
            h = 1e-4  # s, for B's image velocity at A's instants
            both = bandlimited(t_src, ub, np.concatenate([t_dst, t_dst + h]))
            uv_b_at, gain = bandlimited(t_src, ub, t_dst, noise_gain=True)
            vel_b = (both[t_dst.size :] - both[: t_dst.size]) / h
            r = sampson_px(self.F, ua, uv_b_at, gain_b=gain, shift_a=la * vel_b, shift_b=lb * vel_b)
            out.append(r)
        return np.concatenate(out)


def estimate_joint(
    camera_a: object,
    camera_b: object,
    observations_a: object,
    observations_b: object,
    *,
    names: tuple[str, str] = ("a", "b"),
    offset_guess_s: float = 0.0,
    search_half_width_s: float | None = None,
    line_time_s: float | tuple[float, float] | None = None,
    line_time_guess_s: float = 0.0,
    estimate_drift: bool = True,
    max_drift_ppm: float = 200.0,
) -> TimingResult:
    """Joint offset / line time / drift of camera B relative to camera A (see module doc).

    The offset range searched is ``offset_guess_s`` ± ``search_half_width_s`` (default 1.5 frames of B).
    ``line_time_s``: None → one line time common to both cameras is estimated (starting at
    ``line_time_guess_s``); a number → fixed for both; a pair → fixed per camera (A, B).
    ``estimate_drift``: fit B's clock rate error (ppm, |d| ≤ ``max_drift_ppm`` enters only the record margin).
    Errors: TooFewSamplesError, NonMonotonicTimestampsError, NoCommonMotionError (no overlap, or the offset
    does not change the residual), DelayOutOfRangeError (best offset at the edge of the range),
    AmbiguousOffsetError (another offset in the range fits equally well), LineTimeNotObservableError
    (estimated line time on its bound or less certain than its physical range: pass ``line_time_s``).
    """
    P_a, P_b = projection_matrix(camera_a), projection_matrix(camera_b)
    tracks = as_tracks(observations_a, observations_b)
    period_b = float(np.median(np.concatenate([np.diff(tr[3]) for tr in tracks])))
    half = 1.5 * period_b if search_half_width_s is None else float(search_half_width_s)
    if not half > 0:
        raise InputArrayError(f"search_half_width_s must be positive, got {search_half_width_s!r}")
    all_tb = np.concatenate([tr[3] for tr in tracks])
    epoch_b = 0.5 * (all_tb.min() + all_tb.max())
    duration = all_tb.max() - all_tb.min()
    margin = 34 * period_b + max_drift_ppm * 1e-6 * duration  # kernel half-width 32 + line-time spread
    if line_time_s is None:
        fixed_a = fixed_b = None
        line0 = float(line_time_guess_s)
    elif isinstance(line_time_s, tuple | list):
        fixed_a, fixed_b = (float(x) for x in line_time_s)
        line0 = 0.0
    else:
        fixed_a = fixed_b = float(line_time_s)
        line0 = fixed_a
    prob = _Problem(
        fundamental_matrix(P_a, P_b),
        tracks,
        epoch_b=epoch_b,
        margin_s=margin,
        guess_s=offset_guess_s,
        half_width_s=half,
        line_a=fixed_a,
        line_b=fixed_b,
    )
    if prob.n < MIN_OBSERVATIONS:
        raise NoCommonMotionError(
            f"only {prob.n} observations of camera A fall inside camera B's record for offsets "
            f"{offset_guess_s:+.4f} ± {half:.4f} s (need {MIN_OBSERVATIONS}); "
            "the records do not overlap enough (or are too short)"
        )

    # Coarse search over the offset.
    step = min(period_b / 10.0, half / 15.0)
    grid = offset_guess_s + np.arange(-half, half + 0.5 * step, step)
    cost = np.array([np.sum(prob.residuals(d, line0, 0.0, weighted=False) ** 2) for d in grid])
    k = int(np.argmin(cost))
    # Identifiability on the coarse curve, in units of the noise level at its minimum. With no usable motion
    # the curve still fluctuates, because different offsets interpolate different noise: about √(4n)·σ²
    # between two offsets, hence a threshold growing with √n.
    chi2_distinct = CHI2_DISTINCT + 10.0 * np.sqrt(prob.n)
    s2_coarse = cost[k] / max(prob.n - 1, 1)
    if (cost.max() - cost[k]) / s2_coarse < chi2_distinct:
        raise NoCommonMotionError(
            f"the epipolar residual hardly changes over offsets {grid[0]:+.4f} … {grid[-1]:+.4f} s "
            f"(Δχ² = {(cost.max() - cost[k]) / s2_coarse:.1f} < {chi2_distinct:.0f}); "
            "the marker shows no motion out of the epipolar plane"
        )
    if k in (0, grid.size - 1):
        raise DelayOutOfRangeError(
            f"the best offset lies at the edge of the search range {grid[0]:+.6f} … {grid[-1]:+.6f} s; "
            "widen search_half_width_s or correct offset_guess_s"
        )

    # Local least squares in scaled units: ms, µs, ppm.
    estimate_line = line_time_s is None
    free = [True, estimate_line, estimate_drift]
    full0 = np.array([grid[k] * 1e3, line0 * 1e6, 0.0])

    def unpack(x: np.ndarray) -> tuple[float, float, float]:
        full = full0.copy()
        full[np.array(free)] = x
        return full[0] * 1e-3, full[1] * 1e-6, full[2]

    # Bounds keep every evaluation valid: the row-time spread must stay below half a frame for the
    # band-limited reconstruction, the offset inside the searched range, the drift inside its limit.
    v_span = max(float(np.ptp(np.concatenate([tr[2], tr[5]]))) for tr in tracks)
    line_max_us = 0.4 * period_b / max(v_span, 1.0) * 1e6
    lower = np.array([(grid[0] - step) * 1e3, -line_max_us, -max_drift_ppm])[np.array(free)]
    upper = np.array([(grid[-1] + step) * 1e3, line_max_us, max_drift_ppm])[np.array(free)]
    x0 = np.clip(full0[np.array(free)], lower + 1e-9, upper - 1e-9)
    res = optimize.least_squares(
        lambda x: prob.residuals(*unpack(x)),
        x0,
        method="trf",
        bounds=(lower, upper),
        diff_step=1e-7,
        x_scale=1.0,
        xtol=1e-10,
        ftol=1e-10,
        gtol=1e-10,
        max_nfev=60,
    )
    delta, line, drift = unpack(res.x)
    r = res.fun
    dof = r.size - int(np.sum(free))
    if dof <= 0:
        raise TooFewSamplesError(f"{r.size} residuals cannot determine {int(np.sum(free))} timing parameters")
    s2 = float(r @ r) / dof
    J = res.jac
    cov = s2 * np.linalg.pinv(J.T @ J)
    std_full = np.zeros(3)
    std_full[np.array(free)] = np.sqrt(np.clip(np.diag(cov), 0, None))

    if estimate_line:
        check_line_time(tracks, line, std_full[1] * 1e-6, bound_s=line_max_us * 1e-6,
                         at_bound=bool(res.active_mask[1] != 0) or abs(line) >= 0.999 * line_max_us * 1e-6,
                         period_s=period_b, offset_s=delta)
    if not (grid[0] <= delta <= grid[-1]):
        raise DelayOutOfRangeError(
            f"the best offset {delta:+.6f} s lies beyond the search range "
            f"{grid[0]:+.6f} … {grid[-1]:+.6f} s; widen search_half_width_s or correct offset_guess_s"
        )
    best_unweighted = float(np.sum(prob.residuals(delta, line, drift, weighted=False) ** 2))
    check_ambiguity(
        prob, grid, cost, k, line=line, drift=drift, best_cost=best_unweighted, s2=s2, threshold=chi2_distinct
    )

    a, b = names
    return TimingResult(
        reference_camera=a,
        offset_s={a: 0.0, b: delta},
        line_time_s={a: line if fixed_a is None else fixed_a, b: line if fixed_b is None else fixed_b},
        drift_ppm={a: 0.0, b: drift},
        method="joint",
        uncertainty={
            "offset_s": {a: 0.0, b: std_full[0] * 1e-3},
            "line_time_s": {a: std_full[1] * 1e-6, b: std_full[1] * 1e-6},
            "drift_ppm": {a: 0.0, b: std_full[2]},
        },
        epoch_s={a: 0.0, b: epoch_b},
        details={
            **fit_details(r, s2, cov, free, grid=grid, cost=cost),
            "n_left_out_near_gaps": prob.n_near_gaps,
        },
    )
