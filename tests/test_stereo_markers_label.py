"""The compiled binarization (rig.stereo.markers_label) finds the blobs OpenCV's chain finds, whatever the
row bands it is split into."""

from __future__ import annotations

import itertools

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig.stereo import markers_binarize as mb
from rig.stereo.markers_label import (
    _least_level,
    band_runs,
    join_boxes,
    local_blobs,
    reduced_shape,
    subsample_sigma,
)


def _sorted(boxes: np.ndarray) -> np.ndarray:
    return boxes[np.lexsort(boxes.T[::-1])]


def _frame(seed: int, shape: tuple[int, int], noise_dn: float = 60.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = (rng.random(shape) * rng.uniform(0, noise_dn)).astype(np.uint8)
    for _ in range(25):  # rectangles of any size and level, touching, overlapping, at the edges
        y, x = rng.integers(0, shape[0]), rng.integers(0, shape[1])
        img[y:y + rng.integers(1, 40), x:x + rng.integers(1, 40)] = rng.integers(30, 256)
    return img


@pytest.mark.parametrize("seed", range(12))
@pytest.mark.parametrize("factor", [2, 4])
def test_subsampled_bands_equal_opencv(seed: int, factor: int) -> None:
    """The subsample's noise σ and its blobs, labelled in one band and in three (the subsample and the
    polarity done by the kernel, in bands), against numpy's subsample and OpenCV's chain."""
    shape = ((200, 300), (97, 131), (64, 64))[seed % 3]  # widths that are and are not multiples of 4
    img = _frame(seed, shape)
    dark = bool(seed % 2)
    start = factor // 2
    want = np.ascontiguousarray(img[start::factor, start::factor])
    low = 255 - want if dark else want
    assert reduced_shape(img.shape, factor) == low.shape
    sigma = subsample_sigma(img, factor)
    assert sigma == pytest.approx(mb.noise_sigma(want), abs=1e-12)
    block, offset = mb._local_level(low.shape, 50.0 + 300.0 * seed, factor, 20.0, sigma)
    level = cv2.add(cv2.blur(low, (block, block), borderType=cv2.BORDER_REPLICATE),
                    np.array([float(min(offset, 255))]))
    binary = cv2.compare(low, level, cv2.CMP_GT)
    _, _, stats, _ = cv2.connectedComponentsWithStats(binary, connectivity=8)
    whole = _banded(img, [0, low.shape[0]], factor=factor, dark=dark, block=block, offset=offset)
    assert np.array_equal(_sorted(whole), _sorted(stats[1:, :4].astype(np.int64)))
    h = low.shape[0]
    assert np.array_equal(_banded(img, [0, h // 3, 2 * h // 3, h], factor=factor, dark=dark, block=block,
                                  offset=offset), whole)
    assert np.array_equal(local_blobs(low, block, offset), whole)


def _banded(img: np.ndarray, edges: list[int], *, factor: int, dark: bool, block: int,
            offset: int) -> np.ndarray:
    """Boxes of ``img`` labelled in the bands between consecutive ``edges`` (reduced rows)."""
    runs = [band_runs(img, factor, dark, y0, y1, block, offset) for y0, y1 in itertools.pairwise(edges)]
    return join_boxes(runs, edges[:-1])


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**16), cuts=st.lists(st.floats(0.0, 1.0), min_size=1, max_size=4),
       block=st.sampled_from([3, 9, 21]))
def test_any_bands_give_the_boxes_of_one(seed: int, cuts: list[float], block: int) -> None:
    """Blobs straddling one or several band edges (bands down to one row) are found once, with the same
    boxes in the same order as in one band."""
    rng = np.random.default_rng(seed)
    img = (rng.random((60, 90)) * 30).astype(np.uint8)
    for _ in range(int(rng.integers(1, 30))):  # discs, rings and bars of any size, touching, at the edges
        y, x, r = rng.integers(0, 60), rng.integers(0, 90), rng.integers(1, 12)
        yy, xx = np.ogrid[:60, :90]
        d2 = (yy - y) ** 2 + (xx - x) ** 2
        shape = d2 <= r * r if rng.random() < 0.6 else (d2 <= r * r) & (d2 >= (r // 2) ** 2)
        img[shape] = rng.integers(60, 256)
    edges = sorted({0, 60, *(int(c * 60) for c in cuts)})
    whole = _banded(img, [0, 60], factor=1, dark=False, block=block, offset=10)
    assert np.array_equal(_banded(img, edges, factor=1, dark=False, block=block, offset=10), whole)


def test_find_candidates_compiled_equals_opencv_on_a_region_view() -> None:
    img = _frame(3, (240, 320), noise_dn=8.0)  # low noise: find_candidates subsamples (not averages)
    view = img[17:201, 9:290]  # not contiguous, width not a multiple of 4
    boxes = mb._blobs_opencv(view, dark=False, threshold=None, factor=4, max_area_px=2000.0,
                             min_contrast=40.0)
    sigma = subsample_sigma(np.ascontiguousarray(view), 4)
    assert 4.0 * sigma <= 0.5 * 40.0  # min_contrast
    low = np.ascontiguousarray(view[2::4, 2::4])
    block, offset = mb._local_level(low.shape, 2000.0, 4, 40.0, sigma)
    found = {tuple(b) for b in local_blobs(low, block, offset).tolist()}
    # every outer contour's box is a blob's; a blob inside another's hole is a candidate of its own here
    assert {tuple(b) for b in boxes.tolist()} <= found
    rows, cols, half = mb.find_candidates(view, dark=False, threshold=None, factor=4, min_area_px=80.0,
                                          max_area_px=2000.0, min_contrast=40.0, min_roundness=0.5)
    assert len(rows) == len(cols) == len(half) <= len(boxes)


def test_blobs_of_a_frame_full_of_them_equal_opencv() -> None:
    """Rows with many foreground pixels (box sums from prefix sums) and few (summed pixel by pixel), and
    thousands of runs (the run arrays grow): the same blobs as OpenCV's chain."""
    rng = np.random.default_rng(11)
    low = rng.integers(0, 256, (300, 400)).astype(np.uint8)
    low[150:] = (low[150:] // 8 + 20).astype(np.uint8)  # a quiet half with a few bright specks
    low[200:300:17, 30:380:23] = 250
    blobs = []
    for block, offset in ((3, 0), (9, 5), (39, 20)):
        level = cv2.add(cv2.blur(low, (block, block), borderType=cv2.BORDER_REPLICATE),
                        np.array([float(offset)]))
        binary = cv2.compare(low, level, cv2.CMP_GT)
        n, _, stats, _ = cv2.connectedComponentsWithStats(binary, connectivity=8)
        found = local_blobs(low, block, offset)
        assert np.array_equal(_sorted(found), _sorted(stats[1:, :4].astype(np.int64)))
        blobs.append(n - 1)
    assert max(blobs) > 1024  # more runs than the arrays' first size


@given(least=st.integers(0, 255 * 81 * 2 * 81 * 9), offset=st.integers(0, 255),
       block=st.sampled_from([3, 9, 39, 81]))
def test_least_level_is_the_first_pixel_value_that_can_pass(least: int, offset: int, block: int) -> None:
    area = block * block
    first = next((p for p in range(256) if p - offset >= 1 and least < (2 * (p - offset) - 1) * area), 256)
    assert _least_level(least, offset, area) == first
