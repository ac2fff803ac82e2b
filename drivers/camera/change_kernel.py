"""The duplicate test's change maps, compiled (numba): per frame, on every 4th 8×8 block (a 16-px grid);
over every block where a frame needs it (a still frame's largest change).

Bit for bit what OpenCV gives (``cv2.resize`` ``INTER_AREA`` by 2 rounds each 2×2 mean as
``(sum + 2) >> 2``; a block's change is the exact sum of its 4×4 half-size absolute differences / 16;
tests/test_camera_change_kernel.py): :func:`sampled_stats` reads a frame's sampled blocks as 64-bit words
(four half-size values at once) in one pass with the map's largest value and median, about half the time
of the whole map (:func:`half_change_stats`). Only for frames whose sides are multiples of 8 (the caller
crops the others).

Imported lazily by :mod:`drivers.camera.video_file` (numba's import is paid by the first frame, not by
importing the driver). Compiled code is cached on disk next to this file when that location is writable;
otherwise it is compiled once per process (a warning).
"""

from __future__ import annotations

import sys

import numpy as np
from numpy.typing import NDArray

from drivers.numba_kernel import nogil_kernel

__all__ = ["half_change_stats", "half_only", "motion_region", "region_changes", "sampled_half",
           "sampled_stats", "sampled_words"]

_LEVELS = 16 * 255 + 1  # a block's change × 16 is an integer sum of 16 absolute differences: 0 … 4080

_jit = nogil_kernel("change-map")


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


_LANES = np.uint64(0x00FF00FF00FF00FF)  # the low byte of each 16-bit lane of a 64-bit word


@_jit
def _sampled_kernel(image64: np.ndarray, prev32: np.ndarray, sampled32: np.ndarray, change: np.ndarray,
                    counts: np.ndarray) -> int:
    """``sampled32[r, j]`` ← the 4 half-size values of sampled row ``r`` in block (2·(r // 4), 2j) (every
    4th 8×8 block: even block rows and columns; 4 bytes, leftmost first), rounded as :func:`_half_rows`;
    unless ``change`` is empty, ``change[i, j]`` ← block (2i, 2j)'s mean |change| to ``prev32`` (the previous
    frame's ``sampled32``) and ``counts`` ← how many blocks have each change × 16; returns the largest
    change × 16 (0 without). ``image64``: the frame's rows as little-endian 64-bit words (8 pixels each).

    Four half-size values at once in a 64-bit word (16-bit lanes: sums of 4 pixels ≤ 1020 never carry
    into the next lane): a sampled block row reads one word from each of two image rows. Each row pair's
    words are first all reduced in order into ``halves`` (the odd words' values are not used): contiguous
    reads, which the compiler vectorises without gathers and the prefetcher follows — than reading every
    other word, 2.4× faster on a 1080p frame not in the cache, 5 % on one fresh from the decoder."""
    lanes, one, eight, sixteen = _LANES, np.uint64(1), np.uint64(8), np.uint64(16)
    rounding, offset = np.uint64(0x0002000200020002), np.uint64(0x0100010001000100)
    low9, low16 = np.uint64(0x1FF), np.uint64(0xFFFF)
    with_change = change.size > 0
    blocks_wide = sampled32.shape[1]
    column = np.zeros(blocks_wide, np.int32)
    halves = np.empty(image64.shape[1], np.uint64)  # lane i of word w: half column 4w + i
    counts[:] = 0
    largest = 0
    for r in range(sampled32.shape[0]):
        top = 2 * (r + 4 * (r >> 2))  # sampled row r is half row 8·(r // 4) + r % 4
        upper, lower = image64[top], image64[top + 1]
        for w in range(halves.shape[0]):
            a, b = upper[w], lower[w]
            pairs = (a & lanes) + (b & lanes) + ((a >> eight) & lanes) + ((b >> eight) & lanes)
            halves[w] = ((pairs + rounding) >> (one + one)) & lanes
        for j in range(blocks_wide):
            half = halves[2 * j]  # image columns 16j … 16j+7: half columns 8j … 8j+3
            packed = half | (half >> eight)
            high = (packed >> (sixteen + sixteen)) & low16
            sampled32[r, j] = np.uint32((packed & low16) | (high << sixteen))
            if with_change:
                p = np.uint64(prev32[r, j])
                spread = ((p & np.uint64(0xFF)) | ((p & np.uint64(0xFF00)) << eight)
                          | ((p & np.uint64(0xFF0000)) << sixteen)
                          | ((p & np.uint64(0xFF000000)) << np.uint64(24)))
                d = (half + offset) - spread  # lane i: 256 + half − previous, within [1, 511]: no borrow
                column[j] += (abs(np.int32(d & low9) - 256) + abs(np.int32((d >> sixteen) & low9) - 256)
                              + abs(np.int32((d >> np.uint64(32)) & low9) - 256)
                              + abs(np.int32((d >> np.uint64(48)) & low9) - 256))
        if with_change and r % 4 == 3:
            for j in range(blocks_wide):
                total = column[j]
                change[r >> 2, j] = np.float32(total) * np.float32(0.0625)
                largest = max(largest, total)
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


