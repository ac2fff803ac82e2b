"""Joint estimate of time offset, rolling-shutter line time and clock drift from any moving marker (ours).

For parameters θ = (offset δ, line time ℓ, drift d) the observations of both cameras get row-corrected
instants (:func:`rig.stereo.timing_model.corrected_times`; the line time is common to both cameras unless
fixed per camera), camera B's track is reconstructed band-limited at camera A's instants
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

**Line time not observable**: the line time enters only through ℓ·(v_B − v_A). When the row difference of
the two views is nearly the same for every observation (cameras side by side at one height, whatever the
marker's vertical motion: both views' rows move together), ℓ·(v_B − v_A) is a constant delay the offset
absorbs — the data fix δ + ℓ·(v_B − v_A), not δ and ℓ apart. It is declared not observable when the
solution lies on the line-time bound, or its standard uncertainty exceeds the largest physical line time
(frame period / largest observed row) — or, given a prior, that of the prior (width/√12), or it lies more
than 3 σ outside it. Then, with ``line_time_prior_s = (lo, hi)`` (e.g. 0 … frame period /
image height), ℓ is taken uniform over the prior: the offset is refitted at the prior's middle and its
uncertainty widened by the whole trade-off, |∂δ/∂ℓ|·(hi − lo)/√12 (the profile slope ∂δ/∂ℓ ≈ −mean row
difference, from the Jacobian); ``details["line_time"]`` states it. Without a prior
LineTimeNotObservableError is raised: the caller who knows the cameras (datasheet, an earlier rotor sync, 0
for a global shutter) passes ``line_time_s``.

**Gaps in B's track** (frames lost or without the marker): a gap of at most MAX_BRIDGED_GAP_FRAMES frames is
*bridged* — B's reconstruction across it assumes the track is a line spectrum (a rotor and its harmonics,
steady tones): the missing grid values are those its own prediction-error filter predicts (order 8, fitted to
runs of consecutive frames — :func:`rig.stereo.resample.prediction_filter` — and, when gaps are many, fitted
again to the track bridged by a first lower-order filter). The assumption is checked from the data: a track
predicting its next frame to a power gain below MIN_PREDICTION_GAIN is not bridged (a rotor: ≈ 10⁵). The
reconstruction's noise gain includes the bridging exactly and weights the residuals (on the synthetic rotor
with 20 % of both cameras' frames lost at random it stays ≤ 1.1, and the fitted σ within 15 % of the pixel
noise's: what the filter misses shows in σ, which scales the stated uncertainties); A's instants where it
exceeds MAX_BRIDGE_GAIN (clustered gaps) are left out. Around longer gaps A's instants within GAP_GUARD frames
(+ the kernel half-width) are left out, as B's motion cannot be reconstructed there. ``details["gaps_b"]``
counts both, in every track of B (a frame lost from the video is a gap in each).

Units: seconds, pixels; drift in ppm (1e-6 s/s) of camera B's clock relative to camera A's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from scipy import optimize

from rig.stereo._arrays import BoolArray, FloatArray
from rig.stereo._series import as_times
from rig.stereo.epipolar import fundamental_from_projections
from rig.stereo.errors import (
    AmbiguousOffsetError,
    DelayOutOfRangeError,
    InputArrayError,
    LineTimeNotObservableError,
    NoCommonMotionError,
    NonUniformSamplingError,
    TooFewSamplesError,
)
from rig.stereo.normalize import Camera
from rig.stereo.resample import Bandlimited, bandlimited, bridging_filter
from rig.stereo.timing_model import TimingResult

MIN_OBSERVATIONS = 30
CHI2_DISTINCT = 25.0  # Δχ² (5 σ) that separates a real minimum from an equally good one
GAP_GUARD = 32  # frames of B either side of a dropped frame whose reconstruction is not trusted
MAX_BRIDGED_GAP_FRAMES = 3  # gaps of B of at most this many frames are bridged, not guarded (module doc)
PREDICTION_ORDERS = (8, 6, 4)  # of the prediction-error filter that bridges them: the first that fits
MIN_PREDICTION_GAIN = 1e3  # a track less predictable than this is not bridged (its gaps are guarded)
MAX_BRIDGE_GAIN = 3.0  # noise gain above which a bridged reconstruction is left out
EDGE_MARGIN_FRAMES = 34  # A's instants used lie this far inside B's record (the kernel's half-width + 2)


def sampson_px(
    F: FloatArray,
    uv_a: FloatArray,
    uv_b: FloatArray,
    *,
    gain_b: FloatArray | None = None,
    shift_a: FloatArray | None = None,
    shift_b: FloatArray | None = None,
) -> FloatArray:
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
    distance: FloatArray = num / np.sqrt(var)
    return distance


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


class TrackPair(NamedTuple):
    """One marker seen by both cameras: frame time stamps (s, each camera's clock), undistorted centres
    (N, 2) px and exposed rows (N,) px, of camera A then camera B."""

    tau_a: FloatArray
    uv_a: FloatArray
    rows_a: FloatArray
    tau_b: FloatArray
    uv_b: FloatArray
    rows_b: FloatArray


def as_tracks(observations_a: object, observations_b: object) -> list[TrackPair]:
    """Validate both cameras' tracks → [TrackPair(tau_a, uv_a, rows_a, tau_b, uv_b, rows_b), ...].

    ``rows`` are the image rows (px) at which the sensor exposed each observation — the *observed*, lens-
    distorted v — which set the rolling-shutter instant; ``uv`` are the undistorted centres for the epipolar
    geometry. A track given as ``(t, uv)`` uses ``uv[:, 1]`` as its rows (exact without lens distortion)."""
    pa, pb = _pairs(observations_a, "observations_a"), _pairs(observations_b, "observations_b")
    if len(pa) != len(pb) or not pa:
        raise InputArrayError(
            f"observations_a has {len(pa)} tracks, observations_b {len(pb)}; they must match"
        )
    tracks: list[TrackPair] = []
    for i, (track_a, track_b) in enumerate(zip(pa, pb, strict=True)):
        out: list[FloatArray] = []
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
        tracks.append(TrackPair(*out))
    return tracks


def _bridge_of(tau_b: FloatArray, uv_b: FloatArray) -> tuple[dict[str, Any], float | None]:
    """Keyword arguments of :func:`bandlimited` for camera B's track — bridge its short gaps with its own
    prediction-error filter (:func:`rig.stereo.resample.bridging_filter`) when the track is predictable
    enough (a line spectrum), else none — and the track's prediction gain (None: too few runs to fit)."""
    try:
        fitted = bridging_filter(tau_b, uv_b, max_gap_samples=MAX_BRIDGED_GAP_FRAMES,
                                 orders=PREDICTION_ORDERS)
    except (TooFewSamplesError, NonUniformSamplingError):
        return {"bridge_max_samples": 0}, None
    taps, gain = fitted
    if gain < MIN_PREDICTION_GAIN:
        return {"bridge_max_samples": 0}, gain
    return {"bridge_max_samples": MAX_BRIDGED_GAP_FRAMES, "bridge_filter": taps}, gain


class _Residuals:
    """Residuals of the joint timing model for fixed data (one or more tracks)."""

    def __init__(self, F: FloatArray, tracks: list[TrackPair], *, epoch_b: float, margin_s: float,
                 guess_s: float, half_width_s: float, line_a: float | None, line_b: float | None) -> None:
        self.F, self.epoch_b = F, epoch_b
        self.line_a, self.line_b = line_a, line_b  # None → the common estimated line time
        self.data: list[TrackPair] = []
        self.n_near_gaps = 0
        self.gaps_b = 0  # gaps in B's tracks (dropped or skipped frames, or frames without the marker)
        self.missing_b = 0  # B's frames missing in them
        self.n_tracks_b = len(tracks)  # a frame lost from B's video is a gap in each of them
        self.bridges: list[dict[str, Any]] = []  # per track of B kept: its prediction filter, or none
        self.prediction_gains_all: list[float | None] = []  # of every track of B (None: not fitted)
        self.bridged_b = 0  # gaps of B short enough to be bridged (module doc), in the tracks that bridge
        self.n_ill_conditioned = 0  # A's instants left out where the bridging is ill-conditioned
        for track in tracks:
            bridge, prediction_gain = _bridge_of(track.tau_b, track.uv_b)
            self.prediction_gains_all.append(prediction_gain)
            lo = track.tau_b[0] + guess_s + half_width_s + margin_s
            hi = track.tau_b[-1] + guess_s - half_width_s - margin_s
            sel = (track.tau_a >= lo) & (track.tau_a <= hi)
            sel &= ~self._near_unbridged_gaps(track, sel, bridge, reach_s=(guess_s, half_width_s))
            if bridge["bridge_max_samples"] and np.count_nonzero(sel) >= 4:
                # where gaps cluster the bridged reconstruction is ill-conditioned: its noise gain (at the
                # guessed offset, no line time or drift) says so, and those instants are left out too
                _, gain = bandlimited(track.tau_b + guess_s, track.uv_b, track.tau_a[sel], noise_gain=True,
                                      **bridge)
                poor = np.flatnonzero(sel)[gain > MAX_BRIDGE_GAIN]
                self.n_ill_conditioned += poor.size
                sel[poor] = False
            if np.count_nonzero(sel) >= 4:
                ta, ua, ra, tb, ub, rb = track
                self.data.append(TrackPair(ta[sel], ua[sel], ra[sel], tb, ub, rb))
                self.bridges.append(bridge)
        self.n = sum(len(d.tau_a) for d in self.data)
        self._fits_key: tuple[float, float] | None = None  # (line time s, drift ppm) of self._fits
        self._fits: list[Bandlimited] = []

    def _near_unbridged_gaps(self, track: TrackPair, sel: BoolArray, bridge: dict[str, Any], *,
                             reach_s: tuple[float, float]) -> BoolArray:
        """A's instants (mask) near a gap of B that is not bridged, counting B's gaps on the way.

        A dropped frame of B that is not bridged cannot be reconstructed; its error reaches the band-limited
        values through the sinc's 1/d tail, so A's instants within the kernel half-width (+ GAP_GUARD frames)
        of it are left out. ``reach_s``: the offset guess and the search half-width (s)."""
        ta, tb = track.tau_a, track.tau_b
        guess_s, half_width_s = reach_s
        steps = np.diff(tb)
        period = float(np.median(steps))
        near_any = np.zeros(ta.size, dtype=bool)
        for k in np.flatnonzero(steps > 1.5 * period):
            self.gaps_b += 1
            missing = max(1, round(float(steps[k]) / period) - 1)
            self.missing_b += missing
            if bridge["bridge_max_samples"] and missing <= MAX_BRIDGED_GAP_FRAMES:
                self.bridged_b += 1  # B is reconstructed across it
                continue
            near = (ta >= tb[k] + guess_s - half_width_s - GAP_GUARD * period) & (
                ta <= tb[k + 1] + guess_s + half_width_s + GAP_GUARD * period
            )
            self.n_near_gaps += int(np.count_nonzero(sel & near & ~near_any))
            near_any |= near
        return near_any

    def bridging_statement(self) -> str:
        """Whether B's tracks were bridged, and why not (their prediction gains)."""
        gains = [g for g in self.prediction_gains_all if g is not None]
        if not gains:
            return "too few runs of consecutive frames to fit B's prediction filter: no gap bridged"
        low = min(gains)
        if low < MIN_PREDICTION_GAIN:
            return (f"B's track predicts its own next frame only to a gain {low:.0f} < "
                    f"{MIN_PREDICTION_GAIN:.0f} (not a line spectrum): its gaps are not bridged")
        return f"B's prediction gain ≥ {low:.0f}"

    def gap_notes(self) -> dict[str, Any]:
        """For ``details["gaps_b"]``: the gaps of B's tracks, those bridged and A's instants left out."""
        return {"gaps": self.gaps_b, "frames_missing": self.missing_b, "tracks": self.n_tracks_b,
                "bridged": self.bridged_b,
                "max_bridged_gap_frames": MAX_BRIDGED_GAP_FRAMES,
                "left_out_near_unbridged_gaps": self.n_near_gaps,
                "left_out_ill_conditioned": self.n_ill_conditioned,
                "prediction_gain": self.prediction_gains_all, "statement": self.bridging_statement()}

    def residuals(self, delta_s: float, line_s: float, drift_ppm: float) -> FloatArray:
        """Sampson residuals, each weighted by its own noise model (module doc)."""
        la = line_s if self.line_a is None else self.line_a
        lb = line_s if self.line_b is None else self.line_b
        out = []
        for (ta, ua, ra, tb, ub, rb), bridge in zip(self.data, self.bridges, strict=True):
            t_dst = ta + la * ra
            t_src = tb + delta_s + drift_ppm * 1e-6 * (tb - self.epoch_b) + lb * rb
            # Weight by the interpolated noise's own variance: it depends on the parameters (the line time
            # changes how irregular B's instants are), and unweighted it would bias them by O(σ²).
            h = 1e-4  # s, for B's image velocity at A's instants
            fit = Bandlimited(t_src, ub, **bridge)  # solved once for the values, the velocity and the gain
            both_s = np.concatenate([t_dst, t_dst + h])
            K = fit.kernel(both_s)
            both = fit.values_at(K, both_s)
            uv_b_at, gain = both[: t_dst.size], fit.noise_gain(K.head(t_dst.size))
            vel_b = (both[t_dst.size :] - uv_b_at) / h
            r = sampson_px(self.F, ua, uv_b_at, gain_b=gain, shift_a=la * vel_b, shift_b=lb * vel_b)
            out.append(r)
        return np.concatenate(out)

    def offset_costs(self, offsets_s: FloatArray, line_s: float, drift_ppm: float) -> FloatArray:
        """Unweighted sum of squared Sampson residuals (px²) at each of ``offsets_s`` (s), for one line time
        (s) and drift (ppm). An offset only shifts B's instants, so B's reconstruction is solved once per
        track (at offset 0) and evaluated at A's instants moved back by each offset, all offsets at once."""
        offsets = np.asarray(offsets_s, dtype=float)
        la = line_s if self.line_a is None else self.line_a
        costs = np.zeros(offsets.size)
        for (ta, ua, ra, _, _, _), fit in zip(self.data, self._fits_at(line_s, drift_ppm), strict=True):
            t_dst = ((ta + la * ra)[None, :] - offsets[:, None]).ravel()  # row-major: offset by offset
            uv_b_at = fit.values_at(fit.kernel(t_dst), t_dst)
            r = sampson_px(self.F, np.tile(ua, (offsets.size, 1)), uv_b_at)
            costs += np.sum(r.reshape(offsets.size, ta.size) ** 2, axis=1)
        return costs

    def _fits_at(self, line_s: float, drift_ppm: float) -> list[Bandlimited]:
        """B's reconstructions (one per track) at offset 0 for this line time and drift (the last kept)."""
        if self._fits_key != (line_s, drift_ppm):
            lb = line_s if self.line_b is None else self.line_b
            self._fits = [Bandlimited(tb + drift_ppm * 1e-6 * (tb - self.epoch_b) + lb * rb, ub, **bridge)
                          for (_, _, _, tb, ub, rb), bridge in zip(self.data, self.bridges, strict=True)]
            self._fits_key = (line_s, drift_ppm)
        return self._fits


@dataclass
class _Fit:
    """One local least-squares solution (seconds, ppm) with its statistics."""

    offset_s: float
    line_s: float
    drift_ppm: float
    std: FloatArray  # (3,) standard uncertainties in ms, µs, ppm (0 for fixed parameters)
    cov: FloatArray  # covariance of the free parameters (ms, µs, ppm)
    free: list[bool]
    residuals: FloatArray
    s2: float
    jac: FloatArray
    at_bound: bool


class JointTiming:
    """The joint timing problem of one data set: coarse search → refinement → checks → :class:`TimingResult`.

    Options as :func:`estimate_joint`, and ``edge_margin_frames``: how far inside B's record A's instants
    must lie (default the band-limited kernel's half-width: exact reconstruction; fewer keeps the record's
    ends — where a motion starts — at the price of a truncated kernel there, for comparing offsets a whole
    period apart, whose truncation errors coincide on a periodic motion). ``solve(names)`` runs the stages;
    each stage raises the errors listed there.
    """

    # set by coarse_search: the offsets searched (s), their unweighted cost (px²), the index of the best
    # and the Δχ² that tells a separate minimum apart from it
    grid: FloatArray
    costs: FloatArray
    k: int
    chi2_distinct: float

    def __init__(self, camera_a: Camera, camera_b: Camera, observations_a: object, observations_b: object, *,
                 offset_guess_s: float = 0.0, search_half_width_s: float | None = None,
                 line_time_s: float | tuple[float, float] | None = None, line_time_guess_s: float = 0.0,
                 line_time_prior_s: tuple[float, float] | None = None, estimate_drift: bool = True,
                 max_drift_ppm: float = 200.0, edge_margin_frames: float = EDGE_MARGIN_FRAMES) -> None:
        F = fundamental_from_projections(camera_a, camera_b)
        self.tracks = as_tracks(observations_a, observations_b)
        self.period_b = float(np.median(np.concatenate([np.diff(tr.tau_b) for tr in self.tracks])))
        half = 1.5 * self.period_b if search_half_width_s is None else float(search_half_width_s)
        if not half > 0:
            raise InputArrayError(f"search_half_width_s must be positive, got {search_half_width_s!r}")
        if line_time_prior_s is not None:
            lo, hi = (float(x) for x in line_time_prior_s)
            if not (np.isfinite(lo) and np.isfinite(hi) and 0.0 <= lo <= hi < self.period_b):
                raise InputArrayError(f"line_time_prior_s must be (lo, hi) with 0 ≤ lo ≤ hi < frame period, "
                                      f"got {line_time_prior_s!r}")
            self.prior: tuple[float, float] | None = (lo, hi)
        else:
            self.prior = None
        self.guess_s, self.half_s = float(offset_guess_s), half
        self.estimate_drift, self.max_drift_ppm = bool(estimate_drift), float(max_drift_ppm)
        all_tb = np.concatenate([tr.tau_b for tr in self.tracks])
        self.epoch_b = 0.5 * (all_tb.min() + all_tb.max())
        # A's instants this far inside B's record: the kernel half-width (32) + the rows' spread; or fewer
        # frames (``edge_margin_frames``) when a truncated kernel near B's ends is acceptable
        margin = edge_margin_frames * self.period_b + max_drift_ppm * 1e-6 * np.ptp(all_tb)
        self.estimate_line = line_time_s is None
        if line_time_s is None:
            self.fixed: tuple[float | None, float | None] = (None, None)
            self.line0 = float(line_time_guess_s)
        elif isinstance(line_time_s, tuple | list):
            line_a_s, line_b_s = (float(x) for x in line_time_s)
            self.fixed = (line_a_s, line_b_s)
            self.line0 = 0.0
        else:
            self.fixed = (float(line_time_s), float(line_time_s))
            self.line0 = float(line_time_s)
        self.res = _Residuals(F, self.tracks, epoch_b=self.epoch_b,
                              margin_s=margin, guess_s=self.guess_s, half_width_s=half, line_a=self.fixed[0],
                              line_b=self.fixed[1])
        if self.res.n < MIN_OBSERVATIONS:
            gaps = self.res.gaps_b - self.res.bridged_b
            left_out = self.res.n_near_gaps + self.res.n_ill_conditioned
            why = ("the records do not overlap enough (or are too short)" if not left_out else
                   f"{left_out} more were left out within {GAP_GUARD} frames of the {gaps} gap(s) in camera "
                   f"B's track that could not be bridged ({self.res.missing_b} frames missing in "
                   f"{self.res.gaps_b} gap(s), counted in each of B's {self.res.n_tracks_b} track(s): "
                   "dropped, skipped or without the marker; "
                   f"{self.res.bridged_b} gap(s) of at most {MAX_BRIDGED_GAP_FRAMES} frames bridged, "
                   f"{self.res.n_ill_conditioned} instants left out where they cluster; "
                   f"{self.res.bridging_statement()})")
            raise NoCommonMotionError(
                f"only {self.res.n} observations of camera A fall inside camera B's record for offsets "
                f"{self.guess_s:+.4f} ± {half:.4f} s (need {MIN_OBSERVATIONS}); {why}")
        v_span = max(float(np.ptp(np.concatenate([tr.rows_a, tr.rows_b]))) for tr in self.tracks)
        # the row-time spread must stay below half a frame for the band-limited reconstruction
        self.line_max_s = 0.4 * self.period_b / max(v_span, 1.0)
        self.notes: dict[str, Any] = {}

    def solve(self, names: tuple[str, str]) -> TimingResult:
        """All stages; the result of camera B relative to A."""
        self.coarse_search()
        fit = self.refine(free_line=self.estimate_line, offset0_s=self.grid[self.k], line0_s=self.line0)
        if self.estimate_line:
            problem = self.line_time_problem(fit)
            if problem is not None:
                if self.prior is None:
                    raise problem
                fit = self.apply_line_time_prior(fit, problem, self.prior)
        self.check_in_range(fit)
        self.check_ambiguity(fit)
        return self.result(fit, names)

    def cost(self, offset_s: float, line_s: float, drift_ppm: float) -> float:
        """Unweighted sum of squared Sampson residuals (px²)."""
        return float(self.res.offset_costs(np.array([offset_s]), line_s, drift_ppm)[0])

    def coarse_search(self) -> None:
        """Cost over the offset range (step ≤ a tenth of a frame); raises NoCommonMotionError when flat,
        DelayOutOfRangeError when the minimum is at the edge."""
        step = min(self.period_b / 10.0, self.half_s / 15.0)
        self.grid = self.guess_s + np.arange(-self.half_s, self.half_s + 0.5 * step, step)
        self.costs = self.res.offset_costs(self.grid, self.line0, 0.0)
        k = int(np.argmin(self.costs))
        # Identifiability in units of the noise level at the minimum. With no usable motion the curve still
        # fluctuates (different offsets interpolate different noise): about √(4n)·σ², hence the √n term.
        self.chi2_distinct = CHI2_DISTINCT + 10.0 * float(np.sqrt(self.res.n))
        s2 = self.costs[k] / max(self.res.n - 1, 1)
        contrast = (self.costs.max() - self.costs[k]) / s2
        if contrast < self.chi2_distinct:
            raise NoCommonMotionError(
                f"the epipolar residual hardly changes over offsets {self.grid[0]:+.4f} … "
                f"{self.grid[-1]:+.4f} s "
                f"(Δχ² = {contrast:.1f} < {self.chi2_distinct:.0f}); "
                "the marker shows no motion out of the epipolar plane")
        if k in (0, self.grid.size - 1):
            raise DelayOutOfRangeError(
                f"the best offset lies at the edge of the search range {self.grid[0]:+.6f} … "
                f"{self.grid[-1]:+.6f} s; widen search_half_width_s or correct offset_guess_s")
        self.k = k

    def refine(self, *, free_line: bool, offset0_s: float, line0_s: float, drift0_ppm: float = 0.0) -> _Fit:
        """Local least squares in scaled units (ms, µs, ppm) from the given start; the line time free or
        held at ``line0_s``."""
        free = [True, free_line, self.estimate_drift]
        mask = np.array(free)
        full0 = np.array([offset0_s * 1e3, line0_s * 1e6, drift0_ppm])

        def unpack(x: FloatArray) -> tuple[float, float, float]:
            full = full0.copy()
            full[mask] = x
            return full[0] * 1e-3, full[1] * 1e-6, full[2]

        step = self.grid[1] - self.grid[0]
        line_max_us = self.line_max_s * 1e6
        lower = np.array([(self.grid[0] - step) * 1e3, -line_max_us, -self.max_drift_ppm])[mask]
        upper = np.array([(self.grid[-1] + step) * 1e3, line_max_us, self.max_drift_ppm])[mask]
        x0 = np.clip(full0[mask], lower + 1e-9, upper - 1e-9)
        res = optimize.least_squares(lambda x: self.res.residuals(*unpack(x)), x0, method="trf",
                                     bounds=(lower, upper), diff_step=1e-7, x_scale=1.0, xtol=1e-10,
                                     ftol=1e-10, gtol=1e-10, max_nfev=60)
        delta, line, drift = unpack(res.x)
        r = res.fun
        dof = r.size - int(np.sum(free))
        if dof <= 0:
            raise TooFewSamplesError(
                f"{r.size} residuals cannot determine {int(np.sum(free))} timing parameters")
        s2 = float(r @ r) / dof
        cov = s2 * np.linalg.pinv(res.jac.T @ res.jac)
        std = np.zeros(3)
        std[mask] = np.sqrt(np.clip(np.diag(cov), 0, None))
        at_bound = free_line and (bool(res.active_mask[1] != 0) or abs(line) >= 0.999 * self.line_max_s)
        return _Fit(delta, line, drift, std, cov, free, r, s2, res.jac, at_bound)

    def line_time_problem(self, fit: _Fit) -> LineTimeNotObservableError | None:
        """Why the estimated line time cannot be trusted (module doc), or None: on its bound, less certain
        than the largest physical line time (frame period / largest observed row), or (with a prior) more
        than 3 σ outside the prior or less certain than the prior itself (its width / √12)."""
        std_s = float(fit.std[1]) * 1e-6
        prior = self.prior
        max_row = max(float(np.max(np.concatenate([tr.rows_a, tr.rows_b]))) for tr in self.tracks)
        limit_s = self.period_b / max(max_row, 1.0)
        outside = prior is not None and not (prior[0] - 3 * std_s <= fit.line_s <= prior[1] + 3 * std_s)
        vague = prior is not None and std_s > (prior[1] - prior[0]) / np.sqrt(12.0)
        if not fit.at_bound and std_s <= limit_s and not outside and not vague:
            return None
        diff = np.concatenate([np.interp(ta, tb + fit.offset_s, rb) - ra
                               for ta, _, ra, tb, _, rb in self.tracks])
        spread = float(np.std(diff))
        if fit.at_bound:
            why = f"it ran to the bound ±{self.line_max_s * 1e6:.1f} µs of the fit"
        elif std_s > limit_s:
            why = (f"its uncertainty exceeds the largest physical line time {limit_s * 1e6:.2f} µs "
                   "(frame period / largest row)")
        elif outside and prior is not None:
            why = (f"it lies outside the physical range {prior[0] * 1e6:.2f} … "
                   f"{prior[1] * 1e6:.2f} µs by more than 3 σ")
        elif prior is not None:
            why = ("its uncertainty exceeds that of the physical range itself "
                   f"({(prior[1] - prior[0]) / np.sqrt(12.0) * 1e6:.2f} µs)")
        return LineTimeNotObservableError(
            f"the rolling-shutter line time is not observable from this motion: estimate "
            f"{fit.line_s * 1e6:+.2f} ± {std_s * 1e6:.2f} µs, and {why}; the two cameras' rows differ by a "
            f"nearly constant amount (std {spread:.2f} px about mean {float(np.mean(diff)):+.2f} px), so the "
            "line time trades against the offset. Pass line_time_s (the cameras' known line time, or 0 for a "
            "global shutter) or line_time_prior_s",
            estimate_s=float(fit.line_s), uncertainty_s=float(std_s), limit_s=limit_s, at_bound=fit.at_bound,
            row_difference_spread_px=spread)

    def apply_line_time_prior(
        self, fit: _Fit, problem: LineTimeNotObservableError, prior_s: tuple[float, float]
    ) -> _Fit:
        """Refit with the line time held at the middle of ``prior_s`` = (lo, hi) and widen the offset
        uncertainty by the trade-off (module doc)."""
        lo, hi = prior_s
        mid = 0.5 * (lo + hi)
        # profile slope: the best (offset, drift) for a given line time, from the free fit's Jacobian
        J = fit.jac
        others = [0] + ([2] if fit.free[2] else [])
        J_o, J_l = J[:, others], J[:, 1]
        shift = -np.linalg.lstsq(J_o, J_l, rcond=None)[0]  # per µs of line time, in (ms, ppm)
        slope_s_per_s = float(shift[0]) * 1e3  # s of offset per s of line time
        d_line_us = (mid - fit.line_s) * 1e6
        drift0 = fit.drift_ppm + (float(shift[1]) * d_line_us if fit.free[2] else 0.0)
        held = self.refine(free_line=False, offset0_s=fit.offset_s + float(shift[0]) * d_line_us * 1e-3,
                           line0_s=mid, drift0_ppm=drift0)
        u_prior_s = abs(slope_s_per_s) * (hi - lo) / np.sqrt(12.0)
        bound_s = abs(slope_s_per_s) * (hi - lo) / 2.0  # the line time at either end of its range
        u_stat_s = held.std[0] * 1e-3
        held.std[0] = np.hypot(u_stat_s, u_prior_s) * 1e3
        held.std[1] = (hi - lo) / np.sqrt(12.0) * 1e6
        self.notes["line_time"] = {
            "observable": False,
            "reason": str(problem),
            "prior_s": [lo, hi],
            "offset_per_line_time_s_per_s": slope_s_per_s,
            "offset_uncertainty_statistical_s": u_stat_s,
            "offset_uncertainty_from_line_time_s": u_prior_s,
            "offset_bound_from_line_time_s": bound_s,
            "statement": (
                f"line time not observable from this motion (free estimate {problem.estimate_s * 1e6:+.2f} ± "
                f"{problem.uncertainty_s * 1e6:.2f} µs); taken uniform over {lo * 1e6:.2f} … "
                f"{hi * 1e6:.2f} µs "
                f"(value {mid * 1e6:.2f} µs, u {(hi - lo) / np.sqrt(12) * 1e6:.2f} µs). The offset moves by "
                f"{slope_s_per_s:+.2f} s per s of line time (−row difference, px), so its uncertainty "
                f"includes {u_prior_s * 1e3:.4f} ms for the line time beside {u_stat_s * 1e3:.4f} ms "
                f"statistical (anywhere in its range, the line time moves the offset by at most ± "
                f"{bound_s * 1e3:.4f} ms from the value given); give --line-time-s if the cameras' line time "
                "is known"),
        }
        return held

    def check_in_range(self, fit: _Fit) -> None:
        """DelayOutOfRangeError when the refined offset left the searched range."""
        if not (self.grid[0] <= fit.offset_s <= self.grid[-1]):
            raise DelayOutOfRangeError(
                f"the best offset {fit.offset_s:+.6f} s lies beyond the search range {self.grid[0]:+.6f} … "
                f"{self.grid[-1]:+.6f} s; widen search_half_width_s or correct offset_guess_s")

    def check_ambiguity(self, fit: _Fit) -> None:
        """AmbiguousOffsetError if a separate local minimum of the coarse cost fits as well as the best."""
        grid, cost, k = self.grid, self.costs, self.k
        step = grid[1] - grid[0]
        best = self.cost(fit.offset_s, fit.line_s, fit.drift_ppm)
        is_min = np.r_[False, (cost[1:-1] <= cost[:-2]) & (cost[1:-1] <= cost[2:]), False]
        for j in np.flatnonzero(is_min):
            if abs(j - k) <= 3:
                continue
            refined = optimize.minimize_scalar(lambda d: self.cost(d, fit.line_s, fit.drift_ppm),
                                               bounds=(grid[j] - step, grid[j] + step), method="bounded")
            if (refined.fun - best) / fit.s2 < self.chi2_distinct:
                raise AmbiguousOffsetError(
                    f"offsets {grid[k]:+.6f} s and {refined.x:+.6f} s fit equally well "
                    f"(Δχ² = {(refined.fun - best) / fit.s2:.1f}); the motion repeats within the search "
                    "range: narrow search_half_width_s around a better offset_guess_s, or use a non-periodic "
                    "motion")

    def result(self, fit: _Fit, names: tuple[str, str]) -> TimingResult:
        """The :class:`TimingResult` of ``fit`` (camera B relative to A)."""
        a, b = names
        fa, fb = self.fixed
        labels = [n for n, f in zip(("offset", "line_time", "drift"), fit.free, strict=True) if f]
        sd = np.sqrt(np.clip(np.diag(fit.cov), 1e-300, None))
        return TimingResult(
            reference_camera=a,
            offset_s={a: 0.0, b: fit.offset_s},
            line_time_s={a: fit.line_s if fa is None else fa, b: fit.line_s if fb is None else fb},
            drift_ppm={a: 0.0, b: fit.drift_ppm},
            method="joint",
            uncertainty={"offset_s": {a: 0.0, b: fit.std[0] * 1e-3},
                         "line_time_s": {a: fit.std[1] * 1e-6, b: fit.std[1] * 1e-6},
                         "drift_ppm": {a: 0.0, b: fit.std[2]}},
            epoch_s={a: 0.0, b: self.epoch_b},
            details={"residual_rms_px": float(np.sqrt(np.mean(fit.residuals**2))),
                     "n_residuals": int(fit.residuals.size), "sigma_px": float(np.sqrt(fit.s2)),
                     "parameters": labels, "correlation": (fit.cov / np.outer(sd, sd)).tolist(),
                     "coarse_offset_s": self.grid.tolist(), "coarse_cost_px2": self.costs.tolist(),
                     "n_left_out_near_gaps": self.res.n_near_gaps, "gaps_b": self.res.gap_notes(),
                     **self.notes})


def estimate_joint(
    camera_a: Camera,
    camera_b: Camera,
    observations_a: object,
    observations_b: object,
    *,
    names: tuple[str, str] = ("a", "b"),
    offset_guess_s: float = 0.0,
    search_half_width_s: float | None = None,
    line_time_s: float | tuple[float, float] | None = None,
    line_time_guess_s: float = 0.0,
    line_time_prior_s: tuple[float, float] | None = None,
    estimate_drift: bool = True,
    max_drift_ppm: float = 200.0,
) -> TimingResult:
    """Joint offset / line time / drift of camera B relative to camera A (see module doc).

    The offset range searched is ``offset_guess_s`` ± ``search_half_width_s`` (default 1.5 frames of B).
    ``line_time_s``: None → one line time common to both cameras is estimated (starting at
    ``line_time_guess_s``); a number → fixed for both; a pair → fixed per camera (A, B).
    ``line_time_prior_s``: (lo, hi) s, the physical range used when the motion cannot reveal the line time
    (module doc); None → LineTimeNotObservableError instead.
    ``estimate_drift``: fit B's clock rate error (ppm, |d| ≤ ``max_drift_ppm`` enters only the record margin).
    Errors: TooFewSamplesError, NonMonotonicTimestampsError, NoCommonMotionError (no overlap, or the offset
    does not change the residual), DelayOutOfRangeError (best offset at the edge of the range),
    AmbiguousOffsetError (another offset in the range fits equally well), LineTimeNotObservableError.
    """
    problem = JointTiming(camera_a, camera_b, observations_a, observations_b, offset_guess_s=offset_guess_s,
                          search_half_width_s=search_half_width_s, line_time_s=line_time_s,
                          line_time_guess_s=line_time_guess_s, line_time_prior_s=line_time_prior_s,
                          estimate_drift=estimate_drift, max_drift_ppm=max_drift_ppm)
    return problem.solve(names)
