"""Continuous-time 3D trajectories fitted to all 2D observations of all cameras at their exact times.

Nothing is interpolated: every observation (camera c, row-corrected instant t_i, pixel u_i, v_i) constrains
X(t_i) through that camera's projection matrix, and X(t) = Σ_j φ_j(t)·C_j is linear in the coefficients C
(n_basis × 3). The fit minimises the reprojection error Σ‖uv_i − project_c(X(t_i))‖² by Gauss–Newton on C
(the per-observation Jacobian is (p₁ − u·p₃)/w; sparse for splines), started from the linear (DLT-style)
solution. Two unsynchronised cameras sample the motion at interleaved instants, so together they sample it
up to twice as often as one.

Bases:
- :class:`SplineBasis`: cubic B-spline with a knot spacing (default 0.75 of a frame interval, i.e. finer
  than one camera's frame interval) and a small second-difference penalty (P-spline) that fills gaps. Each
  control point has 3 unknowns and each observation gives 2 equations, so with two cameras at fs the knot
  spacing must stay ≥ 3/(4·fs) — a free 3D curve cannot go beyond that. On the twin (60 fps, cameras
  0.27 frame apart, σ = 0.1 px, 3 seeds) the defaults (0.75 frame, penalty 1e-4) give amplitude errors of
  −0.07 % at 5 Hz, −0.02 % at 15 Hz and −0.7 % at 25 Hz (model bias that depends on where the samples fall
  between the knots; penalty 1e-3: −2.1 %, knots at 0.9 frame: −1.3 %). For a steady oscillation the
  sinusoidal model below has no such bias.
- :class:`SineBasis`: a local sinusoidal model X(t) = c + Σ_k a_k cos kωt + b_k sin kωt (+ optional linear
  drift). With the frequency known, each camera on its own determines its projected complex amplitude
  unless f is a multiple of fs/2, so the amplitude is recovered even above one camera's Nyquist limit.
  :func:`fit_sine_trajectory` also **estimates** the frequency by scanning the reprojection cost up to the
  pair's combined Nyquist limit (fs for two cameras): above fs/2 this is where the interleaving matters.

Beyond one camera's Nyquist limit (fs/2), where it holds and where it fails: a tone at f and its alias
fs − f fit one camera's samples identically; across the two cameras they differ only through the cameras'
time offset α (fraction of a frame, mod 1): at the second camera the alias is off by a residual of about
2·A_px·sin(πα) (A_px the image amplitude). The frequency search rejects the alias when its cost exceeds the
best by Δχ² > 25; the separation grows as N·(A_px/σ)²·sin²(πα) (N frames; measured 0.8–1.8 times that
for the benchmark geometry), so it **fails as α → 0 (or 1)**: with identical instants the alias is exactly
as good and AmbiguousFrequencyError is raised rather than a wrong frequency returned. In
``benchmarks/accuracy.py`` (60 fps, 40 Hz, 10 s, A ≈ 3 px, σ = 0.1 px) the alias is rejected from
α ≈ 0.005 frame (80 µs) on and the amplitude is within 0.5 % for α = 0.005 … 0.5; α ≤ 0.002 is ambiguous.
Lower SNR or shorter records raise that limit (α_min ∝ σ/(A_px·√N)). With the frequency *known*
(``frequency_hz=``), the amplitude is recovered at any α except f = k·fs/2, since each camera alone then
determines its projected complex amplitude. The B-spline model cannot go beyond the knot limit above.

Units: times s (all cameras on one clock), pixels, mm (whatever unit the projection matrices use).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TypeAlias

import numpy as np
from scipy import optimize, sparse
from scipy.interpolate import BSpline
from scipy.linalg import LinAlgError, solveh_banded
from scipy.sparse.linalg import spsolve

from rig.stereo._arrays import FloatArray, IntArray
from rig.stereo._series import as_times
from rig.stereo.errors import AmbiguousFrequencyError, InputArrayError, TimingError, TooFewSamplesError
from rig.stereo.normalize import Camera, projection_matrix

CHI2_DISTINCT = 25.0


@dataclass(frozen=True)
class SplineBasis:
    """Cubic B-spline basis on [t_min_s, t_max_s] with uniform knots every ``knot_spacing_s``."""

    t_min_s: float
    t_max_s: float
    knot_spacing_s: float
    penalty: float = 1e-4  # weight of the second-difference penalty relative to the pixel-scaled data rows

    def knots(self) -> FloatArray:
        n = max(1, int(np.ceil((self.t_max_s - self.t_min_s) / self.knot_spacing_s)))
        inner = np.linspace(self.t_min_s, self.t_max_s, n + 1)
        h = inner[1] - inner[0]
        return np.concatenate([inner[0] - h * np.arange(3, 0, -1), inner, inner[-1] + h * np.arange(1, 4)])

    @property
    def size(self) -> int:
        return self.knots().size - 4

    def design(self, t_s: FloatArray) -> sparse.csr_matrix:
        t = np.clip(np.asarray(t_s, float), self.t_min_s, self.t_max_s)
        return BSpline.design_matrix(t, self.knots(), 3).tocsr()

    def regulariser(self) -> sparse.csr_matrix | None:
        n = self.size
        D = sparse.diags([np.ones(n - 2), -2 * np.ones(n - 2), np.ones(n - 2)], [0, 1, 2], shape=(n - 2, n))
        return (np.sqrt(self.penalty) * D).tocsr()


@dataclass(frozen=True)
class SineBasis:
    """c + Σ_{k=1..n_harmonics} a_k cos(k·φ(t)) + b_k sin(k·φ(t)) (+ d·(t − t_ref) if ``drift``), with the
    phase φ = 2π(f·τ + ½·rate·τ²), τ = t − t_ref: a steady tone, or a linear chirp of ``rate_hz_s``."""

    frequency_hz: float
    t_ref_s: float = 0.0
    n_harmonics: int = 1
    drift: bool = False
    rate_hz_s: float = 0.0

    @property
    def size(self) -> int:
        return 1 + 2 * self.n_harmonics + int(self.drift)

    def design(self, t_s: FloatArray) -> sparse.csr_matrix:
        tc = np.asarray(t_s, float) - self.t_ref_s
        cols = [np.ones_like(tc)]
        phase = 2 * np.pi * (self.frequency_hz * tc + 0.5 * self.rate_hz_s * tc**2)
        for k in range(1, self.n_harmonics + 1):
            cols += [np.cos(k * phase), np.sin(k * phase)]
        if self.drift:
            cols.append(tc)
        return sparse.csr_matrix(np.column_stack(cols))

    def regulariser(self) -> None:
        return None


Basis = SplineBasis | SineBasis
#: A Gauss–Newton design: dense for a few sine columns, sparse for splines.
Design: TypeAlias = FloatArray | sparse.csr_matrix


@dataclass(frozen=True)
class Trajectory:
    """A fitted trajectory: ``coefficients`` (n_basis, 3) of ``basis``; residuals per camera (N_c, 2) px."""

    basis: Basis
    coefficients: FloatArray
    residuals_px: list[FloatArray]
    rms_px: float

    def position(self, t_s: object) -> FloatArray:
        """X(t) (N, 3) at ``t_s`` (s)."""
        return np.asarray(self.basis.design(np.atleast_1d(np.asarray(t_s, float))) @ self.coefficients)

    @property
    def amplitude_vectors(self) -> tuple[FloatArray, FloatArray]:
        """(a, b) 3-vectors of the fundamental of a SineBasis: X = c + a cos ωt + b sin ωt + …"""
        if not isinstance(self.basis, SineBasis):
            raise InputArrayError("amplitude_vectors needs a SineBasis trajectory")
        return self.coefficients[1], self.coefficients[2]

    @property
    def amplitude(self) -> float:
        """Major semi-axis of the fundamental's motion ellipse (the amplitude of a 1-D oscillation)."""
        a, b = self.amplitude_vectors
        return float(np.linalg.svd(np.column_stack([a, b]), compute_uv=False)[0])

    @property
    def direction(self) -> FloatArray:
        """Unit vector of the major axis of the fundamental's motion ellipse."""
        a, b = self.amplitude_vectors
        u, _, _ = np.linalg.svd(np.column_stack([a, b]))
        return u[:, 0]


