"""Compiled binarization of a frame into marker candidates: the usual case of
:func:`rig.stereo.markers_binarize.find_candidates` in one call.

The usual case is the local threshold on a subsampled frame (``threshold=None``, reduction ×2 or ×4 with
low noise). One pass over the reduced frame computes what OpenCV's chain computed in five calls and a
Python loop: the subsample (``gray[s::f, s::f]``), its noise σ (as
:func:`~rig.stereo.markers_binarize.noise_sigma`), the box mean of ``block`` × ``block`` reduced pixels
(edges replicated, as ``cv2.blur`` with ``BORDER_REPLICATE``: column sums updated row by row, a running
sum along each row), the comparison ``pixel > round(mean) + offset`` (without a division: ``2·sum <
(2·(pixel − offset) − 1)·area``, exact since the area is odd), and the 8-connected blobs' bounding boxes
(runs of each row joined to the overlapping runs of the row above, union–find). A blob inside another's
hole is a blob of its own here (``cv2.findContours(RETR_EXTERNAL)`` skipped it): one more candidate,
measured and filtered like the others.

The frame can be labelled in row bands (:func:`band_runs`, one per thread: numba ``nogil``), each
subsampling the rows its box sums need; :func:`join_boxes` then joins the runs of each band's first row
to those of the row above it, so a blob straddling a band edge is one blob, and the boxes — in the
order of their first run, as in one band — are the same whatever the bands.

Imported by the first detection (numba is not loaded by ``import rig.stereo``); compiled code cached on
disk as :mod:`rig.stereo.markers_kernel` explains.
"""

from __future__ import annotations

import sys

import numpy as np

from rig.stereo.markers_kernel import _stage, jit_kernel

_LITTLE_ENDIAN = sys.byteorder == "little"  # the 32-bit-word subsample reads byte 2 of a word


def reduced_shape(shape: tuple[int, ...], factor: int) -> tuple[int, int]:
    """Shape of ``gray[s::factor, s::factor]`` (s = factor // 2) for a frame of ``shape``."""
    start = factor // 2
    return (shape[0] - start + factor - 1) // factor, (shape[1] - start + factor - 1) // factor


@jit_kernel
def subsample_sigma(gray: np.ndarray, factor: int) -> float:
    """Noise σ (DN) of ``gray[s::factor, s::factor]`` (s = factor // 2), read from ``gray`` itself:
    1.4826 · median |horizontal difference| / √2 over every 32nd reduced row, at least 0.5 (as
    :func:`rig.stereo.markers_binarize.noise_sigma`; the same for either polarity)."""
    start = factor // 2
    height, width = gray.shape
    h, w = (height - start + factor - 1) // factor, (width - start + factor - 1) // factor
    hist = np.zeros(256, np.int64)
    n = 0
    for i in range(0, h, 32):
        src = gray[start + i * factor]
        for j in range(w - 1):
            hist[abs(np.int64(src[start + (j + 1) * factor]) - np.int64(src[start + j * factor]))] += 1
            n += 1
    half, seen, median = n / 2.0, 0, 0
    while median < 255 and seen + hist[median] < half:
        seen += hist[median]
        median += 1
    return max(1.4826 * median / float(np.sqrt(2.0)), 0.5)


@_stage
def _subsample_rows(gray: np.ndarray, factor: int, dark: bool, r0: int, low: np.ndarray) -> None:
    """Reduced rows r0 … r0 + len(low) − 1 of ``gray`` (C-contiguous): ``gray[s::factor, s::factor]``
    (s = factor // 2; 255 − value when ``dark``) into ``low``."""
    start = factor // 2
    w = low.shape[1]
    words = _LITTLE_ENDIAN and factor == 4 and gray.shape[1] % 4 == 0
    for i in range(low.shape[0]):
        src, dst = gray[start + (r0 + i) * factor], low[i]
        if words:  # byte 2 of each little-endian 32-bit word (vectorized)
            packed = src.view(np.uint32)
            for j in range(w):
                dst[j] = (packed[j] >> 16) & 0xFF
        else:
            for j in range(w):
                dst[j] = src[start + j * factor]
        if dark:
            for j in range(w):
                dst[j] = 255 - dst[j]


