"""The compiled marker kernel: loaded only by a measurement, and usable where its cache cannot be written."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig.stereo import markers_kernel

ROOT = Path(__file__).resolve().parents[1]


def test_a_function_without_a_cache_location_is_compiled_in_the_process() -> None:
    # a function defined by exec has no source file: numba has no location to cache it and refuses cache=True
    namespace: dict[str, object] = {}
    exec("def twice(x):\n    return 2 * x\n", namespace)
    with pytest.warns(RuntimeWarning, match="not cached on disk"):
        twice = markers_kernel.jit_kernel(namespace["twice"])
    assert twice(21) == 42
    assert twice(np.float32(1.5)) == 3.0


def test_importing_the_stereo_core_does_not_load_numba() -> None:
    probe = textwrap.dedent("""
        import sys
        import numpy as np
        from rig.stereo import track_markers
        loaded_at_import = "numba" in sys.modules
        img = np.zeros((64, 64), np.uint8)
        img[28:36, 28:36] = 200
        row = track_markers(img, np.array([[31.5, 31.5]]))
        print(loaded_at_import, "numba" in sys.modules, row["u_px"][0], row["v_px"][0])
    """)
    done = subprocess.run([sys.executable, "-c", probe], env={**os.environ, "PYTHONPATH": str(ROOT)},
                          capture_output=True, text=True, timeout=600, check=True)
    at_import, after_measuring, u_px, v_px = done.stdout.split()
    assert (at_import, after_measuring) == ("False", "True")
    assert (float(u_px), float(v_px)) == (31.5, 31.5)  # an 8×8 flat square centred between pixels


def test_a_window_reaching_outside_the_frame_keeps_all_its_signal() -> None:
    """Out-of-image pixels carry no signal, and only they: every in-image pixel above the floor is a
    support candidate (a conditional clearing loop was miscompiled on an AVX-512 host into stores that
    also cleared eight in-image columns: a whole marker's centre came out 2.8 px off)."""
    half = 20
    scr = markers_kernel.scratch(half)
    raw, valid, d, free, clipped = scr[5], scr[6], scr[7], scr[8], scr[9]
    raw[:] = 100
    valid[:] = True
    valid[0] = False  # the window's top row lies above the frame
    markers_kernel._weigh(raw, 0, valid, False, (20.0, 0.0, 0.0), np.float32(6.0), d, clipped, free)
    pw = 2 * half + 3
    inner = (np.arange(pw * pw) // pw >= 2) & (np.arange(pw * pw) // pw <= 2 * half + 1) \
        & (np.arange(pw * pw) % pw >= 1) & (np.arange(pw * pw) % pw <= 2 * half + 1)
    assert np.array_equal(free.astype(bool), inner)  # rows 1 … W − 1 of the window, all columns
    assert np.array_equal(d > 0, inner)


def test_a_marker_measured_in_a_window_reaching_outside_the_frame_is_measured_whole() -> None:
    from marker_images import Disc, render

    from rig.stereo import FLAG_BORDER, track_markers

    img = render((72, 72), [Disc(30.3, 19.2, 12.0)], noise_sigma_dn=0.0)
    inside = track_markers(img, np.array([[30.3, 19.2]]), window_px=35)[0]
    border = track_markers(img, np.array([[30.3, 19.2]]), window_px=41)[0]  # its top row is outside
    assert border["flags"] & FLAG_BORDER and not inside["flags"]
    assert abs(border["u_px"] - inside["u_px"]) < 0.01 and abs(border["v_px"] - inside["v_px"]) < 0.01
    assert border["area_px"] == pytest.approx(inside["area_px"], rel=0.01)


def _window(seed: int, half: int, crossing: bool) -> np.ndarray:
    """A noisy (W, W) uint8 window on a sloping background with a disc at its centre and, ``crossing``,
    a bright bar across part of its ring (outliers: the robust fit)."""
    rng = np.random.default_rng(seed)
    w = 2 * half + 1
    yy, xx = np.mgrid[0:w, 0:w] - half
    win = 30 + rng.uniform(-2, 2) * xx + rng.uniform(-2, 2) * yy + rng.normal(0, rng.uniform(0.3, 4), (w, w))
    win += np.where(xx**2 + yy**2 <= (0.6 * half) ** 2, rng.uniform(20, 240), 0)
    if crossing:
        win[: rng.integers(1, w), : rng.integers(1, 4)] += rng.uniform(40, 200)
    return np.clip(np.rint(win), 0, 255).astype(np.uint8)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31), st.integers(3, 40), st.booleans(), st.booleans())