def _check(
    cameras: Sequence[Camera], t_list: Sequence[object], uv_list: Sequence[object]
) -> tuple[list[FloatArray], list[FloatArray], list[FloatArray]]:
    """Per camera: projection matrix, times (strictly increasing) and (N, 2) pixels, validated."""
    if not (len(cameras) == len(t_list) == len(uv_list)) or len(cameras) < 1:
        raise InputArrayError("give one time array and one uv array per camera")
    Ps, ts, uvs = [], [], []
    for i, (cam, t, uv) in enumerate(zip(cameras, t_list, uv_list, strict=True)):
        Ps.append(projection_matrix(cam))
        tt = as_times(t, f"t_s[{i}]", min_count=2)
        uu = np.asarray(uv, float)
        if uu.shape != (tt.size, 2) or not np.isfinite(uu).all():
            raise InputArrayError(f"uv_px[{i}] must be finite with shape ({tt.size}, 2), got {uu.shape}")
        ts.append(tt)
        uvs.append(uu)
    return Ps, ts, uvs


def _jacobian(P: FloatArray, design: sparse.csr_matrix, uv: FloatArray, C: FloatArray | None,
              ) -> list[tuple[FloatArray, FloatArray]]:
    """Per image coordinate k (u, v) of one camera: the Jacobian of its equations in X, (N, 3), and their
    residuals, (N,), at coefficients C (None: the linear DLT-style equations)."""
    if C is None:
        uhat, w = uv, np.ones(len(uv))
    else:
        proj = np.column_stack([np.asarray(design @ C), np.ones(len(uv))]) @ P.T
        w = proj[:, 2]
        uhat = proj[:, :2] / w[:, None]
    out = []
    for k in range(2):
        g = (P[k, :3][None, :] - uhat[:, k : k + 1] * P[2, :3][None, :]) / w[:, None]  # (N, 3)
        out.append((g, -(P[k, 3] - uv[:, k] * P[2, 3]) if C is None else uv[:, k] - uhat[:, k]))
    return out


