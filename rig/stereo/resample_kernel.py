"""Compiled kernels of the band-limited reconstruction (:mod:`rig.stereo.resample`): the Kaiser-windowed sinc
rows and the sums over them, each term computed with the same floating-point operations in the same order as
the numpy and scipy.sparse expressions they replace (results equal to the bit: tests/test_resample_kernel.py).

The window's I0 is cephes' Chebyshev series on [0, 8] (the one scipy.special.i0 and numpy.i0 evaluate there:
the same coefficients, the same recurrence); its argument β·√(1 − r²) stays below β ≤ 8.

Imported by :mod:`rig.stereo.resample` when a reconstruction is first built (numba and the compiled code are
loaded then, not by ``import rig.stereo``); compiled once into numba's on-disk cache
(:mod:`rig.warm_kernels`).
"""

from __future__ import annotations

import numpy as np

from rig.stereo.markers_kernel import jit_kernel

# cephes i0.c, coefficients A for 0 ≤ x ≤ 8: exp(−x)·I0(x) = Σ A_k T_k(x/2 − 2) (Chebyshev)
_I0_A = np.array([
    -4.41534164647933937950E-18, 3.33079451882223809783E-17, -2.43127984654795469359E-16,
    1.71539128555513303061E-15, -1.16853328779934516808E-14, 7.67618549860493561688E-14,
    -4.85644678311192946090E-13, 2.95505266312963983461E-12, -1.72682629144155570723E-11,
    9.67580903537323691224E-11, -5.18979560163526290666E-10, 2.65982372468238665035E-9,
    -1.30002500998624804212E-8, 6.04699502254191894932E-8, -2.67079385394061173391E-7,
    1.11738753912010371815E-6, -4.41673835845875056359E-6, 1.64484480707288970893E-5,
    -5.75419501008210370398E-5, 1.88502885095841655729E-4, -5.76375574538582365885E-4,
    1.63947561694133579842E-3, -4.32430999505057594430E-3, 1.05464603945949983183E-2,
    -2.37374148058994688156E-2, 4.93052842396707084878E-2, -9.49010970480476444210E-2,
    1.71620901522208775349E-1, -3.04682672343198398683E-1, 6.76795274409476084995E-1,
])


_BLOCK = 64  # terms whose Chebyshev recurrences run side by side (vectorised across them)


@jit_kernel
def i0_small(x: np.ndarray) -> np.ndarray:
    """Modified Bessel function I0 of each of ``x`` (all in [0, 8]) as cephes computes it: exp(x) × the
    Chebyshev series (cephes' chbevl), its recurrence run for a block of terms at a time (independent chains:
    vectorised; each term's operations are cephes' own, in its order)."""
    out = np.empty(x.size)
    y = np.empty(_BLOCK)
    b0 = np.empty(_BLOCK)
    b1 = np.empty(_BLOCK)
    b2 = np.empty(_BLOCK)
    for start in range(0, x.size, _BLOCK):
        n = min(_BLOCK, x.size - start)
        for e in range(n):
            y[e] = x[start + e] / 2.0 - 2.0
            b0[e] = _I0_A[0]
            b1[e] = 0.0
        for k in range(1, _I0_A.size):
            coef = _I0_A[k]
            for e in range(n):  # b2 ← b1, b1 ← b0, b0 ← y·b1 − b2 + A_k
                previous = b0[e]
                b2[e] = b1[e]
                b1[e] = previous
                b0[e] = y[e] * previous - b2[e] + coef
        for e in range(n):
            out[start + e] = np.exp(x[start + e]) * (0.5 * (b0[e] - b2[e]))
    return out


