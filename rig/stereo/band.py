"""The band of a pair of unsynchronised cameras: where interleaving carries a measurement beyond fs/2.

Two cameras at ``fs`` each, the second offset by α of a frame (α = frac(offset·fs) ∈ [0, 1)), sample a
motion at interleaved instants: two samples per frame period, uniformly spaced only at α = ½.

- **One camera's Nyquist limit** fs/2: a tone at f and its alias fs − f fit one camera's samples exactly
  alike (with conjugate phase).
- **The pair's combined rate** 2·fs (Nyquist fs) when α ∉ {0, 1}: across the cameras the alias is off by
  a residual of 2·A·|sin πα| at the second camera (:mod:`rig.stereo.trajectory`), so the pair tells f from
  fs − f, the better the closer α is to ½ (:attr:`PairBand.alias_separation` = |sin πα|). At α = 0 (or a
  whole frame) the pair samples as one camera: combined rate fs, and nothing above fs/2 is identifiable.
- With the frequency *known*, each camera alone determines its projected complex amplitude except at
  f = k·fs/2, and the pair (α ≠ 0) except at f = k·fs. Identifying the frequency is what the interleaving
  adds: a measurement of an unknown vibration needs it, so :func:`fit_bin` refuses a window whose frequency
  the pair cannot identify (:class:`~rig.stereo.errors.AmbiguousFrequencyError`, or the scan finding
  another tone), with the reason.

:func:`fit_bin` fits X(t) = c + a·cos φ(t) + b·sin φ(t) to every observation of every camera at its own
instant, with the phase φ(t) of a reference (a sweep's exact phase law): the trajectory fit of
:mod:`rig.stereo.trajectory` on the *phase time* u = φ/(2π·f_ref), in which the reference is a steady tone
at f_ref (so a chirped window costs no model error), either as a free 3-D ellipse or along a given line
(a 1-D exciter; there the pair's interleaving also carries the amplitude through f = fs/2). The frequency
is then tested against its aliases k·fs ± f up to the pair's combined Nyquist limit with the Δχ² > 25
rule of :func:`~rig.stereo.trajectory.fit_sine_trajectory` (which raises
:class:`~rig.stereo.errors.AmbiguousFrequencyError` there; here the bin is refused with the reason).

Units: s, Hz, rad, px; lengths in the projection matrices' unit (mm).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rig.stereo._arrays import FloatArray
from rig.stereo.errors import InputArrayError, TooFewSamplesError
from rig.stereo.normalize import Camera
from rig.stereo.trajectory import CHI2_DISTINCT, SineBasis, _check, _linearised_scan, fit_trajectory

#: |sin πα| below this: the cameras' instants coincide to within 1 % of a frame (α < 0.0032 or > 0.9968);
#: the pair is then treated as one camera (combined rate fs): the benchmark's alias test fails below
#: α ≈ 0.002–0.005 at σ = 0.1 px, 3 px amplitude, 10 s (rig/stereo/trajectory.py).
MIN_ALIAS_SEPARATION = 0.01


@dataclass(frozen=True)
class PairBand:
    """The sampling of a camera pair: ``fs_hz`` per camera, ``alpha`` ∈ [0, 1) (frames), and what follows.

    ``single_nyquist_hz`` = fs/2; ``combined_rate_hz`` = 2·fs (fs when the instants coincide);
    ``combined_nyquist_hz`` its half; ``alias_separation`` = |sin πα| ∈ [0, 1]; ``degenerate``: the
    instants coincide (separation < :data:`MIN_ALIAS_SEPARATION`), nothing above fs/2 is identifiable.
    """

    fs_hz: float
    alpha: float

    @property
    def single_nyquist_hz(self) -> float:
        return 0.5 * self.fs_hz

    @property
    def alias_separation(self) -> float:
        return float(abs(np.sin(np.pi * self.alpha)))

    @property
    def degenerate(self) -> bool:
        return self.alias_separation < MIN_ALIAS_SEPARATION

    @property
    def combined_rate_hz(self) -> float:
        return self.fs_hz if self.degenerate else 2.0 * self.fs_hz

    @property
    def combined_nyquist_hz(self) -> float:
        return 0.5 * self.combined_rate_hz

    def degenerate_reason(self) -> str:
        """Why the pair cannot go beyond fs/2 ("" when it can)."""
        if not self.degenerate:
            return ""
        return (f"the cameras' instants coincide (offset {self.alpha:.4f} frame, |sin πα| = "
                f"{self.alias_separation:.4f} < {MIN_ALIAS_SEPARATION:g}): a tone above "
                f"{self.single_nyquist_hz:g} Hz and its alias fit both cameras alike")


def pair_band(fs_hz: float, offset_s: float) -> PairBand:
    """The :class:`PairBand` of cameras at ``fs_hz`` whose instants differ by ``offset_s`` (any sign)."""
    if not (np.isfinite(fs_hz) and fs_hz > 0):
        raise InputArrayError(f"fs_hz must be > 0, got {fs_hz!r}")
    if not np.isfinite(offset_s):
        raise InputArrayError(f"offset_s must be finite, got {offset_s!r}")
    return PairBand(float(fs_hz), _frame_fraction(offset_s * fs_hz))


def _frame_fraction(frames: float) -> float:
    """frames mod 1 in [0, 1) (np.mod rounds a tiny negative up to 1.0)."""
    a = float(np.mod(frames, 1.0))
    return 0.0 if a >= 1.0 else a


def instants_alpha(t_a_s: object, t_b_s: object, fs_hz: float) -> float:
    """Where camera B's instants fall between camera A's, in frames ∈ [0, 1): the circular mean of
    frac((t_b − t_a[0])·fs) (one clock; rolling-shutter row times included, so it is the offset the
    motion of that marker actually sees)."""
    ta, tb = np.asarray(t_a_s, float), np.asarray(t_b_s, float)
    if ta.size < 1 or tb.size < 1 or not (np.isfinite(fs_hz) and fs_hz > 0):
        raise InputArrayError("instants_alpha needs instants of both cameras and fs_hz > 0")
    z = np.mean(np.exp(2j * np.pi * (tb - ta[0]) * fs_hz))
    return _frame_fraction(np.angle(z) / (2 * np.pi))


@dataclass(frozen=True)
class BinFit:
    """One window's interleaved fit: ``amplitude`` along ``axis`` (√((a·n)² + (b·n)²)), its standard
    uncertainty ``u_amplitude`` (fit covariance, residual-scaled), ``phase_rad`` of the motion against the
    reference (x = A·sin(φ + phase)), the reprojection RMS (px), the number of observations, the alias
    test's Δχ² (``alias_dchi2``: how much worse the best alias fits, in units of the residual variance; inf
    with no alias in range, NaN when not tested), why the bin is refused (``refused``, "" if not), and the
    fitted motion's cosine and sine 3-vectors ``a``, ``b`` (X = c + a·cos φ + b·sin φ)."""

    amplitude: float
    u_amplitude: float
    phase_rad: float
    rms_px: float
    n_observations: int
    alias_dchi2: float
    refused: str
    a: FloatArray
    b: FloatArray