def _system(
    Ps: Sequence[FloatArray], ts: Sequence[FloatArray], uvs: Sequence[FloatArray], basis: Basis,
    C: FloatArray | None, *, designs: Sequence[sparse.csr_matrix] | None = None,
) -> tuple[Design, FloatArray]:
    """Gauss–Newton system (A, r) in vec(C) (row-major n_basis × 3) at coefficients C (None: linear DLT);
    ``designs``: each camera's ``basis.design`` at its times ``ts`` when already computed (they do not
    change over the iterations)."""
    designs = designs if designs is not None else [basis.design(t) for t in ts]
    rows, rhs = [], []
    for P, design, uv in zip(Ps, designs, uvs, strict=True):
        Phi = design.tocoo()
        n = len(uv)
        dense = isinstance(basis, SineBasis)  # few dense columns: skip the sparse bookkeeping
        for g, r in _jacobian(P, design, uv, C):
            rhs.append(r)
            if dense:
                phi = Phi.toarray()
                rows.append((phi[:, :, None] * g[:, None, :]).reshape(n, -1))
                continue
            data = (Phi.data[:, None] * g[Phi.row]).ravel()
            r_idx = np.repeat(Phi.row, 3)
            c_idx = (Phi.col[:, None] * 3 + np.arange(3)[None, :]).ravel()
            rows.append(sparse.csr_matrix((data, (r_idx, c_idx)), shape=(n, 3 * basis.size)))
    if isinstance(basis, SineBasis):
        return np.vstack(rows), np.concatenate(rhs)
    return sparse.vstack(rows).tocsr(), np.concatenate(rhs)


def _solve(
    A: Design, r: FloatArray, basis: Basis, scale: float, c_now: FloatArray | None = None
) -> FloatArray:
    """Least-squares step; the penalty acts on the updated coefficients c_now + step (P-spline)."""
    Areg = basis.regulariser()
    if Areg is not None and not isinstance(A, np.ndarray):  # penalty rows added to the normal equations
        R3 = (sparse.kron(Areg, sparse.identity(3)) * scale).tocsr()
        return _solve_normal(A, r, R3, np.zeros(R3.shape[0]) if c_now is None else -(R3 @ c_now))
    if Areg is not None:
        R3 = (sparse.kron(Areg, sparse.identity(3)) * scale).tocsr()
        A = sparse.vstack([A, R3]).tocsr()
        r = np.concatenate([r, np.zeros(R3.shape[0]) if c_now is None else -(R3 @ c_now)])
    if isinstance(A, np.ndarray):  # a few dense columns: normal equations, scaled by the column norms
        d = 1.0 / np.maximum(np.linalg.norm(A, axis=0), 1e-300)
        As = A * d
        step: FloatArray = d * np.linalg.solve(As.T @ As, As.T @ r)
        return step
    return _solve_normal(A, r)