@jit_kernel
def kaiser_sinc_rows(frac: np.ndarray, half: int, beta: float) -> np.ndarray:
    """Kaiser-windowed sinc at ``frac − o`` sample periods, o = −half … half: (frac.size, 2·half + 1), zero
    beyond ±half; ``frac`` (periods past a grid sample) in [0, 1), 0 < ``beta`` ≤ 8 (the caller checks it).
    One sine per row, sin π(f − o) = (−1)ᵒ sin π·min(f, 1 − f) (exact arguments: accurate next to either
    sample): equal to numpy's sinc and i0 term by term within 2e-15 (tests/test_resample_kernel.py)."""
    width = 2 * half + 1
    # the window's argument β·√(1 − r²) of every term inside ±half (r = (f − o)/half), 0 outside
    arg = np.zeros(frac.size * width)
    for i in range(frac.size):
        for c in range(width):
            r = (frac[i] - (c - half)) / half
            if abs(r) < 1.0:
                arg[i * width + c] = beta * np.sqrt(1.0 - r * r)
    win = i0_small(arg)
    i0_beta = i0_small(np.full(1, beta))[0]
    out = np.zeros((frac.size, width))
    for i in range(frac.size):
        f = frac[i]
        sine = np.sin(np.pi * min(f, 1.0 - f))  # sin π(f − o) = (−1)ᵒ sin π·min(f, 1 − f)
        for c in range(width):
            o = c - half
            tau = f - o
            if abs(tau / half) < 1.0:
                signed = sine if o % 2 == 0 else -sine
                sinc = 1.0 if tau == 0.0 else signed / (np.pi * tau)
                out[i, c] = sinc * (win[i * width + c] / i0_beta)
    return out


@jit_kernel
def kernel_rows(tau: np.ndarray, n_cols: int, half: int, beta: float) -> tuple[np.ndarray, np.ndarray]:
    """The rows of K[i, j] = h(tau_i − j) (``tau`` in grid periods) over their support: (values
    (n, 2·half + 1), first column (n,)); the terms on columns outside 0 … n_cols − 1 are zero."""
    base = np.floor(tau)
    rows = kaiser_sinc_rows(tau - base, half, beta)  # tau − floor(tau) is exact
    first = np.empty(tau.size, dtype=np.int64)
    for i in range(tau.size):
        first[i] = int(base[i]) - half
        for c in range(rows.shape[1]):
            if not 0 <= first[i] + c < n_cols:
                rows[i, c] = 0.0
    return rows, first


@jit_kernel
def normal_equations(rows: np.ndarray, first: np.ndarray, n_cols: int, values: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """SᵀS in the lower banded form of scipy.linalg.solveh_banded ((width, n_cols): row d holds N[i + d, i])
    and Sᵀ·``values`` ((n_cols, k)), S the kernel ``rows``: each sum taken over S's rows in order, as
    scipy.sparse's S.T @ S and S.T @ values take them."""
    width = rows.shape[1]
    bands = np.zeros((width, n_cols))
    rhs = np.zeros((n_cols, values.shape[1]))
    for k in range(rows.shape[0]):
        for a in range(width):
            va = rows[k, a]
            if va == 0.0:
                continue
            ja = first[k] + a
            for c in range(values.shape[1]):
                rhs[ja, c] += va * values[k, c]
            for b in range(a + 1):
                vb = rows[k, b]
                if vb != 0.0:
                    bands[a - b, first[k] + b] += vb * va
    return bands, rhs


@jit_kernel
def rows_times(rows: np.ndarray, first: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """K·``grid`` ((n_cols, k) → (n, k)), each row's terms summed in column order (as scipy.sparse's)."""
    out = np.zeros((rows.shape[0], grid.shape[1]))
    for i in range(rows.shape[0]):
        for a in range(rows.shape[1]):
            v = rows[i, a]
            if v != 0.0:
                for c in range(grid.shape[1]):
                    out[i, c] += v * grid[first[i] + a, c]
    return out


@jit_kernel
def rows_transposed(rows: np.ndarray, first: np.ndarray, n_cols: int) -> np.ndarray:
    """Kᵀ as a dense (n_cols, n) array, F-ordered (LAPACK's layout for right-hand sides)."""
    out = np.zeros((rows.shape[0], n_cols)).T
    for i in range(rows.shape[0]):
        for a in range(rows.shape[1]):
            if rows[i, a] != 0.0:
                out[first[i] + a, i] = rows[i, a]
    return out


@jit_kernel
def rows_dot_columns(rows: np.ndarray, first: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Σ_j K[i, j]·z[j, i] for each row i (``z`` (n_cols, n)), terms in column order."""
    out = np.zeros(rows.shape[0])
    for i in range(rows.shape[0]):
        for a in range(rows.shape[1]):
            v = rows[i, a]
            if v != 0.0:
                out[i] += v * z[first[i] + a, i]
    return out

