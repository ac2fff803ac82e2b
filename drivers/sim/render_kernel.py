"""The twin's per-pixel work, compiled (numba): a disc's coverage of its patch, and the patch added onto the
frame. Both reproduce the float32 arithmetic of the numpy expressions they replaced operation by operation
(same operands, same order, no fused multiply-add: numba's default keeps IEEE order), so frames are the
same bytes (tests/test_sim_render_bytes.py); they only skip numpy's full-size temporaries and per-patch
calls. Compiled code is cached on disk next to this file when that location is writable.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from drivers.numba_kernel import nogil_kernel

__all__ = ["add_patches", "chord_coverage"]

_jit = nogil_kernel("render")


@_jit
def chord_coverage(coefficients: NDArray[np.float32], rel_px: NDArray[np.float32],
                   sub_px: NDArray[np.float32], out: NDArray[np.float32]) -> None:
    """Covered fraction of each pixel of each patch row into ``out`` (M, Hp, Wp), averaged over the
    sub-scanlines ``sub_px`` (S,) (row offsets, px) and the K exposure samples.

    ``coefficients`` (M, 5): the conic's a = C00, 2·C01, 2·C02, C11, 2·C12 (pixel offsets, C22 = −1);
    ``rel_px`` (M, Hp, K, 2): the disc centre (x, y) relative to the patch corner per row and sample.
    On a sub-scanline at dy from the centre the chord is x = mid ± half with b = 2C01·dy + 2C02,
    c = (C11·dy + 2C12)·dy − 1, half = √(b² − 4ac)/(2a), mid = x_c − b/(2a); a pixel [e, e + 1] covers
    min(x_r, e + 1) − max(x_l, e), at least 0.
    """
    m_count, hp, k_count = rel_px.shape[0], rel_px.shape[1], rel_px.shape[2]
    s_count, wp = sub_px.shape[0], out.shape[2]
    one, two, four = np.float32(1.0), np.float32(2.0), np.float32(4.0)
    no_chord, half_px = np.float32(-1e6), np.float32(0.5)
    scale = np.float32(1.0 / (s_count * k_count))
    acc = np.empty(wp, np.float32)
    for m in range(m_count):
        a, b1, b0 = coefficients[m, 0], coefficients[m, 1], coefficients[m, 2]
        c1, c0 = coefficients[m, 3], coefficients[m, 4]
        two_a, four_a = two * a, four * a
        for r in range(hp):
            acc[:] = 0.0
            row = np.float32(r)
            for s in range(s_count):
                y = row + sub_px[s]
                for k in range(k_count):
                    dy = y - rel_px[m, r, k, 1]
                    b = b1 * dy + b0
                    c = (c1 * dy + c0) * dy - one
                    disc = b * b - four_a * c
                    half = no_chord if disc <= 0 else np.sqrt(disc) / two_a
                    mid = rel_px[m, r, k, 0] - b / two_a
                    xl, xr = mid - half, mid + half
                    for w in range(wp):
                        e = np.float32(w) - half_px
                        cov = min(xr, e + one) - max(xl, e)
                        if cov > 0:
                            acc[w] += cov
            for w in range(wp):
                out[m, r, w] = acc[w] * scale


@_jit
def add_patches(  # noqa: PLR0917 (numba: no keyword-only arguments)
        frame: NDArray[np.uint8], cov: NDArray[np.float32], row0: NDArray[np.int64], col0: NDArray[np.int64],
        contrast_dn: np.float32, shot_dn2_per_dn: np.float32, normals: NDArray[np.float32]) -> None:
    """Add each patch's signal onto ``frame`` in place, patch after patch, saturating at 0 and 255.

    Signal = cov·contrast_dn, plus (when ``shot_dn2_per_dn`` > 0) its shot noise √(max(signal, 0)·shot)
    × ``normals`` (standard normals, one per patch pixel, in patch order), rounded half to even. Patch j
    starts at image row ``row0[j]``, column ``col0[j]``; the part outside the frame is left out."""
    h, w = frame.shape
    m_count, hp, wp = cov.shape
    noisy = shot_dn2_per_dn > 0
    zero = np.float32(0.0)
    for j in range(m_count):
        for r in range(max(0, -row0[j]), min(hp, h - row0[j])):
            y = row0[j] + r
            for q in range(max(0, -col0[j]), min(wp, w - col0[j])):
                sig = cov[j, r, q] * contrast_dn
                if noisy:
                    sig += np.sqrt(max(sig, zero) * shot_dn2_per_dn) * normals[(j * hp + r) * wp + q]
                value = int(frame[y, col0[j] + q]) + int(np.rint(sig))  # |signal| < 2¹⁵: int16 in numpy
                frame[y, col0[j] + q] = min(max(value, 0), 255)