def _solve_normal(A: sparse.csr_matrix, r: FloatArray, R: sparse.csr_matrix | None = None,
                  r_reg: FloatArray | None = None) -> FloatArray:
    """Least squares of the rows (A, r) and the penalty rows (R, r_reg) by the normal equations: by banded
    Cholesky when they are narrow (a B-spline design: 4 knots × 3 coordinates either side of the diagonal),
    else (or not positive definite) by sparse LU."""
    AT = sparse.csr_matrix(A.T)
    N, rhs = sparse.csr_matrix(AT @ A), AT @ r
    if R is not None and r_reg is not None:
        N, rhs = sparse.csr_matrix(N + R.T @ R), rhs + R.T @ r_reg
    N.sum_duplicates()  # a no-op on the canonical products; the bands below need one entry per element
    row = np.repeat(np.arange(N.shape[0]), np.diff(N.indptr))
    col = N.indices
    upper = row <= col
    width = int(np.max(col - row)) if N.nnz else 0
    if N.shape[0] > 4 * (width + 1):
        bands = np.zeros((width + 1, N.shape[0]))
        bands[width + row[upper] - col[upper], col[upper]] = N.data[upper]
        try:
            return np.asarray(solveh_banded(bands, rhs, check_finite=False))
        except LinAlgError:
            pass
    return np.asarray(spsolve(N.tocsc(), rhs))


def _row_scale(A: Design) -> float:
    """RMS row norm of the design (sets the penalty relative to the data)."""
    # a sparse design's Frobenius norm from its stored values (sparse.linalg.norm copies the matrix twice)
    if isinstance(A, np.ndarray):
        fro = float(np.linalg.norm(A))
    else:
        A = sparse.csr_matrix(A)
        A.sum_duplicates()  # in place; a no-op on the canonical matrices _system builds
        fro = float(np.sqrt(np.sum(np.square(A.data))))
    return float(fro / np.sqrt(max(A.shape[0], 1)))


def fit_trajectory(
    cameras: Sequence[Camera],
    t_s: Sequence[object],
    uv_px: Sequence[object],
    basis: Basis,
    *,
    iterations: int = 8,
) -> Trajectory:
    """Fit ``basis`` coefficients to all observations (per camera: row-corrected times, (N, 2) pixels).

    ``cameras``: projection matrices or objects with ``.P`` (lens distortion already removed from uv).
    Raises TooFewSamplesError when there are fewer equations than unknowns.
    """
    Ps, ts, uvs = _check(cameras, t_s, uv_px)
    n_eq = 2 * sum(len(t) for t in ts)
    if n_eq < 3 * basis.size and basis.regulariser() is None:
        raise TooFewSamplesError(
            f"{n_eq} equations cannot determine {3 * basis.size} trajectory coefficients"
        )
    designs = [basis.design(t) for t in ts]
    spline_rows = [_spline_rows(d) for d in designs] if isinstance(basis, SplineBasis) else []
    # any cubic B-spline (≥ 4 basis functions: ≥ 12 columns, the band's width) by its band sums: for a short
    # track too (a still calibration position, ≈ 8 frames) the sparse design's steps cost ≈ 20× as much
    if isinstance(basis, SplineBasis) and all(r is not None for r in spline_rows):
        C = _fit_banded(Ps, [r for r in spline_rows if r is not None], uvs, basis, iterations=iterations)
    else:
        C = _fit_general(Ps, ts, designs, uvs, basis, iterations=iterations)
    res = []
    for P, design, uv in zip(Ps, designs, uvs, strict=True):
        Xh = np.column_stack([np.asarray(design @ C), np.ones(len(uv))]) @ P.T
        res.append(uv - Xh[:, :2] / Xh[:, 2:3])
    allr = np.concatenate(res)
    return Trajectory(basis, C, res, float(np.sqrt(np.mean(allr**2))))


def _fit_general(Ps: Sequence[FloatArray], ts: Sequence[FloatArray], designs: Sequence[sparse.csr_matrix],
                 uvs: Sequence[FloatArray], basis: Basis, *, iterations: int) -> FloatArray:
    """Gauss–Newton on the coefficients (n_basis × 3) with the design assembled (sparse or dense)."""
    A, r = _system(Ps, ts, uvs, basis, None, designs=designs)
    scale = _row_scale(A)
    C = _solve(A, r, basis, scale).reshape(-1, 3)
    for it in range(iterations):
        A, r = _system(Ps, ts, uvs, basis, C, designs=designs)
        if it == 0:  # penalty weight relative to the pixel-scaled equations
            scale = _row_scale(A)
        dC = _solve(A, r, basis, scale, C.ravel()).reshape(-1, 3)
        C = C + dC
        if np.max(np.abs(dC)) < 1e-10 * (1.0 + np.max(np.abs(C))):
            break
    return C