def _phase_times(phase_rad: Sequence[object], f_ref_hz: float) -> list[FloatArray]:
    out = []
    for i, p in enumerate(phase_rad):
        u = np.asarray(p, float) / (2 * np.pi * f_ref_hz)
        if u.ndim != 1 or u.size < 2 or not np.all(np.diff(u) > 0):
            raise InputArrayError(f"phase_rad[{i}] must increase strictly (a rising phase), got {u.size} "
                                  "values")
        out.append(u)
    return out


@dataclass(frozen=True)
class _Window:
    """One window's data: per camera the projection matrix, phase times u (s) and pixels (N, 2); the
    reference time ``t_ref`` (s) and angular frequency ``w`` (rad/s) of the sinusoid on the phase time."""

    Ps: Sequence[FloatArray]
    us: Sequence[FloatArray]
    uvs: Sequence[FloatArray]
    t_ref: float
    w: float

    def cos_sin(self, u: FloatArray) -> tuple[FloatArray, FloatArray]:
        return np.cos(self.w * (u - self.t_ref)), np.sin(self.w * (u - self.t_ref))


def _jacobian(P: FloatArray, X: FloatArray) -> FloatArray:
    """(N, 2, 3) derivative of the projection of points ``X`` (N, 3) by ``P``."""
    x = np.column_stack([X, np.ones(len(X))]) @ P.T
    depth = x[:, 2, None, None]
    out: FloatArray = (P[None, :2, :3] - (x[:, :2, None] / depth) * P[None, None, 2, :3]) / depth
    return out


def _project(P: FloatArray, X: FloatArray) -> FloatArray:
    x = np.column_stack([X, np.ones(len(X))]) @ P.T
    out: FloatArray = x[:, :2] / x[:, 2:3]
    return out


