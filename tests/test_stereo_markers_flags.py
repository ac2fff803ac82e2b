"""Marker quality flags (occluded, border, saturated) and geometric properties of the centre."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from marker_images import Disc, centroid_noise_px, render

from rig.stereo import (
    FLAG_BORDER,
    FLAG_OCCLUDED,
    FLAG_SATURATED,
    detect_markers,
    track_markers,
)
from rig.stereo.markers_refine import measure_windows


def only(found: np.ndarray) -> np.void:
    assert len(found) == 1, found
    return found[0]


@pytest.mark.parametrize("outline_check", [False, True])
@pytest.mark.parametrize("radius_px", [8.0, 20.0])
@pytest.mark.parametrize("cut", [0.3, 0.5, 1.0])
def test_partly_occluded_disc_is_flagged(radius_px, cut, outline_check):
    """A straight-edged object hides the right part of the disc (cut = hidden depth / radius)."""
    u, v = 60.3, 59.6
    occluder = (u + radius_px * (1.0 - cut), 0.0, 500.0, 500.0)
    img = render((120, 120), [Disc(u, v, radius_px)], occluders=[occluder], seed=1)
    row = only(detect_markers(img, min_roundness=0.2, outline_check=outline_check))
    assert row["flags"] & FLAG_OCCLUDED


@pytest.mark.parametrize("radius_px", [2.5, 4.0, 8.0, 20.0, 30.0])
@pytest.mark.parametrize("centre", ["centroid", "ellipse"])
def test_whole_discs_and_ellipses_are_not_flagged(radius_px, centre):
    rng = np.random.default_rng(int(radius_px * 10))
    discs = [Disc(50 + rng.uniform(-0.5, 0.5), 50 + rng.uniform(-0.5, 0.5), radius_px),
             Disc(150 + rng.uniform(-0.5, 0.5), 50 + rng.uniform(-0.5, 0.5), radius_px,
                  0.6 * radius_px, rng.uniform(0, 180))]
    for seed in range(5):
        img = render((110, 210), discs, seed=seed)
        found = detect_markers(img, min_area_px=5, centre=centre)
        assert len(found) == 2
        assert np.all(found["flags"] == 0), found


def test_low_contrast_noisy_disc_is_not_flagged():
    """Contrast 40 DN over noise σ = 6 DN: the occlusion tests widen with the noise."""
    for seed in range(10):
        img = render((80, 80), [Disc(40.2, 39.7, 8.0, contrast_dn=40.0)], noise_sigma_dn=6.0,
                     background_dn=40.0, seed=seed)
        row = only(detect_markers(img, outline_check=True))
        assert row["flags"] == 0, row


def test_small_bite_is_flagged_by_the_outline_check():
    u, v, r = 60.0, 60.0, 20.0
    bite = (u + 0.6 * r, v - 0.2 * r, u + r + 2, v + 0.2 * r)  # a 40 %-deep, 40 %-wide notch
    img = render((120, 120), [Disc(u, v, r)], occluders=[bite], seed=2)
    assert only(detect_markers(img, outline_check=True))["flags"] & FLAG_OCCLUDED


def test_border_flag():
    img = render((80, 120), [Disc(5.0, 40.0, 6.0), Disc(60.0, 40.0, 6.0)], seed=3)
    found = detect_markers(img)
    assert len(found) == 2
    near, far = found[np.argsort(found["u_px"])]
    assert near["flags"] & FLAG_BORDER
    assert not far["flags"] & FLAG_BORDER
    tracked = track_markers(img, np.array([[5.0, 40.0], [60.0, 40.0]]), window_px=21)
    assert tracked["flags"][0] & FLAG_BORDER and not tracked["flags"][1] & FLAG_BORDER


def test_saturated_flag_both_polarities():
    img = render((80, 160), [Disc(40, 40, 7.0, contrast_dn=300.0), Disc(120, 40, 7.0, contrast_dn=150.0)],
                 seed=4)
    found = detect_markers(img)
    assert len(found) == 2
    sat, ok = found[np.argsort(found["u_px"])]
    assert sat["flags"] & FLAG_SATURATED and not ok["flags"] & FLAG_SATURATED
    dark = render((80, 160), [Disc(40, 40, 7.0, contrast_dn=250.0), Disc(120, 40, 7.0, contrast_dn=100.0)],
                  background_dn=200.0, dark=True, seed=5)
    found = detect_markers(dark, polarity="dark")
    sat, ok = found[np.argsort(found["u_px"])]
    assert sat["flags"] & FLAG_SATURATED and not ok["flags"] & FLAG_SATURATED


NOISE_DN = 2.0


@settings(max_examples=25, deadline=None)
@given(
    u=st.floats(30.0, 34.0), v=st.floats(30.0, 34.0),
    du=st.floats(-12.0, 12.0), dv=st.floats(-12.0, 12.0),
    radius=st.floats(4.0, 12.0), seed=st.integers(0, 2**16),
)
def test_translating_the_disc_translates_the_centre(u, v, du, dv, radius, seed):  # noqa: PLR0917
    """Same noise pattern relative to the disc is not possible, so the tolerance is the noise: the
    measured displacement equals (du, dv) within 5·√2·σ_c plus the grid allowance of 0.005 px per axis."""
    shape = (72, 72)
    a, clean = render(shape, [Disc(u, v, radius)], seed=seed, return_float=True)
    b = render(shape, [Disc(u + du, v + dv, radius)], seed=seed + 1)
    ra, rb = only(detect_markers(a)), only(detect_markers(b))
    pixel_sigma = np.sqrt(NOISE_DN**2 + 1 / 12)
    sigma_c = centroid_noise_px(clean, 20.0, (u, v), noise_sigma_dn=pixel_sigma, floor_dn=3 * pixel_sigma,
                                half_px=int(radius) + 5)
    tol = 5.0 * np.sqrt(2.0) * sigma_c + 0.005
    assert abs((rb["u_px"] - ra["u_px"]) - du) < tol
    assert abs((rb["v_px"] - ra["v_px"]) - dv) < tol


@settings(max_examples=15, deadline=None)
@given(angle=st.floats(0.0, 180.0), ratio=st.floats(0.55, 1.0), seed=st.integers(0, 2**16))
def test_rotating_an_ellipse_keeps_its_centre(angle, ratio, seed):
    u, v = 40.37, 39.81
    img, clean = render((80, 80), [Disc(u, v, 10.0, 10.0 * ratio, angle)], seed=seed, return_float=True)
    row = only(detect_markers(img))
    pixel_sigma = np.sqrt(NOISE_DN**2 + 1 / 12)
    sigma_c = centroid_noise_px(clean, 20.0, (u, v), noise_sigma_dn=pixel_sigma, floor_dn=3 * pixel_sigma,
                                half_px=15)
    assert np.hypot(row["u_px"] - u, row["v_px"] - v) < 5.0 * sigma_c + 0.005
    assert row["roundness"] == pytest.approx(np.sqrt((ratio**2 * 25 + 0.64) / (25 + 0.64)), abs=0.05)


@settings(max_examples=30, deadline=None)
@given(
    radius=st.floats(3.0, 25.0), ratio=st.floats(0.6, 1.0), angle=st.floats(0.0, 180.0),
    contrast=st.floats(30.0, 200.0), noise=st.floats(0.5, 4.0), blur=st.floats(0.3, 2.0),
    du=st.floats(0.0, 1.0), dv=st.floats(0.0, 1.0), seed=st.integers(0, 2**16),
)
def test_any_whole_marker_is_found_once_unflagged_within_noise(  # noqa: PLR0917
        radius, ratio, angle, contrast, noise, blur, du, dv, seed):
    """Random size, shape, contrast, noise and blur: one detection, no occlusion flag, and a centre error
    within 5 per-axis σ_c (times √2 for the 2-D distance) plus the 0.005 px grid allowance per axis.

    Markers must be detectable at all: a blurred peak at least 8σ above the background (the binarization
    needs 4σ, the weights start at 3σ), and at least 20 px² of the noise-free image above the binarization's
    4σ — the area the detector measures, twice ``min_area_px`` (a small faint disc's geometric area is not:
    radius 3, contrast 30, noise σ 3 has 21 px² of disc but 9.5 px² above 4σ after the blur). And wide
    enough across for the pixel grid not to skew them: √(b²/4 + blur²) ≥ 1.1 px for the minor semi-axis b
    (the domain of the occlusion limits, rig/stereo/markers.py).
    """
    u, v = 64.0 + du, 64.0 + dv
    background = 20.0
    img, clean = render((128, 128), [Disc(u, v, radius, radius * ratio, angle, contrast)],
                        background_dn=background, noise_sigma_dn=noise, blur_sigma_px=blur, seed=seed,
                        return_float=True)
    pixel_sigma = np.sqrt(noise**2 + 1 / 12)
    above_threshold_px2 = int(np.count_nonzero(clean - background >= 4.0 * pixel_sigma))
    assume(clean.max() - background >= 8.0 * pixel_sigma and above_threshold_px2 >= 20)
    assume(np.hypot(radius * ratio / 2.0, blur) >= 1.1)
    row = only(detect_markers(img, min_area_px=10, min_contrast=10))
    assert not row["flags"] & FLAG_OCCLUDED
    sigma_c = centroid_noise_px(clean, background, (u, v), noise_sigma_dn=pixel_sigma,
                                floor_dn=3 * pixel_sigma, half_px=int(radius) + 8)
    assert np.hypot(row["u_px"] - u, row["v_px"] - v) < np.sqrt(2) * (5.0 * sigma_c + 0.005)


@pytest.mark.parametrize(("radius_px", "ratio", "blur_px", "contrast_dn", "half_px"), [
    (3.0, 1.0, 2.0, 30.0, 10), (5.0, 1.0, 1.5, 40.0, 12), (8.0, 1.0, 0.8, 60.0, 14),
    (20.0, 0.6, 1.5, 40.0, 28),
])
def test_skewness_noise_is_the_mean_skewness_of_a_whole_marker(
        radius_px, ratio, blur_px, contrast_dn, half_px):
    """Noise σ 2 DN, 200 draws (10 sub-pixel centres and angles × 20): the measured skewness of a whole
    marker over its ``skewness_noise`` averages 0.5–1.5 (measured 0.69, 0.85, 0.99, 1.03 over 400 draws;
    the former allowance 8σ²/(contrast²·area): 14.9, 7.3, 2.6, 4.3)."""
    rng = np.random.default_rng(17)
    ratios = []
    for _ in range(10):
        u, v = 40.0 + rng.uniform(0, 1), 40.0 + rng.uniform(0, 1)
        disc = Disc(u, v, radius_px, radius_px * ratio, rng.uniform(0, 180), contrast_dn)
        _, clean = render((80, 80), [disc], blur_sigma_px=blur_px, noise_sigma_dn=0.0, return_float=True)
        for _ in range(20):
            img = np.clip(np.rint(clean + rng.normal(0.0, 2.0, clean.shape)), 0, 255).astype(np.uint8)
            m = measure_windows(img, np.array([round(v)]), np.array([round(u)]), half_px, dark=False)
            assert not m.cramped[0]
            ratios.append(m.skewness[0] / m.skewness_noise[0])
    assert 0.5 < np.mean(ratios) < 1.5


@pytest.mark.parametrize(("radius_px", "ratio", "blur_px", "contrast_dn", "noise_dn"), [
    (3.0, 1.0, 2.0, 30.0, 2.0),  # small, faint, blurred: the noise on its wide skirt (the former miss)
    (3.0, 0.6, 0.64, 200.0, 0.5),  # narrow and sharp, at the domain's edge: the pixel grid's own skewness
])
def test_whole_markers_at_the_edge_of_the_domain_are_not_flagged(
        radius_px, ratio, blur_px, contrast_dn, noise_dn):
    """1,000 noise draws (20 sub-pixel centres and angles × 50) of the worst shapes measured in the domain
    of the occlusion limits: none flagged. Their skewness reaches at most 0.15 (first: noise) and 0.48
    (second: the pixel grid) of the limit in these draws, so a flag would take a tail 7× or 2× beyond them.
    The former allowance flagged 14 of the first's 1,000 (none of the second's, which guards the domain's
    edge √(b²/4 + blur²) ≥ 1.1 px: at blur 0.3 px the same marker reaches 1.2× the limit)."""
    rng = np.random.default_rng(16)
    flagged = 0
    for _ in range(20):
        u, v = 20.0 + rng.uniform(0, 1), 20.0 + rng.uniform(0, 1)
        disc = Disc(u, v, radius_px, radius_px * ratio, rng.uniform(0, 180), contrast_dn)
        _, clean = render((40, 40), [disc], blur_sigma_px=blur_px, noise_sigma_dn=0.0, return_float=True)
        for _ in range(50):
            img = np.clip(np.rint(clean + rng.normal(0.0, noise_dn, clean.shape)), 0, 255).astype(np.uint8)
            row = only(detect_markers(img, min_area_px=10, min_contrast=10))
            flagged += bool(row["flags"] & FLAG_OCCLUDED)
    assert flagged == 0


@pytest.mark.parametrize("shape", [(8, 8), (12, 20), (24, 24)])
def test_frames_smaller_than_the_windows(shape):
    """Windows larger than the frame: the marker is still measured, flagged at the border, no warning."""
    disc = Disc(shape[1] / 2 - 0.3, shape[0] / 2 + 0.2, min(shape) / 4)
    img = render(shape, [disc], seed=1)
    for found in (detect_markers(img, min_area_px=5),
                  track_markers(img, np.array([[disc.u_px, disc.v_px]]), window_px=41, min_area_px=5)):
        row = only(found)
        assert row["flags"] & FLAG_BORDER
        assert np.hypot(row["u_px"] - disc.u_px, row["v_px"] - disc.v_px) < 1.0