def test_a_window_inside_the_image_is_weighed_in_place_as_its_copy(seed: int, half: int, crossing: bool,
                                                                  dark: bool) -> None:
    """The in-place path (ring and signal read from the image, dark as I ^ 255) gives the bytes of the
    copied window's path: the same plane and σ, the same signal, clipped and support candidates."""
    image = _window(seed, half, crossing)
    scr = markers_kernel.scratch(half)
    vals, ok, keep, ring_x, ring_y, raw, valid, d, free, clipped, *_, ri, ci, hist = scr
    raw[:] = 255 - image if dark else image
    ok[:] = True
    vals[:] = raw[ri, ci]
    copied = markers_kernel._ring_plane(vals, ok, True, ring_x, ring_y, keep, hist)
    a, b, c, s, clean = markers_kernel._ring_inside(image, 255 if dark else 0, hist)
    ring = np.sort(vals.astype(np.float64))  # 'lower' percentiles: is a ring value an outlier?
    p16, p50, p84 = (ring[int(q * (len(ring) - 1))] for q in (0.16, 0.5, 0.84))
    reach = markers_kernel.OUTLIER_SPREADS * max(min(p50 - p16, p84 - p50), 1.0)
    assert clean == (max(ring[-1] - p50, p50 - ring[0]) <= reach)
    if clean:  # else the caller fits the ring's values, as the copy's path does
        assert (a, b, c, s) == copied
    results = []
    for src, flip in ((raw, 0), (image, 255 if dark else 0)):
        d[:], free[:], clipped[:] = 0, 0, False
        markers_kernel._weigh(src, flip, valid, True, copied[:3], np.float32(3 * copied[3]), d, clipped, free)
        results.append((d.tobytes(), free.tobytes(), clipped.tobytes()))
    assert results[0] == results[1]


