"""The duplicate test's per-frame images in one compiled pass (numba): the half-size image and the 8×8-block
change map to the previous frame's half-size image.

Bit for bit what :mod:`drivers.camera.video_file`'s OpenCV path gives (``cv2.resize`` ``INTER_AREA`` by 2
rounds each 2×2 mean as ``(sum + 2) >> 2``; the block change is the exact sum of the 4×4 half-size absolute
differences / 16), in one read of the frame instead of six array passes (resize, absdiff, two casts, two
reductions): about a third of the duplicate test's cost. Only for frames whose sides are multiples of 8
(every common video size); the caller keeps OpenCV for the others.

Imported lazily by :mod:`drivers.camera.video_file` (numba's import is paid by the first frame, not by
importing the driver). Compiled code is cached on disk next to this file when that location is writable;
otherwise it is compiled once per process (a warning).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba
import numpy as np
from numpy.typing import NDArray

__all__ = ["block_change", "half_and_change", "half_change_stats", "half_only"]

_LEVELS = 16 * 255 + 1  # a block's change × 16 is an integer sum of 16 absolute differences: 0 … 4080

_F = TypeVar("_F", bound=Callable[..., Any])


def _jit(fn: _F) -> _F:
    """numba.njit (no GIL: both videos' threads run it at once) with the on-disk cache where writable."""
    try:
        return cast(_F, numba.njit(cache=True, nogil=True)(fn))
    except RuntimeError as exc:  # numba: "cannot cache function ...: no locator available"
        warnings.warn(f"change-map kernel not cached on disk ({exc}); compiling it in this process",
                      RuntimeWarning, stacklevel=2)
        return cast(_F, numba.njit(nogil=True)(fn))


@_jit
def _half_rows(image: np.ndarray, half: np.ndarray, r: int, pairs: np.ndarray) -> None:
    """Half-size row ``r`` of ``image`` into ``half``: the 2×2 means rounded as OpenCV's INTER_AREA
    (``pairs``: a work row of the image's width)."""
    top, bottom = 2 * r, 2 * r + 1
    for x in range(pairs.shape[0]):  # vertical pairs first: contiguous, vectorised
        pairs[x] = np.int16(image[top, x]) + np.int16(image[bottom, x])
    for q in range(half.shape[1]):
        half[r, q] = (pairs[2 * q] + pairs[2 * q + 1] + 2) >> 2


@_jit
def _half_kernel(image: np.ndarray, half: np.ndarray) -> None:
    pairs = np.empty(image.shape[1], np.int16)
    for r in range(half.shape[0]):
        _half_rows(image, half, r, pairs)


@_jit
def _half_change_kernel(image: np.ndarray, prev_half: np.ndarray, half: np.ndarray, change: np.ndarray,
                        counts: np.ndarray) -> int:
    """``half`` ← the half-size ``image``; ``change`` ← mean |half − prev_half| per 4×4 half-size block;
    ``counts`` ← how many of every 4th block (even block rows and columns) have each change × 16; returns
    the largest change × 16."""
    width = half.shape[1]
    column = np.zeros(width, np.int32)  # |half − prev_half| summed over the block row's 4 rows
    pairs = np.empty(image.shape[1], np.int16)
    counts[:] = 0
    largest = 0
    for r in range(half.shape[0]):
        _half_rows(image, half, r, pairs)
        for q in range(width):
            column[q] += abs(np.int32(half[r, q]) - np.int32(prev_half[r, q]))
        if r % 4 == 3:
            for j in range(change.shape[1]):
                total = column[4 * j] + column[4 * j + 1] + column[4 * j + 2] + column[4 * j + 3]
                change[r >> 2, j] = np.float32(total) * np.float32(0.0625)
                largest = max(largest, total)
                if (r >> 2) % 2 == 0 and j % 2 == 0:
                    counts[total] += 1
            column[:] = 0
    return largest


@_jit
def _median_of_counts(counts: np.ndarray) -> float:
    """The median (× 16) of the values whose occurrences ``counts`` holds (mean of the middle two when
    their number is even), as ``np.median``."""
    n = counts.sum()
    k = n // 2
    seen = 0
    low = -1
    for value in range(counts.shape[0]):
        seen += counts[value]
        if low < 0 and seen >= k:  # rank k−1 (0-based) reached: the lower middle value
            low = value
        if seen > k:  # rank k: the upper middle value
            return float(value) if n % 2 else 0.5 * (float(low) + float(value))
    return 0.0


@_jit
def _block_change_kernel(a_half: np.ndarray, b_half: np.ndarray, change: np.ndarray) -> None:
    """``change`` ← mean |a_half − b_half| per 4×4 block."""
    width = a_half.shape[1]
    column = np.zeros(width, np.int32)
    for r in range(a_half.shape[0]):
        for q in range(width):
            column[q] += abs(np.int32(a_half[r, q]) - np.int32(b_half[r, q]))
        if r % 4 == 3:
            for j in range(change.shape[1]):
                change[r >> 2, j] = np.float32(column[4 * j] + column[4 * j + 1] + column[4 * j + 2]
                                               + column[4 * j + 3]) * np.float32(0.0625)
            column[:] = 0


def half_only(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """The half-size image (uint8) of ``image`` (sides multiples of 8)."""
    h, w = image.shape
    half = np.empty((h // 2, w // 2), np.uint8)
    _half_kernel(np.ascontiguousarray(image), half)
    return half


def half_change_stats(image: NDArray[np.uint8], prev_half: NDArray[np.uint8],
                      ) -> tuple[NDArray[np.uint8], NDArray[np.float32], float, float]:
    """(half-size image, 8×8-block change map in DN to ``prev_half`` — the previous frame's half-size
    image —, the map's largest value, the median of every 4th block ``change[::2, ::2]``) of ``image``
    (sides multiples of 8). The two statistics are the duplicate test's, counted in the same pass."""
    h, w = image.shape
    if prev_half.shape != (h // 2, w // 2):
        raise ValueError(f"prev_half has shape {prev_half.shape}; expected {(h // 2, w // 2)} for a frame of "
                         f"{(h, w)}")
    half = np.empty((h // 2, w // 2), np.uint8)
    change = np.empty((h // 8, w // 8), np.float32)
    counts = np.empty(_LEVELS, np.int64)
    largest = _half_change_kernel(np.ascontiguousarray(image), np.ascontiguousarray(prev_half), half, change,
                                  counts)
    return half, change, largest / 16, _median_of_counts(counts) / 16


def half_and_change(image: NDArray[np.uint8], prev_half: NDArray[np.uint8],
                    ) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
    """(half-size image, 8×8-block change map in DN to ``prev_half``, the previous frame's half-size image)
    of ``image`` (sides multiples of 8)."""
    half, change, _, _ = half_change_stats(image, prev_half)
    return half, change


def block_change(a_half: NDArray[np.uint8], b_half: NDArray[np.uint8]) -> NDArray[np.float32]:
    """Mean |a_half − b_half| per 4×4 block of two half-size images (sides multiples of 4), DN."""
    if a_half.shape != b_half.shape or a_half.shape[0] % 4 or a_half.shape[1] % 4:
        raise ValueError(f"half-size images of shapes {a_half.shape} and {b_half.shape}; expected one shape "
                         "with sides multiples of 4")
    change = np.empty((a_half.shape[0] // 4, a_half.shape[1] // 4), np.float32)
    _block_change_kernel(np.ascontiguousarray(a_half), np.ascontiguousarray(b_half), change)
    return change