def half_only(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """The half-size image (uint8) of ``image`` (sides multiples of 8)."""
    h, w = image.shape
    half = np.empty((h // 2, w // 2), np.uint8)
    _half_kernel(np.ascontiguousarray(image), half)
    return half


def _check_sampled(image: NDArray[np.uint8]) -> None:
    h, w = image.shape
    if h % 8 or w % 8:
        raise ValueError(f"an image of {(h, w)} px; the sampled blocks need sides multiples of 8")
    if sys.byteorder != "little":  # the kernel reads 8 pixels as one little-endian word
        raise NotImplementedError("the sampled change kernel needs a little-endian machine")


@_jit
def _sampled_pass(image: np.ndarray, prev32: np.ndarray, with_change: bool,
                  ) -> tuple[np.ndarray, np.ndarray, int, float]:
    """(the packed sampled image as 32-bit words (4 half-size values each), its change map to ``prev32``
    (a previous frame's), the map's largest value × 16, its median × 16) of a C-contiguous ``image``
    (sides multiples of 8), in one call: a frame's Python is tens of microseconds per numpy call after its
    decoding; without ``with_change`` the sampled image only (an empty map, 0, 0)."""
    h, w = image.shape
    sampled32 = np.empty((4 * ((h // 8 + 1) // 2), (w // 8 + 1) // 2), np.uint32)
    if not with_change:
        _sampled_kernel(image.view(np.uint64), sampled32, sampled32, np.empty((0, 0), np.float32),
                        np.empty(1, np.int64))
        return sampled32, np.empty((0, 0), np.float32), 0, 0.0
    change = np.empty((sampled32.shape[0] // 4, sampled32.shape[1]), np.float32)
    counts = np.empty(_LEVELS, np.int64)
    largest = _sampled_kernel(image.view(np.uint64), prev32, sampled32, change, counts)
    return sampled32, change, largest, _median_of_counts(counts)


def sampled_words(image: NDArray[np.uint8], prev_words: NDArray[np.uint32] | None,
                  ) -> tuple[NDArray[np.uint32], NDArray[np.float32], float, float]:
    """:func:`sampled_stats` (or :func:`sampled_half` when ``prev_words`` is None: an empty map, 0, 0) for a
    C-contiguous ``image`` (sides multiples of 8, unchecked: the video reader's per-frame call), the sampled
    image as 32-bit words — ``sampled.view(np.uint32)`` —, which the next frame's call takes as
    ``prev_words``."""
    if prev_words is None:
        return _sampled_pass(image, np.empty((0, 0), np.uint32), False)
    sampled32, change, largest, median = _sampled_pass(image, prev_words, True)
    return sampled32, change, largest / 16, median / 16


def sampled_half(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """The half-size image on every 4th 8×8 block of ``image`` (sides multiples of 8), packed as
    :func:`sampled_stats` gives it."""
    _check_sampled(image)
    sampled32: NDArray[np.uint32] = sampled_words(np.ascontiguousarray(image), None)[0]
    return sampled32.view(np.uint8)


def sampled_stats(image: NDArray[np.uint8], prev_sampled: NDArray[np.uint8],
                  ) -> tuple[NDArray[np.uint8], NDArray[np.float32], float, float]:
    """(the half-size image on every 4th 8×8 block — even block rows and columns, the blocks
    ``change[::2, ::2]`` of :func:`half_change_stats` — packed: block (2i, 2j) at rows 4i … 4i+3, columns
    4j … 4j+3; those blocks' change map to ``prev_sampled``, DN; its largest value; its median) of
    ``image`` (sides multiples of 8): ``change[::2, ::2]``, its maximum and the noise floor of
    :func:`half_change_stats` bit for bit, from half the frame's rows and a quarter of its pixels (about
    half the time of the whole map)."""
    _check_sampled(image)
    h, w = image.shape
    expected = (4 * ((h // 8 + 1) // 2), 4 * ((w // 8 + 1) // 2))
    if prev_sampled.shape != expected:
        raise ValueError(f"prev_sampled has shape {prev_sampled.shape}; expected {expected} for a frame "
                         f"of {image.shape}")
    sampled32, change, largest_dn, floor_dn = sampled_words(
        np.ascontiguousarray(image), np.ascontiguousarray(prev_sampled).view(np.uint32))
    return sampled32.view(np.uint8), change, largest_dn, floor_dn


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


@_jit
def _motion_region_kernel(before: np.ndarray, after: np.ndarray, before_limit: np.float32,
                          after_limit: np.float32, marked: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(block rows, block columns), row-major, of the blocks of a frame (``marked``: False, its blocks'
    shape) within one block of a sampled block (2i, 2j) with ``before[i, j] >= before_limit`` or
    ``after[i, j] >= after_limit``."""
    rows, cols = marked.shape
    count = 0
    for i in range(before.shape[0]):
        for j in range(before.shape[1]):
            if before[i, j] >= before_limit or after[i, j] >= after_limit:
                for r in range(max(2 * i - 1, 0), min(2 * i + 2, rows)):
                    for c in range(max(2 * j - 1, 0), min(2 * j + 2, cols)):
                        if not marked[r, c]:
                            marked[r, c] = True
                            count += 1
    out_rows = np.empty(count, np.intp)
    out_cols = np.empty(count, np.intp)
    k = 0
    for r in range(rows):
        for c in range(cols):
            if marked[r, c]:
                out_rows[k], out_cols[k] = r, c
                k += 1
    return out_rows, out_cols


@_jit
def _region_changes_kernel(images: tuple[np.ndarray, ...], rows: np.ndarray, cols: np.ndarray,
                           pairs: np.ndarray, out: np.ndarray) -> None:
    """``out[p, b]`` ← mean |half(images[pairs[p, 1]]) − half(images[pairs[p, 0]])| over 8×8 block
    (``rows[b]``, ``cols[b]``) (the half-size values rounded as :func:`_half_rows`)."""
    halves = np.empty((len(images), 16), np.int32)
    for b in range(rows.shape[0]):
        top, left = 8 * rows[b], 8 * cols[b]
        for k in range(len(images)):  # a literal_unroll is not needed: the images share one type
            image = images[k]
            for y in range(4):
                for x in range(4):
                    r, c = top + 2 * y, left + 2 * x
                    pixels = (np.int32(image[r, c]) + np.int32(image[r + 1, c]) + np.int32(image[r, c + 1])
                              + np.int32(image[r + 1, c + 1]))
                    halves[k, 4 * y + x] = (pixels + 2) >> 2
        for p in range(pairs.shape[0]):
            total = 0
            for v in range(16):
                total += abs(halves[pairs[p, 1], v] - halves[pairs[p, 0], v])
            out[p, b] = np.float32(total) * np.float32(0.0625)


def motion_region(before: NDArray[np.float32], after: NDArray[np.float32], before_limit: float,
                  after_limit: float, shape: tuple[int, int]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """(block rows, block columns), row-major, of the blocks of a frame of ``shape`` blocks (rows, columns)
    within one block of a sampled block (2i, 2j) — ``before`` and ``after``: every 4th block's change maps
    (DN, :func:`sampled_stats`) — whose change before reaches ``before_limit`` or after ``after_limit`` (DN,
    compared in float32 as numpy compares a float32 map with a Python float)."""
    return _motion_region_kernel(np.ascontiguousarray(before, np.float32),
                                 np.ascontiguousarray(after, np.float32), np.float32(before_limit),
                                 np.float32(after_limit), np.zeros(shape, np.bool_))


def region_changes(images: tuple[NDArray[np.uint8], ...], rows: NDArray[np.intp], cols: NDArray[np.intp],
                   pairs: NDArray[np.int64]) -> NDArray[np.float32]:
    """Block change maps (DN, float32) over the 8×8 blocks (``rows[b]``, ``cols[b]``) of same-sized
    ``images`` (sides multiples of 8): row p is mean |half(images[pairs[p, 1]]) − half(images[pairs[p,
    0]])| per block, the numbers of :func:`half_change_stats`' map there, in one pass."""
    shape = images[0].shape
    if any(image.shape != shape for image in images) or shape[0] % 8 or shape[1] % 8:
        raise ValueError(f"images of shapes {[image.shape for image in images]}; the region's blocks need "
                         "one size, sides multiples of 8")
    out = np.empty((len(pairs), len(rows)), np.float32)
    _region_changes_kernel(tuple(np.ascontiguousarray(image) for image in images),
                           np.ascontiguousarray(rows, np.intp), np.ascontiguousarray(cols, np.intp),
                           np.ascontiguousarray(pairs, np.int64), out)
    return out
