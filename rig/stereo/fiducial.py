"""A camera's clock against the controller's from a timing fiducial: an LED whose drive edges are known.

The LED (or LED bar) is in view; its drive switches at instants ``e_k`` the controller knows in its own
clock (:class:`DriveEdges`, with their common standard uncertainty). A rolling-shutter camera exposes
row y of a frame over [s, s + E] of its own clock (s = frame start + y·line time, E the exposure), so a
row lit part-way through its exposure dates an edge to a fraction of the exposure, and every frame in
which an edge crosses the LED's rows dates it again.

Model fitted (:func:`fit_fiducial_clock`), controller time t_c of camera time t:
``t_c = t + offset_s + rate·(t − t_ref_s)``. The LED's light is a linear ramp of duration ``rise_time_s``
starting at each drive edge (a linear response: rising and falling ramps add), so the mean level of a
row is in closed form (:func:`mean_levels`), and a row's brightness is ``b_off + gain·level``. The rise
time is the LED's (its datasheet's 10–90 %), not fitted: a ramp short against the exposure changes a
row's level only through its centre of light, e + rise/2, so rise and offset cannot be told apart. The
parameters (offset, rate, b_off, gain) are fitted by least squares over the rows near the edges,
after a coarse search of the offset over the prior interval (the current start-event bound), with the
rate held at 0 unless the edges seen span long enough to resolve it. The pattern must not repeat within
the prior interval, otherwise the offset is ambiguous (:class:`AmbiguousOffsetError`). The drive's
period must be incommensurate with the frame period (e.g. 97.3 ms against 16.67 ms), so that its edges
walk through the frame and cross the LED's rows; a commensurate one may never be seen there
(:class:`TooFewSamplesError`).

Uncertainty: the fit's (Jacobian covariance scaled by the residual variance) combined with the edge
times' own uncertainty (how well the controller knows its edges: the command's round trip). A real
LED's rise is not exactly a ramp: the fitted ramp's length bounds where the light's centre can be, a
shape term in the uncertainty (the twin renders a first-order rise, not a ramp, to keep the model honest).

Units: seconds, digital numbers (DN) for brightness. Pure functions on arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from rig.stereo.errors import AmbiguousOffsetError, InputArrayError, NoCommonMotionError, TooFewSamplesError

__all__ = ["DriveEdges", "FiducialClock", "RowSamples", "fit_fiducial_clock", "mean_levels", "row_profile",
           "square_wave_edges"]

# the rate (drift) is fitted only when the edges seen span at least this long (camera clock, s)
MIN_RATE_SPAN_S = 2.0
# the line time is fitted when the rows lit part-way span at least this many rows (and 2 edges are seen)
MIN_LINE_TIME_SPAN_PX = 50.0
# rows lit part-way (at the fitted offset) that a fit needs: fewer date no edge
MIN_TRANSITION_ROWS = 3
# bound on the fitted line-time correction (ns per row): a sync's line time of a 540-row frame was 1.34 µs/row
# short on `rig mock lab` (27.78 µs true), beyond the former 1 µs bound
MAX_LINE_TIME_ERROR_NS = 5e3
# bound on the LED's rise time (s): an LED rises in ns–µs; 1 ms would be a wrong configuration
MAX_RISE_TIME_S = 1e-3
_F = NDArray[np.float64]


@dataclass(frozen=True)
class DriveEdges:
    """The fiducial's drive edges in the controller's clock.

    ``times_s`` strictly increasing (s); ``rising[k]`` True for a rising edge (LED turns on), False for a
    falling one; ``u_s`` the standard uncertainty of every edge time as the controller knows it (s, ≥ 0).
    """

    times_s: _F
    rising: NDArray[np.bool_]
    u_s: float = 0.0

    def __post_init__(self) -> None:
        t = np.asarray(self.times_s, dtype=float)
        r = np.asarray(self.rising, dtype=bool)
        if t.ndim != 1 or t.size < 1 or r.shape != t.shape:
            raise InputArrayError(f"times_s and rising must be 1-D of the same length ≥ 1, got shapes "
                                  f"{t.shape} and {r.shape}")
        if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
            raise InputArrayError("times_s must be finite and strictly increasing")
        if not (math.isfinite(self.u_s) and self.u_s >= 0):
            raise InputArrayError(f"u_s must be finite and ≥ 0, got {self.u_s!r}")
        object.__setattr__(self, "times_s", t)
        object.__setattr__(self, "rising", r)

    @property
    def signs(self) -> _F:
        """+1 for a rising edge, −1 for a falling one."""
        return np.where(self.rising, 1.0, -1.0)

    @property
    def initial_level(self) -> float:
        """Level before the first edge: off when it rises, on when it falls."""
        return 0.0 if bool(self.rising[0]) else 1.0

    @property
    def states(self) -> _F:
        """The level after the first k edges, k = 0 … number of edges (a step model: each edge complete)."""
        return np.concatenate([[self.initial_level], self.initial_level + np.cumsum(self.signs)])

    def repeat_s(self) -> float:
        """The shortest shift that could map the pattern onto itself: the smallest gap between two edges of
        the same sense (inf with fewer than two of a sense)."""
        gaps = [np.diff(self.times_s[self.rising == sense]) for sense in (True, False)]
        return min((float(g.min()) for g in gaps if g.size), default=math.inf)


@dataclass(frozen=True)
class RowSamples:
    """LED brightness per image row: ``start_s`` (camera clock, start of that row's exposure),
    ``brightness_dn`` (mean of the LED's pixels in that row), ``exposure_s`` (> 0, the rows' exposure),
    ``row_px`` (optional: the rows' indices; given, the fit also corrects the line time that ``start_s``
    assumed, when the LED spans enough rows)."""

    start_s: _F
    brightness_dn: _F
    exposure_s: float
    row_px: _F | None = None

    def __post_init__(self) -> None:
        s = np.asarray(self.start_s, dtype=float)
        b = np.asarray(self.brightness_dn, dtype=float)
        if s.ndim != 1 or b.shape != s.shape:
            raise InputArrayError(f"start_s and brightness_dn must be 1-D of one length, got {s.shape}, "
                                  f"{b.shape}")
        if not (np.all(np.isfinite(s)) and np.all(np.isfinite(b))):
            raise InputArrayError("start_s and brightness_dn must be finite")
        if not (math.isfinite(self.exposure_s) and self.exposure_s > 0):
            raise InputArrayError(f"exposure_s must be a finite number > 0, got {self.exposure_s!r}")
        object.__setattr__(self, "start_s", s)
        object.__setattr__(self, "brightness_dn", b)
        if self.row_px is not None:
            r = np.asarray(self.row_px, dtype=float)
            if r.shape != s.shape or not np.all(np.isfinite(r)):
                raise InputArrayError(f"row_px must be finite and of start_s's length, got shape {r.shape}")
            object.__setattr__(self, "row_px", r)

    def subset(self, keep: NDArray[np.bool_]) -> RowSamples:
        return RowSamples(self.start_s[keep], self.brightness_dn[keep], self.exposure_s,
                          None if self.row_px is None else self.row_px[keep])


@dataclass(frozen=True)
class FiducialClock:
    """Controller time of a camera's clock: t_c = t + offset_s + rate·(t − t_ref_s) (all s, camera clock t),
    plus ``line_time_error_s``·(row − ``row_ref_px``) for a row's instant when the line time was fitted
    (``line_time_fitted``; the offset is then stated at ``row_ref_px``, the mean lit-part-way row).

    ``u_offset_s``: standard uncertainty of the offset at ``t_ref_s`` (fit ⊕ edge knowledge);
    ``u_fit_s`` the fit's part; ``rate_fitted`` False when the edges seen spanned too little time to
    resolve a drift (rate held at 0; the caller bounds it). ``n_transition_rows``: rows lit part-way
    (the informative ones); ``n_edges_seen``: drive edges that crossed the LED's rows during an exposure.
    """

    offset_s: float
    u_offset_s: float
    u_fit_s: float
    rate: float
    u_rate: float
    rate_fitted: bool
    t_ref_s: float
    rise_time_s: float
    n_rows: int
    n_transition_rows: int
    n_edges_seen: int
    residual_dn: float
    line_time_fitted: bool = False
    line_time_error_s: float = 0.0
    u_line_time_error_s: float = 0.0
    row_ref_px: float = 0.0

    def offset_at_row_s(self, row_px: float) -> tuple[float, float]:
        """(offset, standard uncertainty) s at ``t_ref_s`` for an instant of image row ``row_px``."""
        d = row_px - self.row_ref_px if self.line_time_fitted else 0.0
        return (self.offset_s + self.line_time_error_s * d,
                math.hypot(self.u_offset_s, self.u_line_time_error_s * d))

    def controller_time_s(self, camera_time_s: ArrayLike) -> _F:
        t = np.asarray(camera_time_s, dtype=float)
        return t + self.offset_s + self.rate * (t - self.t_ref_s)

    def u_offset_at_s(self, camera_time_s: float) -> float:
        """Standard uncertainty (s) of the offset at another camera time (the rate's share grows away)."""
        return math.hypot(self.u_offset_s, self.u_rate * (camera_time_s - self.t_ref_s))


def mean_levels(window_start_s: ArrayLike, exposure_s: float, edges: DriveEdges, rise_time_s: float) -> _F:
    """Mean LED level (0..1) over each window [s, s + exposure_s] of controller time (ramp model), for
    finite window starts ``window_start_s`` (s, 1-D, any order).

    Edges that finished rising before a window count fully (the running on/off state), the few that fall
    inside it (or ramp into it) partially; the windows in order of their start walk along the edges, compiled
    (:func:`rig.stereo.fiducial_kernel.levels`): O(n log n + m) for n windows and m edges.
    """
    from rig.stereo.fiducial_kernel import levels  # numba: loaded by the first fit

    s = np.asarray(window_start_s, dtype=float)
    order = np.argsort(s, kind="stable")
    in_order = np.empty(s.size)
    levels(np.ascontiguousarray(s[order]), 0.0, float(exposure_s), edges.times_s, edges.signs, edges.states,
           float(rise_time_s), in_order)
    out = np.empty(s.size)
    out[order] = in_order
    return out


def row_profile(gray: ArrayLike, region: tuple[int, int, int, int]) -> tuple[NDArray[np.int64], _F]:
    """(rows, mean brightness DN per row) of the image region (x0, y0, x1, y1) px, half-open, clipped to the
    image; raises InputArrayError when the region lies outside it."""
    img = np.asarray(gray)
    if img.ndim != 2:
        raise InputArrayError(f"gray must be a 2-D image, got shape {img.shape}")
    x0, y0, x1, y1 = (int(v) for v in region)
    x0, y0 = max(x0, 0), max(y0, 0)
    x1, y1 = min(x1, img.shape[1]), min(y1, img.shape[0])
    if x1 <= x0 or y1 <= y0:
        raise InputArrayError(f"region {region} lies outside the {img.shape[1]}×{img.shape[0]} image")
    patch = img[y0:y1, x0:x1].astype(float)
    return np.arange(y0, y1, dtype=np.int64), patch.mean(axis=1)


def _affine(level: _F, brightness: _F) -> tuple[float, float, _F]:
    """(b_off, gain, residuals) of the linear least-squares fit brightness ≈ b_off + gain·level."""
    a = np.column_stack([np.ones_like(level), level])
    coef, *_ = np.linalg.lstsq(a, brightness, rcond=None)
    return float(coef[0]), float(coef[1]), brightness - a @ coef


def _grid_offset_s(rows: RowSamples, edges: DriveEdges, grid: _F, rise_time_s: float) -> float | None:
    """Grid offset of the best affine fit of the rows (None when no offset lights any row part-way).

    Every offset's residual sum of squares comes from one compiled pass over the rows
    (:func:`rig.stereo.fiducial_kernel.grid_sse`, on the levels of :func:`mean_levels`, in closed form on
    centred values), and only the offsets within its rounding of the least are fitted again by :func:`_affine`
    (lstsq), which chooses among them: the offset a lstsq at every node would choose."""
    from rig.stereo.fiducial_kernel import grid_sse  # numba: loaded by the first search

    b = rows.brightness_dn
    order = np.argsort(rows.start_s, kind="stable")
    all_sse = grid_sse(rows.start_s[order], b[order], float(rows.exposure_s), edges.times_s, edges.signs,
                       edges.states, float(rise_time_s), np.ascontiguousarray(grid, dtype=float))
    if not np.isfinite(all_sse).any():
        return None
    slack = 1e-6 * float(np.min(all_sse)) + 1e-9 * float(np.sum((b - b.mean()) ** 2))
    near = np.nonzero(all_sse <= np.min(all_sse) + slack)[0]
    exact = [float(np.sum(_affine(mean_levels(grid[i] + rows.start_s, rows.exposure_s, edges, rise_time_s),
                                  b)[2] ** 2)) for i in near]
    return float(grid[near[int(np.argmin(exact))]])


def _coarse_offset_s(rows: RowSamples, edges: DriveEdges, prior_offset_s: float, half_width_s: float,
                     rise_time_s: float) -> float:
    """Offset of the best affine fit, coarse to fine over the prior interval: grids of 1 ms, 0.25 ms and
    ¼ exposure, each coarse level with the ramp blurred to its step (so that no minimum falls between its
    nodes) and its estimate corrected for the blur's shift of the ramp's centre, half of the extra length."""
    centre, half = prior_offset_s, half_width_s
    fine = 0.25 * rows.exposure_s
    steps = [st for st in (1e-3, 2.5e-4) if fine < st < half] + [fine]
    for step in steps:
        rise = max(rise_time_s, step)
        grid = centre + np.arange(-half, half + 0.5 * step, step)
        near = _near_edges(rows, edges, centre, half + rise + rows.exposure_s)
        best = _grid_offset_s(RowSamples(rows.start_s[near], rows.brightness_dn[near], rows.exposure_s),
                              edges, grid, rise) if near.any() else None
        if best is None:
            raise NoCommonMotionError(
                "the LED is on (or off) in every row at every offset of the prior interval: no drive edge "
                "falls within the recording; record longer or check the generator's sync output and the LED "
                "region")
        centre, half = best - 0.5 * (rise - rise_time_s), 2.0 * step
    return centre


def _near_edges(rows: RowSamples, edges: DriveEdges, offset_s: float, margin_s: float) -> NDArray[np.bool_]:
    """Rows whose exposure lies within ``margin_s`` of a drive edge at this offset (the informative rows and
    the plateaus beside them)."""
    a = rows.start_s + offset_s
    lo = np.searchsorted(edges.times_s, a - margin_s, side="left")
    hi = np.searchsorted(edges.times_s, a + rows.exposure_s + margin_s, side="left")
    return hi > lo


def _edges_seen(rows: RowSamples, edges: DriveEdges, offset_s: float | _F,
                rise_time_s: float) -> tuple[int, _F]:
    """(number of distinct edges lit part-way in some row, mask of transition rows) at this offset."""
    a = rows.start_s + offset_s
    lo = np.searchsorted(edges.times_s, a - rise_time_s, side="left")
    hi = np.searchsorted(edges.times_s, a + rows.exposure_s, side="left")
    transition = hi > lo
    return int(np.unique(lo[transition]).size), transition.astype(float)


def fit_fiducial_clock(rows: RowSamples, edges: DriveEdges, *, prior_offset_s: float,
                       prior_half_width_s: float, rise_time_s: float = 1e-5,
                       t_ref_s: float | None = None) -> FiducialClock:
    """Fit the camera clock against the controller's (see the module docstring).

    ``prior_offset_s`` ± ``prior_half_width_s``: the interval (controller − camera, s) the offset is known
    to lie in beforehand (e.g. the start events' ±½ frame); the drive pattern must not repeat within it.
    ``rise_time_s``: the LED's rise time (s, 0 ≤ rise ≤ 1 ms). ``t_ref_s`` (camera clock): where the offset
    is stated (default: the middle of the rows' span).
    Raises TooFewSamplesError (fewer than 8 rows or no row lit part-way), AmbiguousOffsetError,
    NoCommonMotionError (no edge within the recording).
    """
    n = rows.start_s.size
    if n < 8:
        raise TooFewSamplesError(f"need ≥ 8 LED row samples, got {n}")
    if not (math.isfinite(prior_half_width_s) and prior_half_width_s > 0 and math.isfinite(prior_offset_s)):
        raise InputArrayError(f"prior_offset_s and prior_half_width_s > 0 must be finite, got "
                              f"{prior_offset_s!r}, {prior_half_width_s!r}")
    repeat = edges.repeat_s()
    if 2.0 * prior_half_width_s >= repeat:
        raise AmbiguousOffsetError(
            f"the drive pattern repeats every {1e3 * repeat:.3f} ms, within the prior interval "
            f"±{1e3 * prior_half_width_s:.3f} ms: drive the LED with a period > "
            f"{2e3 * prior_half_width_s:.3f} ms")
    if not (math.isfinite(rise_time_s) and 0.0 <= rise_time_s <= MAX_RISE_TIME_S):
        raise InputArrayError(f"rise_time_s must be within 0..{MAX_RISE_TIME_S} s, got {rise_time_s!r}")
    rise0 = float(rise_time_s)
    t_ref = float(np.median(rows.start_s)) if t_ref_s is None else float(t_ref_s)
    off0 = _coarse_offset_s(rows, edges, prior_offset_s, prior_half_width_s, rise0)
    n_seen, transition = _edges_seen(rows, edges, off0, rise0)
    if n_seen == 0:
        raise TooFewSamplesError("no LED row is lit part-way through its exposure: no edge to date")
    seen_t = rows.start_s[transition > 0]
    fit_rate = n_seen >= 2 and float(np.ptp(seen_t)) >= MIN_RATE_SPAN_S
    fit_line = rows.row_px is not None and n_seen >= 2 and \
        float(np.ptp(rows.row_px[transition > 0])) >= MIN_LINE_TIME_SPAN_PX
    row_ref = float(np.mean(rows.row_px[transition > 0])) if fit_line and rows.row_px is not None else 0.0
    used = rows.subset(_near_edges(rows, edges, off0, 4.0 * (rows.exposure_s + rise0)))
    dt = used.start_s - t_ref
    drow = used.row_px - row_ref if fit_line and used.row_px is not None else np.zeros_like(dt)
    scale = rows.exposure_s  # offsets and the ramp in exposures, the rate in ppm: well-conditioned steps
    # times relative to the first row (controller edges shifted by the coarse offset too), so that the
    # finite-difference steps (≥ 1e-11 s) stay far above the rounding of clocks that read 10⁶ s
    t_base = float(used.start_s[0])
    s_rel = used.start_s - t_base
    edges_rel = DriveEdges(edges.times_s - (t_base + off0), edges.rising, edges.u_s)

    def residuals(p: _F) -> _F:
        rate = p[1] * 1e-6 if fit_rate else 0.0
        shift = p[0] * scale + rate * dt + p[2] * 1e-9 * drow  # line time error in ns per row
        level = mean_levels(s_rel + shift, used.exposure_s, edges_rel, rise0)
        return _affine(level, used.brightness_dn)[2]

    upper = np.array([prior_half_width_s / scale + 1.0, 1e3, MAX_LINE_TIME_ERROR_NS])
    sol = least_squares(residuals, np.zeros(3), bounds=(-upper, upper), x_scale=np.array([0.1, 10.0, 1.0]),
                        diff_step=1e-4)
    return _result(used, edges, sol.x, sol.jac, sol.fun, off0=off0, scale=scale, t_ref=t_ref,
                   fit_rate=fit_rate, fit_line=fit_line, row_ref=row_ref, rise_s=rise0,
                   n_rows=rows.start_s.size)


def _result(used: RowSamples, edges: DriveEdges, x: _F, jac: _F, res: _F, *, off0: float, scale: float,
            t_ref: float, fit_rate: bool, fit_line: bool, row_ref: float, rise_s: float,
            n_rows: int) -> FiducialClock:
    """The fitted clock with its covariance (Jacobian, residual variance; b_off and gain profiled out).

    The ramp is a model: a real rise (first order, or an LED driver's delay curve) of that rise time has
    its centre of light anywhere within the ramp, a rectangular ± rise/2 about the ramp's centre: the
    shape term rise/(2√3) of the offset's uncertainty."""
    cols = [0, *([1] if fit_rate else []), *([2] if fit_line else [])]
    offset, rise = off0 + float(x[0]) * scale, rise_s
    drow = used.row_px - row_ref if fit_line and used.row_px is not None else 0.0
    n_seen, transition = _edges_seen(used, edges, offset + float(x[2]) * 1e-9 * drow, rise)
    if n_seen == 0 or int(transition.sum()) < MIN_TRANSITION_ROWS:
        raise TooFewSamplesError(
            f"{int(transition.sum())} LED row(s) lit part-way by {n_seen} edge(s) at the fitted offset; need "
            f"≥ {MIN_TRANSITION_ROWS}: record longer (the edges must cross the LED's rows during an "
            "exposure)")
    j = jac[:, cols]
    dof = max(res.size - len(cols) - 2, 1)
    sigma2 = float(res @ res) / dof
    normal = j.T @ j
    diag = np.diag(normal)
    if not np.all(np.isfinite(normal)) or np.any(diag <= 0) or \
            np.linalg.cond(normal / np.sqrt(np.outer(diag, diag))) > 1e10:  # scale-free: the correlations
        raise TooFewSamplesError("the LED's rows do not determine the offset (flat fit): record longer")
    cov = np.linalg.inv(normal) * sigma2
    u_fit = math.sqrt(max(float(cov[0, 0]), 0.0)) * scale
    u_rate = math.sqrt(max(float(cov[1, 1]), 0.0)) * 1e-6 if fit_rate else 0.0
    u_line = math.sqrt(max(float(cov[-1, -1]), 0.0)) * 1e-9 if fit_line else 0.0
    u_shape = rise / (2.0 * math.sqrt(3.0))
    return FiducialClock(
        offset_s=offset, u_offset_s=math.sqrt(u_fit**2 + u_shape**2 + edges.u_s**2), u_fit_s=u_fit,
        rate=float(x[1]) * 1e-6 if fit_rate else 0.0, u_rate=u_rate, rate_fitted=fit_rate, t_ref_s=t_ref,
        rise_time_s=rise, n_rows=n_rows, n_transition_rows=int(transition.sum()), n_edges_seen=n_seen,
        residual_dn=math.sqrt(sigma2), line_time_fitted=fit_line,
        line_time_error_s=float(x[2]) * 1e-9 if fit_line else 0.0, u_line_time_error_s=u_line,
        row_ref_px=row_ref)


def square_wave_edges(origin_s: float, frequency_hz: float, t_start_s: float, t_stop_s: float, *,
                      u_origin_s: float = 0.0) -> DriveEdges:
    """Edges of a square wave (high over the first half of each cycle) started at phase 0 at ``origin_s``
    (s, the controller's clock), within [t_start_s, t_stop_s]: rising at origin + k/f, falling half a
    period later (k ≥ 0). ``u_origin_s``: standard uncertainty of the origin, that of every edge."""
    if not (math.isfinite(frequency_hz) and frequency_hz > 0):
        raise InputArrayError(f"frequency_hz must be a finite number > 0, got {frequency_hz!r}")
    half = 0.5 / frequency_hz
    first = max(0, math.ceil((t_start_s - origin_s) / half))
    last = math.floor((t_stop_s - origin_s) / half)
    if last < first:
        raise InputArrayError(f"no edge of the {frequency_hz:g} Hz square wave started at {origin_s!r} s "
                              f"within [{t_start_s!r}, {t_stop_s!r}] s")
    k = np.arange(first, last + 1)
    return DriveEdges((origin_s + k * half).astype(np.float64), k % 2 == 0, u_origin_s)
