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

__all__ = ["half_and_change", "half_only"]

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
def _half_change_kernel(image: np.ndarray, prev_half: np.ndarray, half: np.ndarray,
                        change: np.ndarray) -> None:
    """``half`` ← the half-size ``image``; ``change`` ← mean |half − prev_half| per 4×4 half-size block."""
    width = half.shape[1]
    column = np.zeros(width, np.int32)  # |half − prev_half| summed over the block row's 4 rows
    pairs = np.empty(image.shape[1], np.int16)
    for r in range(half.shape[0]):
        _half_rows(image, half, r, pairs)
        for q in range(width):
            column[q] += abs(np.int32(half[r, q]) - np.int32(prev_half[r, q]))
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


def half_and_change(image: NDArray[np.uint8], prev_half: NDArray[np.uint8],
                    ) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
    """(half-size image, 8×8-block change map in DN to ``prev_half``, the previous frame's half-size image)
    of ``image`` (sides multiples of 8)."""
    h, w = image.shape
    if prev_half.shape != (h // 2, w // 2):
        raise ValueError(f"prev_half has shape {prev_half.shape}; expected {(h // 2, w // 2)} for a frame of "
                         f"{(h, w)}")
    half = np.empty((h // 2, w // 2), np.uint8)
    change = np.empty((h // 8, w // 8), np.float32)
    _half_change_kernel(np.ascontiguousarray(image), np.ascontiguousarray(prev_half), half, change)
    return half, change