@_stage
def _find(parent: np.ndarray, k: int) -> int:
    while parent[k] != k:
        parent[k] = parent[parent[k]]
        k = parent[k]
    return k


@jit_kernel
def _grown(a: np.ndarray, size: int) -> np.ndarray:
    """``a`` (1-D int64) copied into the start of a new array of ``size``."""
    out = np.empty(size, np.int64)
    out[:len(a)] = a
    return out


@_stage
def _row_runs(  # noqa: PLR0917 (numba: no keyword-only arguments)
        fg: np.ndarray, y: int, runs: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], n_runs: int,
        prev_lo: int, prev_hi: int) -> int:
    """The runs of row ``y``'s foreground ``fg`` (its last element 0, its length a multiple of 8)
    appended to ``runs`` (row, first and last column, union–find parent; room for them) from index
    ``n_runs``, each joined to the runs ``prev_lo … prev_hi − 1`` of the row above that touch it
    (8-connected); returns the new run count."""
    run_y, run_a, run_b, parent = runs
    start = -1
    words = fg.view(np.uint64)
    x = 0
    while x < len(fg):
        if start < 0 and words[x // 8] == 0:  # x % 8 == 0 here: eight background pixels, skipped
            x += 8
            continue
        for i in range(x, x + 8):
            if fg[i] and start < 0:
                start = i
            elif not fg[i] and start >= 0:  # a run start..i−1
                run_y[n_runs], run_a[n_runs], run_b[n_runs] = y, start, i - 1
                parent[n_runs] = n_runs
                for q in range(prev_lo, prev_hi):
                    if run_a[q] <= i and run_b[q] >= start - 1:
                        a, b = _find(parent, q), _find(parent, n_runs)
                        if a != b:
                            parent[max(a, b)] = min(a, b)
                n_runs += 1
                start = -1
        x += 8
    return n_runs


@_stage
def _least_level(least_twice_sum: int, offset: int, area: int) -> int:
    """The smallest pixel value p (capped at 256: none) with v = p − offset ≥ 1 and (2v − 1)·area above
    ``least_twice_sum`` (≥ 0): a pixel below it is background whatever its box sum (the test is monotone
    in p). In integers: (2v − 1)·area > s ⇔ 2v − 1 > ⌊s / area⌋ ⇔ v ≥ (⌊s / area⌋ + 3) // 2."""
    return min(offset + max(1, (least_twice_sum // area + 3) // 2), 256)


@_stage
def _box_sum(col: np.ndarray, x: int, r: int) -> int:
    """Sum of the column sums ``col[x − r … x + r]``, edges replicated."""
    w = len(col)
    total = 0
    if x - r >= 0 and x + r < w:  # inside: no clamping (vectorized)
        for t in range(x - r, x + r + 1):
            total += col[t]
        return total
    for t in range(x - r, x + r + 1):
        total += col[min(max(t, 0), w - 1)]
    return total


@_stage
def _foreground(  # noqa: PLR0917 (numba: no keyword-only arguments)
        row: np.ndarray, col: np.ndarray, r: int, offset: int, area: int, prefix: np.ndarray,
        fg: np.ndarray) -> int:
    """``fg[x]`` = pixel x of ``row`` is brighter than the rounded mean of its box (column sums ``col`` of
    the box's rows, 2r + 1 columns, edges replicated) plus ``offset``; returns how many are (0: ``fg``
    left as it was).

    First the pixels that could be, against the smallest possible box sum, (2r + 1) × the smallest column
    sum: those at or above one level (:func:`_least_level`). Most rows of a frame of markers have none
    (their maximum is below it: the row is done) or a few (their box sums are added up, sliding along
    runs of neighbours); a row with many gets the box sums of every pixel from prefix sums of its column
    sums (``prefix``: scratch, w + 2r + 2)."""
    w = len(row)
    block = 2 * r + 1
    least = col[0]
    for x in range(w):  # vectorized (a third of col.min()'s time)
        least = min(least, col[x])
    level = _least_level(2 * block * int(least), offset, area)
    top = np.uint8(0)
    for x in range(w):  # vectorized in uint8 (a fifth of the time in int64)
        top = max(top, row[x])
    if int(top) < level:
        return 0
    low = np.uint8(level)
    count = 0
    for x in range(w):
        on = row[x] >= low
        fg[x] = on
        count += on
    if count <= w // 16:
        count, last, total = 0, -2, 0
        for x in range(w):
            if fg[x]:
                if x == last + 1:  # slide the box one column
                    total += col[min(x + r, w - 1)] - col[max(x - r - 1, 0)]
                else:
                    total = _box_sum(col, x, r)
                last = x
                on = 2 * total < (2 * (int(row[x]) - offset) - 1) * area
                fg[x] = on
                count += on
        return count
    off32, area32 = np.int32(offset), np.int32(area)
    running = np.int32(0)
    for i in range(r):  # the left edge replicated
        running += col[0]
        prefix[i + 1] = running
    for x in range(w):
        running += col[x]
        prefix[r + x + 1] = running
    for i in range(r + w, w + 2 * r + 1):  # the right edge replicated
        running += col[w - 1]
        prefix[i + 1] = running
    count = 0
    for x in range(w):  # branch-free: vectorized
        v = np.int32(row[x]) - off32
        twice_sum = np.int32(2) * (prefix[x + block] - prefix[x])
        on = (v >= 1) & (twice_sum < (np.int32(2) * v - np.int32(1)) * area32)
        fg[x] = on
        count += on
    return count


@jit_kernel
def band_runs(  # noqa: PLR0917 (numba: no keyword-only arguments)
        gray: np.ndarray, factor: int, dark: bool, y0: int, y1: int, block: int,
        offset: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Foreground runs of the reduced rows ``y0 … y1 − 1`` of ``gray`` (C-contiguous; reduced as
    :func:`_subsample_rows`): pixels brighter than the rounded mean of their ``block`` × ``block``
    neighbourhood (odd, edges replicated) plus ``offset`` DN, 8-connected within the band.

    Returns (row, first column, last column, root) int64 arrays, one element per run in row-major order;
    root: the index of the first run of its blob within the band (a union–find forest of roots)."""
    height, width = gray.shape
    h, w = (height - factor // 2 + factor - 1) // factor, (width - factor // 2 + factor - 1) // factor
    r = block // 2
    area = block * block
    b0, b1 = max(y0 - r, 0), min(y1 + r, h)  # the reduced rows the band's box sums read
    low = np.empty((b1 - b0, w), np.uint8)
    _subsample_rows(gray, factor, dark, b0, low)
    # int32 throughout (vectorized; sums ≤ 255·block·(w + block) < 2³¹ for any frame up to 8k × 8k)
    col = np.zeros(w, np.int32)  # column sums of rows y0 − r … y0 + r, edges replicated
    for i in range(y0 - r, y0 + r + 1):
        src = low[min(max(i, 0), h - 1) - b0]
        for x in range(w):
            col[x] += np.int32(src[x])
    # the runs and their union–find parents, grown as needed (the largest possible count, h·w/2, is
    # 2 MB for a 1080p frame reduced ×4: allocating that each call cost more than the labelling)
    run_y, run_a = np.empty(1024, np.int64), np.empty(1024, np.int64)
    run_b, parent = np.empty(1024, np.int64), np.empty(1024, np.int64)
    prefix = np.zeros(w + 2 * r + 2, np.int32)  # prefix sums of the column sums, edges replicated
    # the row's foreground (fg[w:] stays 0: a run ends there; whole 64-bit words, skipped when 0)
    fg = np.zeros((w + 8) // 8 * 8, np.uint8)
    n_runs, prev_lo, prev_hi = 0, 0, 0
    for y in range(y0, y1):
        if y > y0:  # column sums of rows y − r … y + r
            add, sub = low[min(y + r, h - 1) - b0], low[max(y - r - 1, 0) - b0]
            for x in range(w):
                col[x] += np.int32(add[x]) - np.int32(sub[x])
        if _foreground(low[y - b0], col, r, offset, area, prefix, fg) == 0:
            prev_lo = prev_hi = n_runs
            continue
        if n_runs + (w + 1) // 2 > len(run_y):  # room for the most runs a row can have
            size = 2 * len(run_y) + w
            run_y, run_a, run_b, parent = (_grown(run_y, size), _grown(run_a, size), _grown(run_b, size),
                                           _grown(parent, size))
        this_lo = n_runs
        n_runs = _row_runs(fg, y, (run_y, run_a, run_b, parent), n_runs, prev_lo, prev_hi)
        prev_lo, prev_hi = this_lo, n_runs
    for k in range(n_runs):
        parent[k] = _find(parent, k)
    return run_y[:n_runs], run_a[:n_runs], run_b[:n_runs], parent[:n_runs]


@jit_kernel
def _joined(runs: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
            below: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
            edge_y: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The runs of two bands, ``runs`` above ``below`` whose first row is ``edge_y``, in one forest:
    each run of row ``edge_y`` joined to the runs of row ``edge_y − 1`` that touch it (8-connected)."""
    n_a, n_b = len(runs[0]), len(below[0])
    run_y, run_a = np.concatenate((runs[0], below[0])), np.concatenate((runs[1], below[1]))
    run_b, parent = np.concatenate((runs[2], below[2])), np.concatenate((runs[3], below[3] + n_a))
    first = n_a  # the runs of row edge_y − 1 are the last of the upper band's
    while first > 0 and run_y[first - 1] == edge_y - 1:
        first -= 1
    for k in range(n_a, n_a + n_b):
        if run_y[k] != edge_y:
            break
        for q in range(first, n_a):
            if run_a[q] <= run_b[k] + 1 and run_b[q] >= run_a[k] - 1:
                a, b = _find(parent, q), _find(parent, k)
                if a != b:
                    parent[max(a, b)] = min(a, b)
    return run_y, run_a, run_b, parent


@jit_kernel
def _boxes(runs: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """Bounding boxes (B, 4) int64 (x0, y0, width, height) of the blobs of ``runs`` (row-major order;
    :func:`band_runs`), in the order of each blob's first run."""
    run_y, run_a, run_b, parent = runs
    n_runs = len(run_y)
    boxes = np.empty((n_runs, 4), np.int64)
    slot = np.full(n_runs, -1, np.int64)
    n_blobs = 0
    for k in range(n_runs):
        root = _find(parent, k)
        if slot[root] < 0:
            slot[root] = n_blobs
            boxes[n_blobs] = (run_a[k], run_y[k], run_b[k], run_y[k])
            n_blobs += 1
        b = boxes[slot[root]]
        b[0], b[1] = min(b[0], run_a[k]), min(b[1], run_y[k])
        b[2], b[3] = max(b[2], run_b[k]), max(b[3], run_y[k])
    out = boxes[:n_blobs].copy()
    out[:, 2] = out[:, 2] - out[:, 0] + 1
    out[:, 3] = out[:, 3] - out[:, 1] + 1
    return out


def join_boxes(bands: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
               first_rows: list[int]) -> np.ndarray:
    """Bounding boxes (B, 4) int64 (x0, y0, width, height; reduced px) of the blobs of consecutive
    bands' runs (:func:`band_runs`; ``first_rows``: each band's first reduced row), a blob straddling
    band edges counted once; the same boxes, in the same order, for any split into bands."""
    runs = bands[0]
    for below, edge_y in zip(bands[1:], first_rows[1:], strict=True):
        runs = _joined(runs, below, edge_y)
    return _boxes(runs)


def local_blobs(low: np.ndarray, block: int, offset: int) -> np.ndarray:
    """Bounding boxes (B, 4) int64 (x0, y0, width, height) of the 8-connected blobs of pixels of ``low``
    brighter than the rounded mean of their ``block`` × ``block`` neighbourhood (odd, edges replicated)
    plus ``offset`` DN: one band, without reduction."""
    return _boxes(band_runs(np.ascontiguousarray(low), 1, False, 0, low.shape[0], block, offset))