_BAND = 11  # upper bandwidth of a cubic B-spline's normal equations in vec(C): 3 basis steps × 3 + 2
_UPPER_P, _UPPER_Q = np.triu_indices(12)  # the pairs p ≤ q of an equation's 12 non-zero coefficients


def _spline_rows(design: sparse.csr_matrix) -> tuple[FloatArray, IntArray] | None:
    """(values (N, 4), first basis index (N,)) of a cubic B-spline design whose every row holds 4
    consecutive basis functions (as ``BSpline.design_matrix`` gives), else None."""
    if not design.has_sorted_indices or not np.all(np.diff(design.indptr) == 4):
        return None
    cols = np.asarray(design.indices, dtype=np.int64).reshape(-1, 4)
    if not np.all(np.diff(cols, axis=1) == 1):
        return None
    return np.asarray(design.data, dtype=float).reshape(-1, 4), cols[:, 0]


# An equation's 12 coefficients are index 3p + k: basis function p (0–3) × coordinate k (0–2); the pairs
# P ≤ Q of them are the upper band of the normal equations. Per observation the two equations (u, v) share
# the basis values v_p, so their contribution to entry (3p + k, 3q + l) is v_p·v_q·G_kl with G = Σ_u,v g gᵀ.
_COEF_P, _COEF_K = np.divmod(np.arange(12), 3)
_PAIRS_10 = [(p, q) for p in range(4) for q in range(p, 4)]  # v_p·v_q, p ≤ q
_SYM_6 = [(k, m) for k in range(3) for m in range(k, 3)]  # G_kl, k ≤ l
_V_OF_PAIR = np.array([_PAIRS_10.index((min(a, b), max(a, b))) for a, b in
                       zip(_COEF_P[_UPPER_P], _COEF_P[_UPPER_Q], strict=True)])
_G_OF_PAIR = np.array([_SYM_6.index((min(a, b), max(a, b))) for a, b in
                       zip(_COEF_K[_UPPER_P], _COEF_K[_UPPER_Q], strict=True)])
_V_A, _V_B = np.array(_PAIRS_10).T
_G_A, _G_B = np.array(_SYM_6).T


@dataclass(frozen=True)
class _SplineData:
    """All cameras' observations of one spline fit, stacked: basis values (N, 4) and first basis index (N,)
    per observation, the camera's projection matrix per observation (N, 3, 4), pixels (N, 2), and the
    fixed parts of the band sums: each observation's 78 products v_p·v_q (N, 78), its flat positions in
    the band storage (N, 78) and in the right-hand side (N, 12)."""

    values: FloatArray
    first: IntArray
    P: FloatArray
    uv: FloatArray
    vv: FloatArray
    band_at: IntArray
    rhs_at: IntArray
    n_cols: int


def _spline_data(Ps: Sequence[FloatArray], rows: Sequence[tuple[FloatArray, IntArray]],
                 uvs: Sequence[FloatArray], n_cols: int) -> _SplineData:
    """Stack the cameras' observations and precompute what does not change over the iterations."""
    values = np.concatenate([r[0] for r in rows])
    first = np.concatenate([r[1] for r in rows])
    P = np.concatenate([np.broadcast_to(P, (len(uv), 3, 4)) for P, uv in zip(Ps, uvs, strict=True)])
    c0 = 3 * first[:, None]
    band_at = (_BAND + _UPPER_P - _UPPER_Q) * n_cols + c0 + _UPPER_Q[None, :]
    vv = (values[:, _V_A] * values[:, _V_B])[:, _V_OF_PAIR]
    return _SplineData(values, first, P, np.concatenate(uvs), vv, band_at, c0 + np.arange(12), n_cols)


def _spline_positions(data: _SplineData, C: FloatArray) -> FloatArray:
    """X(t) (N, 3) at every observation: Σ_p v_p·C[first + p]."""
    return np.asarray(np.einsum("np,npk->nk", data.values, C[data.first[:, None] + np.arange(4)]))


