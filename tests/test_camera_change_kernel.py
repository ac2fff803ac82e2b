"""The compiled change maps of the duplicate test give OpenCV's numbers bit for bit; the sampled per-frame
pass gives every 4th block of the whole map, its largest value and its median; the region's maps (the
candidates' judging: :func:`drivers.camera.change_kernel.region_changes`) give the whole map's numbers."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.camera.change_kernel import (
    half_change_stats,
    half_only,
    region_changes,
    sampled_half,
    sampled_stats,
    sampled_words,
)
from drivers.camera.video_file import _tested


def _half(image: np.ndarray) -> np.ndarray:
    """OpenCV's 2× area reduction (the reference the kernels follow)."""
    h, w = image.shape
    return cv2.resize(image, (w // 2, h // 2), interpolation=cv2.INTER_AREA)


def _block_change(a_half: np.ndarray, b_half: np.ndarray) -> np.ndarray:
    """Mean |a − b| per 8×8 block of the full image from two half-size images, by OpenCV: two exact 2× area
    reductions of 16 × |a − b| (float32 DN, to 1/16 DN)."""
    d = cv2.absdiff(a_half, b_half).astype(np.uint16) << 4
    for _ in range(2):
        h, w = d.shape
        d = cv2.resize(d, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    return d.astype(np.float32) * np.float32(1 / 16)


def _sampled_reference(half: np.ndarray) -> np.ndarray:
    """The half-size image's 4×4 blocks at even block rows and columns, packed."""
    rows = (np.arange(half.shape[0]) // 4) % 2 == 0
    cols = (np.arange(half.shape[1]) // 4) % 2 == 0
    return half[rows][:, cols]


@st.composite
def frame_pairs(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    rows, cols = 8 * draw(st.integers(1, 12)), 8 * draw(st.integers(1, 12))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    a = rng.integers(0, 256, (rows, cols), dtype=np.uint8)
    if draw(st.booleans()):  # a frame close to the other: small differences, some identical blocks
        b = np.clip(a.astype(int) + rng.integers(-3, 4, a.shape) * (rng.random(a.shape) < 0.3), 0, 255)
        return a, b.astype(np.uint8)
    return a, rng.integers(0, 256, (rows, cols), dtype=np.uint8)


@settings(max_examples=60, deadline=None)
@given(frame_pairs())
def test_the_kernel_gives_opencvs_half_image_and_block_change(pair: tuple[np.ndarray, np.ndarray]) -> None:
    a, b = pair
    prev_half = _half(b)
    half, change, max_dn, floor_dn = half_change_stats(a, prev_half)
    assert half.dtype == np.uint8 and change.dtype == np.float32
    np.testing.assert_array_equal(half, _half(a))
    np.testing.assert_array_equal(change, _block_change(_half(a), prev_half))
    np.testing.assert_array_equal(half_only(a), _half(a))
    assert max_dn == float(change.max())
    assert floor_dn == float(np.median(change[::2, ::2]))


@settings(max_examples=80, deadline=None)
@given(frame_pairs())
def test_the_sampled_pass_gives_every_4th_block_of_the_whole_map(pair: tuple[np.ndarray, np.ndarray]) -> None:
    a, b = pair
    half, change, max_dn, floor_dn = half_change_stats(a, _half(b))
    np.testing.assert_array_equal(sampled_half(b), _sampled_reference(_half(b)))
    sampled, sampled_map, sampled_max_dn, sampled_floor_dn = sampled_stats(a, sampled_half(b))
    np.testing.assert_array_equal(sampled, _sampled_reference(half))
    assert sampled_map.dtype == np.float32
    np.testing.assert_array_equal(sampled_map, change[::2, ::2])
    assert sampled_max_dn == float(change[::2, ::2].max()) <= max_dn
    assert sampled_floor_dn == floor_dn  # the noise floor is counted on these blocks: the same number


@settings(max_examples=40, deadline=None)
@given(frame_pairs(), st.integers(0, 2**32 - 1))
def test_the_region_maps_are_the_kernels_numbers(pair: tuple[np.ndarray, np.ndarray], seed: int) -> None:
    a, b = pair
    change = half_change_stats(a, _half(b))[1]
    chosen = np.random.default_rng(seed).random(change.shape) < 0.5
    rows, cols = np.nonzero(chosen)
    region = region_changes((b, a), rows, cols, np.array([[0, 1], [1, 0], [0, 0]]))
    assert region.dtype == np.float32
    np.testing.assert_array_equal(region[0], change[rows, cols])
    np.testing.assert_array_equal(region[1], change[rows, cols])  # |a − b| both ways round
    assert not region[2].any()


def test_the_extremes_a_non_contiguous_frame_and_a_cropped_size() -> None:
    white, black = np.full((16, 24), 255, np.uint8), np.zeros((16, 24), np.uint8)
    half, change, _, _ = half_change_stats(white, _half(black))
    assert (half == 255).all() and (change == 255).all()
    sampled, sampled_map, max_dn, floor_dn = sampled_stats(white, sampled_half(black))
    assert (sampled == 255).all() and (sampled_map == 255).all() and max_dn == floor_dn == 255
    big = np.random.default_rng(3).integers(0, 256, (32, 48), dtype=np.uint8)
    view = big[:16, :24]  # a view with the parent's row stride
    reference = _block_change(_half(view), _half(black))
    np.testing.assert_array_equal(half_change_stats(view, _half(black))[1], reference)
    np.testing.assert_array_equal(sampled_stats(view, sampled_half(black))[1], reference[::2, ::2])
    odd = np.random.default_rng(4).integers(0, 256, (36, 50), dtype=np.uint8)  # not multiples of 8
    np.testing.assert_array_equal(_tested(odd), odd[:32, :48])
    # the reader's per-frame call (sampled_words) takes the tested image unchecked: a strided frame of a
    # whole size must come out C-contiguous, equal, and give the kernel's numbers
    tested = _tested(view)
    assert tested.flags.c_contiguous
    np.testing.assert_array_equal(tested, view)
    prev_words = sampled_words(np.ascontiguousarray(black), None)[0]
    np.testing.assert_array_equal(sampled_words(tested, prev_words)[1], reference[::2, ::2])


def test_a_wrong_previous_image_or_size_is_refused() -> None:
    with pytest.raises(ValueError, match="prev_half has shape"):
        half_change_stats(np.zeros((16, 16), np.uint8), np.zeros((4, 4), np.uint8))
    with pytest.raises(ValueError, match="prev_sampled has shape"):
        sampled_stats(np.zeros((16, 16), np.uint8), np.zeros((4, 8), np.uint8))
    with pytest.raises(ValueError, match="multiples of 8"):
        sampled_half(np.zeros((12, 16), np.uint8))


@pytest.mark.parametrize("blocks", [(1, 1), (2, 2), (3, 4), (4, 6)])
def test_the_compiled_median_counts_odd_and_even_numbers_of_blocks(blocks: tuple[int, int]) -> None:
    """Every 4th block of a (rows × cols)-block frame: 1, 1, 4 and 6 blocks — odd and even counts."""
    rng = np.random.default_rng(sum(blocks))
    a, b = (rng.integers(0, 256, (8 * blocks[0], 8 * blocks[1]), dtype=np.uint8) for _ in range(2))
    _, change, max_dn, floor_dn = half_change_stats(a, _half(b))
    assert floor_dn == float(np.median(change[::2, ::2])) and max_dn == float(change.max())
    assert sampled_stats(a, sampled_half(b))[3] == floor_dn