def _line_rows(win: _Window, p: FloatArray, n: FloatArray) -> tuple[FloatArray, FloatArray, list[FloatArray]]:
    """Jacobian (2N, 5), residuals (2N,) and per-camera residuals (N, 2) of X = c + n·(a cos + b sin) at
    p = (c, a, b)."""
    rows, res, per_cam = [], [], []
    for P, u, uv in zip(win.Ps, win.us, win.uvs, strict=True):
        cs, sn = win.cos_sin(u)
        X = p[:3][None, :] + np.outer(p[3] * cs + p[4] * sn, n)
        J = _jacobian(P, X)  # (N, 2, 3)
        Jn = J @ n  # (N, 2)
        rows.append(np.concatenate([J, (Jn * cs[:, None])[..., None], (Jn * sn[:, None])[..., None]], axis=2)
                    .reshape(-1, 5))
        r = uv - _project(P, X)
        per_cam.append(r)
        res.append(r.ravel())
    return np.vstack(rows), np.concatenate(res), per_cam


def _fit_line(win: _Window, n: FloatArray, X0: FloatArray) -> tuple[FloatArray, FloatArray, list[FloatArray]]:
    """Gauss–Newton for a motion along the line ``n`` through ``X0``: (p = (c, a, b), Jacobian, residuals)."""
    p = np.concatenate([X0, [0.0, 0.0]])
    for _ in range(10):
        A, r, _ = _line_rows(win, p, n)
        step = np.linalg.lstsq(A, r, rcond=None)[0]
        p = p + step
        if np.max(np.abs(step)) < 1e-10 * (1.0 + np.max(np.abs(p))):
            break
    A, _, per_cam = _line_rows(win, p, n)
    return p, A, per_cam


def _covariance(A: FloatArray, residuals: Sequence[FloatArray]) -> FloatArray:
    dof = A.shape[0] - A.shape[1]
    s2 = float(sum(np.sum(r**2) for r in residuals)) / max(dof, 1)
    out: FloatArray = s2 * np.linalg.pinv(A.T @ A)
    return out


def _free_jacobian(win: _Window, p: FloatArray) -> FloatArray:
    """(2N, 9) Jacobian of the free model at p = (c, a, b), linearised at each observation's position."""
    c, a, b = p[:3], p[3:6], p[6:9]
    rows = []
    for P, u in zip(win.Ps, win.us, strict=True):
        cs, sn = win.cos_sin(u)
        J = _jacobian(P, c[None, :] + np.outer(cs, a) + np.outer(sn, b))
        basis = np.column_stack([np.ones_like(cs), cs, sn])  # (N, 3)
        rows.append(np.einsum("ni,nkj->nkij", basis, J).reshape(-1, 9))
    return np.vstack(rows)


def fit_bin(
    cameras: Sequence[Camera],
    t_s: Sequence[object],
    uv_px: Sequence[object],
    phase_rad: Sequence[object],
    axis: object,
    *,
    f_ref_hz: float,
    direction: object | None = None,
    identify: PairBand | None = None,
) -> BinFit:
    """Interleaved fit of one window (see the module docstring).

    Per camera: ``t_s`` instants (one clock, increasing; only checked), ``uv_px`` (N, 2) undistorted pixels,
    ``phase_rad`` the reference's exact phase at each instant. ``axis``: the direction the amplitude is
    measured along (normalised here). ``f_ref_hz``: the reference's mean frequency over the window.
    ``direction``: None fits a free 3-D ellipse (c, a, b: 9 unknowns; each camera must
    then determine its own projected complex amplitude, impossible near f = k·fs/2); a 3-vector fits a
    motion along that line (c and two amplitudes: 5 unknowns), where the cameras' interleaved instants
    make up each other's missing quadrature near fs/2 — the pair's combined rate. ``identify``: the pair's
    sampling; the reference's aliases up to its combined Nyquist limit (fs; fs/2 when the instants
    coincide, where any motion must be assumed band-limited to one camera's Nyquist) are tested against
    it (:func:`_identify`); None skips the test (the frequency taken as known).
    Raises TooFewSamplesError / InputArrayError for unusable input; an unidentifiable frequency is not an
    error but a refused :class:`BinFit` with the amplitude still given (at the known frequency).
    """
    ax = _unit(axis, "axis")
    if not (np.isfinite(f_ref_hz) and f_ref_hz > 0):
        raise InputArrayError(f"f_ref_hz must be > 0, got {f_ref_hz!r}")
    us = _phase_times(phase_rad, f_ref_hz)
    Ps, ts, uvs = _check(cameras, t_s, uv_px)
    if any(u.size != t.size for u, t in zip(us, ts, strict=True)):
        raise InputArrayError("give one phase per observation of each camera")
    n_obs = sum(t.size for t in ts)
    if 2 * n_obs < 3 * 9:
        raise TooFewSamplesError(f"{n_obs} observations cannot determine a 3-D sinusoid")
    t_ref = 0.5 * (min(float(u[0]) for u in us) + max(float(u[-1]) for u in us))
    win = _Window(Ps, us, uvs, t_ref, 2 * np.pi * f_ref_hz)
    traj = fit_trajectory(Ps, us, uvs, SineBasis(f_ref_hz, t_ref, 1, False))
    if direction is None:
        p = traj.coefficients.ravel()
        residuals = traj.residuals_px
        cov = _covariance(_free_jacobian(win, p), residuals)
        g_a, g_b = np.zeros(9), np.zeros(9)
        g_a[3:6], g_b[6:9] = ax, ax
        vec_a, vec_b = p[3:6], p[6:9]
    else:
        n = _unit(direction, "direction")
        p, A, residuals = _fit_line(win, n, traj.coefficients[0])
        cov = _covariance(A, residuals)
        g_a, g_b = np.zeros(5), np.zeros(5)
        g_a[3], g_b[4] = float(n @ ax), float(n @ ax)
        vec_a, vec_b = p[3] * n, p[4] * n
    pa, pb = float(g_a @ p), float(g_b @ p)  # x along the axis = pa·cos φ + pb·sin φ
    amp = float(np.hypot(pa, pb))
    g = (pa * g_a + pb * g_b) / amp if amp > 0 else g_a
    u_amp = float(np.sqrt(max(float(g @ cov @ g), 0.0)))
    rms = float(np.sqrt(np.mean(np.concatenate([r.ravel() for r in residuals]) ** 2)))
    dchi2, refused = float("nan"), ""
    if identify is not None:
        dchi2, refused = _identify(win, f_ref_hz, identify.fs_hz, identify.combined_nyquist_hz)
        if identify.degenerate and f_ref_hz > identify.single_nyquist_hz:
            refused = identify.degenerate_reason()
    # the fit's sinusoid runs on φ − w·t_ref (conditioning): back to the reference's own phase φ
    phase = float(np.angle(np.exp(1j * (np.arctan2(pa, pb) - win.w * t_ref))))
    return BinFit(amp, u_amp, phase, rms, n_obs, dchi2, refused, vec_a, vec_b)