def _banded_normal(data: _SplineData, C: FloatArray | None) -> tuple[FloatArray, FloatArray, float]:
    """The normal equations AᵀA x = Aᵀr of the spline equations at C in upper band storage (``solveh_banded``:
    ``bands[_BAND + i − j, j] = N[i, j]``, i ≤ j), Aᵀr, and the RMS row norm of A (the penalty's scale):
    summed per observation from its basis values and the 3×3 G = Σ_u,v g gᵀ of its two equations
    (g = (p_k − û·p₃)/w, the Jacobian in X; at C None the linear DLT-style rows, w = 1), no matrix built."""
    P, uv = data.P, data.uv
    p3 = P[:, 2, :3]
    if C is None:
        uhat, w = uv, np.ones(len(uv))
        r = uv * P[:, 2, 3:4] - P[:, :2, 3]  # −(p_k4 − u_k·p_34)
    else:
        proj = np.einsum("nij,nj->ni", P[:, :, :3], _spline_positions(data, C)) + P[:, :, 3]
        w = proj[:, 2]
        uhat = proj[:, :2] / w[:, None]
        r = uv - uhat
    gu = (P[:, 0, :3] - uhat[:, :1] * p3) / w[:, None]
    gv = (P[:, 1, :3] - uhat[:, 1:] * p3) / w[:, None]
    G = gu[:, _G_A] * gu[:, _G_B] + gv[:, _G_A] * gv[:, _G_B]  # (N, 6)
    n_cols = data.n_cols
    bands = np.bincount(data.band_at.ravel(), (data.vv * G[:, _G_OF_PAIR]).ravel(),
                        minlength=(_BAND + 1) * n_cols)
    h = gu * r[:, :1] + gv * r[:, 1:]  # (N, 3): Σ_u,v g·r
    rhs = np.bincount(data.rhs_at.ravel(), (data.values[:, :, None] * h[:, None, :]).ravel(),
                      minlength=n_cols)
    sum_sq = float(np.sum(np.sum(data.values**2, axis=1) * (G[:, 0] + G[:, 3] + G[:, 5])))
    rms_row = float(np.sqrt(sum_sq / max(2 * len(uv), 1)))
    return np.asarray(bands, np.float64).reshape(_BAND + 1, n_cols), np.asarray(rhs, np.float64), rms_row


def _second_differences(C: FloatArray) -> FloatArray:
    """D·C: C[j] − 2·C[j+1] + C[j+2] for each coordinate, (n − 2, 3)."""
    return np.asarray(C[:-2] - 2.0 * C[1:-1] + C[2:])


def _penalty_gradient(C: FloatArray, weight: float) -> FloatArray:
    """−weight·DᵀD·C (n, 3): the penalty's right-hand side at C (weight = penalty·scale²)."""
    d = _second_differences(C)
    out = np.zeros_like(C)
    out[:-2] += d
    out[1:-1] -= 2.0 * d
    out[2:] += d
    return -weight * out


def _penalty_bands(weight: float, n_basis: int) -> FloatArray:
    """weight·(DᵀD ⊗ I₃) in the band storage of :func:`_banded_normal` (D the second differences on n_basis
    coefficients; a coefficient's coordinate k couples only to the same k, 3·offset columns away)."""
    bands = np.zeros((_BAND + 1, 3 * n_basis))
    stencil = (1.0, -2.0, 1.0)
    for a in range(3):
        for b in range(a, 3):  # row j of D touches coefficients j + a and j + b
            diag = np.zeros(n_basis)
            diag[b:b + n_basis - 2] = stencil[a] * stencil[b]
            bands[_BAND - 3 * (b - a)] += weight * np.repeat(diag, 3)
    return bands


def _solve_bands(bands: FloatArray, rhs: FloatArray) -> FloatArray:
    """N x = rhs for a symmetric banded N: banded Cholesky, or sparse LU when N is not positive definite."""
    try:
        return np.asarray(solveh_banded(bands, rhs, check_finite=False))
    except LinAlgError:
        n = bands.shape[1]
        upper = sparse.diags([bands[_BAND - d, d:] for d in range(_BAND + 1)], list(range(_BAND + 1)),
                             shape=(n, n))
        return np.asarray(spsolve(sparse.csc_matrix(upper + sparse.triu(upper, 1).T), rhs))