@settings(max_examples=150, deadline=None)
@given(st.integers(0, 2**31), st.sampled_from([3, 4, 8, 16, 20, 31]), st.floats(-1.5, 1.0))
def test_the_support_through_row_masks_is_the_flood_filled_one(seed: int, half: int, level: float) -> None:
    """Windows of up to 64 columns take their support through 64-bit row masks (:func:`_support_bits`):
    the same 8-connected region as the scanline flood fill (:func:`_support`) — noise masks of 7–84 %
    density, so regions of every shape — the same peak, saturation and cramped flags, plateau and moments
    (summed in another order: equal to 1e-12), and skewness noise."""
    rng = np.random.default_rng(seed)
    w, pw = 2 * half + 1, 2 * half + 3
    scr = markers_kernel.scratch(half)
    d, free, clipped, pixels, stack = scr[7], scr[8], scr[9], scr[10], scr[11]
    masks, region = scr[13], scr[14]
    d[:] = 0.0
    d.reshape(pw, pw)[1:-1, 1:-1] = rng.normal(level, 1.0, (w, w)).astype(np.float32)
    free[:] = d > 0
    clipped[:] = rng.random(len(clipped)) < 0.02
    m_fill, m_bits = np.empty(10), np.empty(10)
    n, peak, saturated, cramped = markers_kernel._support(d, half, free, clipped, pixels, stack, m_fill)
    filled = np.sort(pixels[:n])
    plateau = markers_kernel._plateau(d, filled, peak)
    *same, first, last = markers_kernel._support_bits(d, half, clipped, masks, region, m_bits)
    n_bits = markers_kernel._region_pixels(region, first, last, half, pixels)
    assert same == [n, peak, saturated, cramped]
    assert np.array_equal(pixels[:n_bits], filled)
    if n:
        assert (first, last) == (filled[0] // pw - 1, filled[-1] // pw - 1)
    assert np.allclose(m_bits, m_fill, rtol=1e-12, atol=1e-9)
    plateau_bits = markers_kernel._plateau_bits(d, half, region, first, last, peak)
    assert plateau_bits == pytest.approx(plateau, rel=1e-12)
    noise_bits = markers_kernel._skew_noise_bits(region, first, last, half, m_bits)
    noise_fill = markers_kernel._skew_noise(filled, half, m_fill)
    assert noise_bits == pytest.approx(noise_fill, rel=1e-9, nan_ok=True)


def _third_moments(w: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """Central third moments (μ30, μ21, μ12, μ03) of weights ``w`` at (xs, ys), and det(Σ)."""
    m0 = w.sum()
    x, y = xs - (w * xs).sum() / m0, ys - (w * ys).sum() / m0
    det = (w * x * x).sum() / m0 * (w * y * y).sum() / m0 - ((w * x * y).sum() / m0) ** 2
    return np.array([(w * x**p * y ** (3 - p)).sum() / m0 for p in (3, 2, 1, 0)] + [det])


@pytest.mark.parametrize(("radius_px", "blur_px", "half"), [(3.0, 2.0, 10), (6.0, 0.8, 12), (20.0, 1.5, 40)])
def test_skewness_noise_is_the_first_order_propagation_of_pixel_noise(radius_px, blur_px, half) -> None:
    """A whole blurred disc's weights on its support (both paths: row bits, and the flood fill's pixels for
    W > 64): the skewness noise per DN² equals Σ_pixels (∂μ30² + ∂μ03² + 3∂μ21² + 3∂μ12²)/det(Σ)^(3/2), the
    moments' derivatives by each pixel's weight taken numerically (central differences), to 1e-3: the kernel
    leaves out the −μ_pq/m0 in each derivative, 0 for a centrally symmetric marker (2e-4 of it here, where
    the pixel grid makes the disc not quite symmetric)."""
    w, pw = 2 * half + 1, 2 * half + 3
    yy, xx = np.mgrid[-half:half + 1, -half:half + 1].astype(float)
    r = np.hypot(xx - 0.31, yy + 0.17)  # the disc's centre off the pixel grid
    signal = 40.0 * 0.5 * (1.0 - np.tanh((r - radius_px) / blur_px)) - 6.0  # weights above a floor of 6 DN
    scr = markers_kernel.scratch(half)
    d, free, clipped, pixels, stack, m = scr[7], scr[8], scr[9], scr[10], scr[11], scr[12]
    d[:] = 0.0
    d.reshape(pw, pw)[1:-1, 1:-1] = signal.astype(np.float32)
    free[:] = d > 0
    clipped[:] = False
    n = markers_kernel._support(d, half, free, clipped, pixels, stack, m)[0]
    support = np.zeros(pw * pw, dtype=bool)
    support[pixels[:n]] = True
    support = support.reshape(pw, pw)[1:-1, 1:-1]
    weights = d.reshape(pw, pw)[1:-1, 1:-1][support].astype(float)
    xs, ys = xx[support], yy[support]
    total, step = 0.0, 1e-3
    for i in range(len(weights)):
        up, down = weights.copy(), weights.copy()
        up[i] += step
        down[i] -= step
        dmu = (_third_moments(up, xs, ys)[:4] - _third_moments(down, xs, ys)[:4]) / (2 * step)
        total += dmu[0] ** 2 + dmu[3] ** 2 + 3.0 * (dmu[1] ** 2 + dmu[2] ** 2)
    expected = total / _third_moments(weights, xs, ys)[4] ** 1.5
    assert markers_kernel._skew_noise(pixels[:n], half, m) == pytest.approx(expected, rel=1e-3)
    if w <= markers_kernel.MASK_BITS:
        m_bits = np.empty(10)
        *_, first, last = markers_kernel._support_bits(d, half, clipped, scr[13], scr[14], m_bits)
        noise_bits = markers_kernel._skew_noise_bits(scr[14], first, last, half, m_bits)
        assert noise_bits == pytest.approx(expected, rel=1e-3)