def _unit(v: object, name: str) -> FloatArray:
    n = np.asarray(v, float)
    if n.shape != (3,) or not np.all(np.isfinite(n)) or not np.linalg.norm(n) > 0:
        raise InputArrayError(f"{name} must be a finite non-zero 3-vector, got {v!r}")
    out: FloatArray = n / np.linalg.norm(n)
    return out


def _identify(win: _Window, f_ref_hz: float, fs_hz: float, up_to_hz: float) -> tuple[float, str]:
    """(Δχ² of the best alias, "") or (Δχ², why not): the reference's aliases k·fs ± f inside
    (0, ``up_to_hz``] and more than one resolution cell (1/duration) from it — as the frequency search
    tells candidates apart — are scanned (±½ cell, linearised cost of a free 3-D sinusoid on the phase
    time, :func:`rig.stereo.trajectory._linearised_scan`) and compared with the cost at ``f_ref_hz``; an
    alias within Δχ² < 25 (the frequency search's own threshold) of it makes the bin unidentifiable."""
    us = win.us
    duration = max(float(u[-1]) for u in us) - min(float(u[0]) for u in us)
    aliases = sorted({a for k in range(1, int(up_to_hz // fs_hz) + 2) for a in (k * fs_hz - f_ref_hz,
                                                                            k * fs_hz + f_ref_hz)
                      if 2.0 / duration < a <= up_to_hz and abs(a - f_ref_hz) > 1.0 / duration})
    if not aliases:
        return float("inf"), ""
    cell = 1.0 / duration
    grid = np.concatenate([[f_ref_hz], *[a + cell * np.linspace(-0.5, 0.5, 21) for a in aliases]])
    cost = _linearised_scan(win.Ps, us, win.uvs, grid, t_ref=win.t_ref)
    n_obs = sum(u.size for u in us)
    s2 = max(float(cost[0]), 1e-300) / max(2 * n_obs - 10, 1)
    k = int(np.argmin(cost[1:])) + 1
    dchi2 = float((cost[k] - cost[0]) / s2)
    if dchi2 < CHI2_DISTINCT:
        return dchi2, (f"frequency not identifiable: the alias {grid[k]:.3f} Hz of {f_ref_hz:.3f} Hz fits "
                       f"within Δχ² = {dchi2:.1f} < {CHI2_DISTINCT:g} (the cameras' instants do not separate "
                       "them)")
    return dchi2, ""


__all__ = ["MIN_ALIAS_SEPARATION", "BinFit", "PairBand", "fit_bin", "instants_alpha", "pair_band"]
