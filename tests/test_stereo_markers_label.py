"""The compiled binarization (rig.stereo.markers_label) finds the blobs OpenCV's chain finds."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rig.stereo import markers_binarize as mb
from rig.stereo.markers_label import local_blobs, subsample_noise


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
def test_subsample_noise_and_blobs_equal_opencv(seed: int, factor: int) -> None:
    shape = ((200, 300), (97, 131), (64, 64))[seed % 3]  # widths that are and are not multiples of 4
    img = _frame(seed, shape)
    dark = bool(seed % 2)
    low, sigma = subsample_noise(img, factor, dark)
    start = factor // 2
    want = img[start::factor, start::factor]
    assert np.array_equal(low, 255 - want if dark else want)
    assert sigma == pytest.approx(mb.noise_sigma(np.ascontiguousarray(want)), abs=1e-12)
    block, offset = mb._local_level(low.shape, 50.0 + 300.0 * seed, factor, 20.0, sigma)
    level = cv2.add(cv2.blur(low, (block, block), borderType=cv2.BORDER_REPLICATE),
                    np.array([float(min(offset, 255))]))
    binary = cv2.compare(low, level, cv2.CMP_GT)
    _, _, stats, _ = cv2.connectedComponentsWithStats(binary, connectivity=8)
    found = local_blobs(low, block, offset)
    assert np.array_equal(_sorted(found), _sorted(stats[1:, :4].astype(np.int64)))


def test_find_candidates_compiled_equals_opencv_on_a_region_view() -> None:
    img = _frame(3, (240, 320), noise_dn=8.0)  # low noise: find_candidates subsamples (not averages)
    view = img[17:201, 9:290]  # not contiguous, width not a multiple of 4
    boxes = mb._blobs_opencv(view, dark=False, threshold=None, factor=4, max_area_px=2000.0,
                             min_contrast=40.0)
    low, sigma = subsample_noise(np.ascontiguousarray(view), 4, False)
    assert 4.0 * sigma <= 0.5 * 40.0  # min_contrast
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
