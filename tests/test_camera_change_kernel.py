"""The compiled change maps of the duplicate test give OpenCV's numbers bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.camera.change_kernel import block_change, half_and_change, half_change_stats, half_only
from drivers.camera.video_file import _block_change, _half, _half_and_change, _noise_floor


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
    half, change = half_and_change(a, prev_half)
    assert half.dtype == np.uint8 and change.dtype == np.float32
    np.testing.assert_array_equal(half, _half(a))
    np.testing.assert_array_equal(change, _block_change(_half(a), prev_half))
    np.testing.assert_array_equal(half_only(a), _half(a))
    _, _, max_dn, floor_dn = half_change_stats(a, prev_half)
    assert max_dn == float(change.max()) and floor_dn == _noise_floor(change)
    assert floor_dn == float(np.median(change[::2, ::2]))
    np.testing.assert_array_equal(block_change(_half(a), prev_half), _block_change(_half(a), prev_half))


def test_the_extremes_and_a_non_contiguous_frame() -> None:
    white, black = np.full((16, 24), 255, np.uint8), np.zeros((16, 24), np.uint8)
    half, change = half_and_change(white, _half(black))
    assert (half == 255).all() and (change == 255).all()
    big = np.random.default_rng(3).integers(0, 256, (32, 48), dtype=np.uint8)
    view = big[:16, :24]  # a view with the parent's row stride
    np.testing.assert_array_equal(half_and_change(view, _half(black))[1],
                                  _block_change(_half(view), _half(black)))


def test_sizes_off_the_kernels_grid_take_opencv_and_a_wrong_previous_image_is_refused() -> None:
    rng = np.random.default_rng(5)
    a, b = (rng.integers(0, 256, (36, 50), dtype=np.uint8) for _ in range(2))  # not multiples of 8
    half, change = _half_and_change(a, _half(b))
    np.testing.assert_array_equal(half, _half(a))
    assert change is not None
    np.testing.assert_array_equal(change.map, _block_change(_half(a), _half(b)))
    assert change.max_dn == float(change.map.max()) and change.floor_dn == _noise_floor(change.map)
    assert _half_and_change(a, None)[1] is None
    with pytest.raises(ValueError, match="prev_half has shape"):
        half_and_change(np.zeros((16, 16), np.uint8), np.zeros((4, 4), np.uint8))
    with pytest.raises(ValueError, match="sides multiples of 4"):
        block_change(np.zeros((6, 8), np.uint8), np.zeros((6, 8), np.uint8))


@pytest.mark.parametrize("blocks", [(1, 1), (2, 2), (3, 4), (4, 6)])
def test_the_compiled_median_counts_odd_and_even_numbers_of_blocks(blocks: tuple[int, int]) -> None:
    """Every 4th block of a (rows × cols)-block frame: 1, 1, 4 and 6 blocks — odd and even counts."""
    rng = np.random.default_rng(sum(blocks))
    a, b = (rng.integers(0, 256, (8 * blocks[0], 8 * blocks[1]), dtype=np.uint8) for _ in range(2))
    _, change, max_dn, floor_dn = half_change_stats(a, _half(b))
    assert floor_dn == float(np.median(change[::2, ::2])) and max_dn == float(change.max())
