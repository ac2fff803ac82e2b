"""One frame's marker work split over threads: a small persistent pool for the compiled kernels.

The marker kernels are compiled with numba ``nogil=True``: while one runs, other Python threads run too,
so the parts of a frame (row bands of the binarization, halves of the windows to measure) go to
``threads`` threads at once — the calling thread takes the first part, the pool's threads the others.
Each part writes only its own outputs, so the results are those of one thread, bit for bit.

The pool is created on first use (and grown when a call asks for more threads), shared by every caller
of the process, and recreated in a child process after ``fork`` (a forked child has no threads).
:func:`check_threads` is the option's check; 1 (the default everywhere) uses no pool: the right choice
where each camera already has a core (``rig measure`` reduces the two cameras' frames in parallel).
"""

from __future__ import annotations

import itertools
import os
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor, wait
from typing import Any, TypeVar

from rig.stereo.errors import InputArrayError

_T = TypeVar("_T")
MAX_THREADS = 64

_lock = threading.Lock()
_pool: ThreadPoolExecutor | None = None
_pool_workers = 0


def check_threads(threads: object) -> int:
    """``threads`` as an int if it is an integer 1 … MAX_THREADS, else InputArrayError saying why."""
    if isinstance(threads, bool) or not isinstance(threads, int) or not 1 <= threads <= MAX_THREADS:
        raise InputArrayError(
            f"threads={threads!r}; give an integer from 1 to {MAX_THREADS}: the threads one frame's work is "
            f"split over (1 where each camera already has a core, e.g. two cameras reduced in parallel)"
        )
    return threads


def _forget_pool() -> None:
    global _pool, _pool_workers
    _pool, _pool_workers = None, 0


os.register_at_fork(after_in_child=_forget_pool)


def _pool_of(workers: int) -> ThreadPoolExecutor:
    """The shared pool, with at least ``workers`` threads."""
    global _pool, _pool_workers
    with _lock:
        if _pool is None or _pool_workers < workers:
            old = _pool
            _pool, _pool_workers = ThreadPoolExecutor(workers, thread_name_prefix="markers"), workers
            if old is not None:
                old.shutdown(wait=False)  # its queued parts still run
        return _pool


def run_parts(fn: Callable[..., _T], parts: Sequence[tuple[Any, ...]]) -> list[_T]:
    """``[fn(*part) for part in parts]``, the parts run at the same time: the first in this thread, the
    others on the pool. Returns after every part has finished (a part's exception is raised then)."""
    if len(parts) <= 1:
        return [fn(*part) for part in parts]
    futures = [_pool_of(len(parts) - 1).submit(fn, *part) for part in parts[1:]]
    try:
        first = fn(*parts[0])
    finally:
        wait(futures)  # no part may still write into the caller's arrays after this returns
    return [first, *(future.result() for future in futures)]


def split(n: int, threads: int, least: int) -> list[tuple[int, int]]:
    """``range(n)`` in at most ``threads`` consecutive (lo, hi) parts of nearly equal size, each of at
    least ``least`` items (one part when n < 2·least)."""
    count = max(1, min(threads, n // max(least, 1)))
    edges = [n * i // count for i in range(count + 1)]
    return list(itertools.pairwise(edges))