def _fit_banded(Ps: Sequence[FloatArray], rows: Sequence[tuple[FloatArray, IntArray]],
                uvs: Sequence[FloatArray], basis: SplineBasis, *, iterations: int) -> FloatArray:
    """:func:`_fit_general` for a cubic B-spline: the same steps (penalty on the updated coefficients, its
    weight from the design's RMS row norm), the normal equations summed in band form."""
    n_basis = basis.size
    data = _spline_data(Ps, rows, uvs, 3 * n_basis)
    bands, rhs, scale = _banded_normal(data, None)
    C = _solve_bands(bands + _penalty_bands(basis.penalty * scale**2, n_basis), rhs).reshape(-1, 3)
    for it in range(iterations):
        bands, rhs, rms_row = _banded_normal(data, C)
        if it == 0:  # penalty weight relative to the pixel-scaled equations
            weight = basis.penalty * rms_row**2
            penalty = _penalty_bands(weight, n_basis)
        dC = _solve_bands(bands + penalty, rhs + _penalty_gradient(C, weight).ravel()).reshape(-1, 3)
        C = C + dC
        if np.max(np.abs(dC)) < 1e-10 * (1.0 + np.max(np.abs(C))):
            break
    return C


def fit_spline_trajectory(
    cameras: Sequence[Camera],
    t_s: Sequence[object],
    uv_px: Sequence[object],
    *,
    knot_spacing_s: float | None = None,
    penalty: float = 1e-4,
) -> Trajectory:
    """Cubic B-spline trajectory through all observations; knots every ``knot_spacing_s`` (default 0.75 of
    the median frame interval of the first camera)."""
    ts = [as_times(t, f"t_s[{i}]") for i, t in enumerate(t_s)]
    if knot_spacing_s is None:
        knot_spacing_s = 0.75 * float(np.median(np.diff(ts[0])))
    t_min = min(t[0] for t in ts)
    t_max = max(t[-1] for t in ts)
    return fit_trajectory(cameras, ts, uv_px, SplineBasis(t_min, t_max, knot_spacing_s, penalty))


def _sine_cost(
    Ps: Sequence[FloatArray], ts: Sequence[FloatArray], uvs: Sequence[FloatArray], f: float, *, t_ref: float,
    n_harmonics: int, drift: bool, iterations: int,
) -> tuple[float, Trajectory]:
    """Sum of squared reprojection residuals (px²) of the sine model at ``f`` (Hz), and its trajectory."""
    traj = fit_trajectory(Ps, ts, uvs, SineBasis(f, t_ref, n_harmonics, drift), iterations=iterations)
    return float(sum(np.sum(r**2) for r in traj.residuals_px)), traj


def fit_sine_trajectory(
    cameras: Sequence[Camera],
    t_s: Sequence[object],
    uv_px: Sequence[object],
    *,
    frequency_hz: float | None = None,
    frequency_range_hz: tuple[float, float] | None = None,
    n_harmonics: int = 1,
    drift: bool = False,
) -> tuple[Trajectory, float]:
    """Local sinusoidal 3D trajectory; returns (trajectory, frequency_hz).

    ``frequency_hz`` None → scanned over ``frequency_range_hz`` (default 1.5/duration … number of cameras ×
    fs/2) on a grid of a quarter of the record's resolution, then refined. Raises AmbiguousFrequencyError when
    another frequency (typically the alias fs − f) fits within Δχ² < 25 of the best.
    """
    Ps, ts, uvs = _check(cameras, t_s, uv_px)
    t_all = np.concatenate(ts)
    t_ref = 0.5 * (t_all.min() + t_all.max())

    def cost_at(f: float, iterations: int) -> tuple[float, Trajectory]:
        return _sine_cost(
            Ps, ts, uvs, f, t_ref=t_ref, n_harmonics=n_harmonics, drift=drift, iterations=iterations
        )

    if frequency_hz is not None:
        traj = fit_trajectory(Ps, ts, uvs, SineBasis(float(frequency_hz), t_ref, n_harmonics, drift))
        return traj, float(frequency_hz)
    duration = float(np.ptp(t_all))
    fs = 1.0 / float(np.median(np.diff(ts[0])))
    lo, hi = frequency_range_hz or (1.5 / duration, 0.5 * fs * len(ts))
    if duration * lo < 1.0 and frequency_range_hz is None:
        raise TooFewSamplesError(f"record of {duration:.3g} s is too short for a frequency search")
    df = 0.25 / duration
    grid = np.arange(lo, hi, df)
    if grid.size < 3:
        raise TooFewSamplesError(f"frequency range {lo}…{hi} Hz holds fewer than 3 grid points")
    cost = _linearised_scan(Ps, ts, uvs, grid, t_ref=t_ref)
    is_min = np.r_[
        cost[0] < cost[1], (cost[1:-1] <= cost[:-2]) & (cost[1:-1] <= cost[2:]), cost[-1] < cost[-2]
    ]
    candidates = np.flatnonzero(is_min)
    candidates = candidates[np.argsort(cost[candidates])][:4]  # refine the best few basins exactly
    refined = []
    for j in candidates.tolist():
        r = optimize.minimize_scalar(
            lambda f: cost_at(f, 3)[0],
            bounds=(grid[max(j - 1, 0)], grid[min(j + 1, grid.size - 1)]),
            method="bounded",
            options={"xatol": 1e-7},
        )
        refined.append((float(r.fun), float(r.x)))
    refined.sort()
    best_cost, traj = cost_at(refined[0][1], 8)
    f_best = refined[0][1]
    n_par = 3 * traj.basis.size + 1
    dof = 2 * t_all.size - n_par
    if dof <= 0:
        raise TooFewSamplesError(f"{2 * t_all.size} equations cannot determine {n_par} parameters")
    s2 = best_cost / dof
    for c_j, f_j in refined[1:]:
        if abs(f_j - f_best) > 4 * df and (c_j - best_cost) / s2 < CHI2_DISTINCT:
            raise AmbiguousFrequencyError(
                f"frequencies {f_best:.4f} Hz and {f_j:.4f} Hz fit equally well (Δχ² = "
                f"{(c_j - best_cost) / s2:.1f}); the cameras' sampling instants do not separate the alias "
                "(time offset too close to 0 or a whole frame) — give frequency_hz or re-time the cameras"
            )
    if not np.isfinite(best_cost):
        raise TimingError("sine trajectory fit failed (non-finite cost)")
    return traj, f_best


def _linearised_scan(
    Ps: Sequence[FloatArray], ts: Sequence[FloatArray], uvs: Sequence[FloatArray], grid: FloatArray, *,
    t_ref: float, chunk: int = 256,
) -> FloatArray:
    """Sum of squared pixel residuals of a fundamental-only sine model at each frequency of ``grid``.

    The projection is linearised about the static fit X0 (motion small against the distance): camera c's
    pixel residual is J_c·(d + a cos ωt + b sin ωt) with a constant 2×3 Jacobian J_c, so each frequency is a
    9-unknown linear least-squares problem whose normal equations are Kronecker sums
    Σ_c (Σ_i β_i β_iᵀ) ⊗ J_cᵀJ_c with β_i = (1, cos ωt_i, sin ωt_i) — cheap for thousands of frequencies.
    """
    static = fit_trajectory(Ps, ts, uvs, SineBasis(1.0, t_ref, 0, False), iterations=4)
    X0 = static.coefficients[0]
    G = np.zeros((grid.size, 9, 9))
    h = np.zeros((grid.size, 9))
    e2 = 0.0
    for P, t, uv in zip(Ps, ts, uvs, strict=True):
        x = P @ np.append(X0, 1.0)
        J = (P[:2, :3] - np.outer(x[:2] / x[2], P[2, :3])) / x[2]  # (2, 3)
        e = uv - x[:2] / x[2]
        e2 += float(np.sum(e**2))
        JtJ = J.T @ J
        q = e @ J  # (N, 3): J_cᵀ e_i
        tc = t - t_ref
        for s0 in range(0, grid.size, chunk):
            w = 2 * np.pi * grid[s0 : s0 + chunk, None] * tc[None, :]
            c, s = np.cos(w), np.sin(w)
            n = np.full(w.shape[0], float(tc.size))
            sums = [n, c.sum(1), s.sum(1), (c * c).sum(1), (c * s).sum(1), (s * s).sum(1)]
            one, sc, ss, cc, cs, s2 = sums
            B = np.stack(
                [np.stack([one, sc, ss], -1), np.stack([sc, cc, cs], -1), np.stack([ss, cs, s2], -1)], 1
            )
            G[s0 : s0 + chunk] += np.einsum("fij,kl->fikjl", B, JtJ).reshape(-1, 9, 9)
            hq = np.stack([np.broadcast_to(q.sum(0), (w.shape[0], 3)), c @ q, s @ q], 1)  # (F, 3, 3)
            h[s0 : s0 + chunk] += hq.reshape(-1, 9)
    ridge = 1e-12 * np.trace(G, axis1=1, axis2=2)[:, None, None] * np.eye(9)
    sol = np.linalg.solve(G + ridge, h[..., None])[..., 0]
    cost: FloatArray = e2 - np.einsum("fi,fi->f", h, sol)
    return cost
