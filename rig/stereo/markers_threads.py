"""One frame's marker work split over threads: a small persistent pool for the compiled kernels.

The marker kernels are compiled with numba ``nogil=True``: while one runs, other Python threads run too,
so the parts of a frame (row bands of the binarization, halves of the windows to measure) go to
``threads`` threads at once — the calling thread takes the first part, the pool's threads the others.
Each part writes only its own outputs, so the results are those of one thread, bit for bit.

The pool's threads are daemons waiting on a lock each (a hand-over costs ≈ 11 µs wall on this VM,
against ≈ 40 µs through ``concurrent.futures``); a call takes idle ones (starting new ones when
none is idle: calls from several threads at once each get their own) and gives them back when its parts
have finished. A forked child forgets its parent's (it has no threads). :func:`check_threads` is the
option's check; 1 (the default everywhere) uses no pool: the right choice where each camera already has
a core (``rig measure`` reduces the two cameras' frames in parallel).
"""

from __future__ import annotations

import itertools
import os
import threading
from collections.abc import Callable, Sequence
from typing import Any, TypeVar, cast

from rig.stereo.errors import InputArrayError

_T = TypeVar("_T")
MAX_THREADS = 64


def check_threads(threads: object) -> int:
    """``threads`` as an int if it is an integer 1 … MAX_THREADS, else InputArrayError saying why."""
    if isinstance(threads, bool) or not isinstance(threads, int) or not 1 <= threads <= MAX_THREADS:
        raise InputArrayError(
            f"threads={threads!r}; give an integer from 1 to {MAX_THREADS}: the threads one frame's work is "
            f"split over (1 where each camera already has a core, e.g. two cameras reduced in parallel)"
        )
    return threads


class _Worker:
    """A daemon thread that runs one part at a time, handed over and back by two locks."""

    def __init__(self) -> None:
        self._go, self._done = threading.Lock(), threading.Lock()
        self._go.acquire()
        self._done.acquire()
        self._job: tuple[Callable[..., Any], tuple[Any, ...]] | None = None
        self._outcome: tuple[Any, BaseException | None] = (None, None)
        threading.Thread(target=self._loop, name="markers-part", daemon=True).start()

    def start(self, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        self._job = (fn, args)
        self._go.release()

    def join(self) -> tuple[Any, BaseException | None]:
        """(result, None) or (None, the exception) of the part started last, once it has finished."""
        self._done.acquire()
        outcome, self._outcome = self._outcome, (None, None)
        return outcome

    def _loop(self) -> None:
        while True:
            self._go.acquire()
            assert self._job is not None
            fn, args = self._job
            self._job = None
            try:
                self._outcome = (fn(*args), None)
            except BaseException as exc:  # handed to the caller's thread, raised there
                self._outcome = (None, exc)
            self._done.release()


_lock = threading.Lock()
_idle: list[_Worker] = []


def _forget_workers() -> None:
    global _lock, _idle
    _lock, _idle = threading.Lock(), []


os.register_at_fork(after_in_child=_forget_workers)


def _take(count: int) -> list[_Worker]:
    with _lock:
        taken = [_idle.pop() for _ in range(min(count, len(_idle)))]
    return taken + [_Worker() for _ in range(count - len(taken))]


def run_parts(fn: Callable[..., _T], parts: Sequence[tuple[Any, ...]]) -> list[_T]:
    """``[fn(*part) for part in parts]``, the parts run at the same time: the first in this thread, the
    others on the pool's. Returns after every part has finished (the first part's exception is raised
    then)."""
    if len(parts) <= 1:
        return [fn(*part) for part in parts]
    workers = _take(len(parts) - 1)
    for worker, part in zip(workers, parts[1:], strict=True):
        worker.start(fn, part)
    try:
        first = fn(*parts[0])
    finally:  # no part may still write into the caller's arrays after this returns
        outcomes = [worker.join() for worker in workers]
        with _lock:
            _idle.extend(workers)
    for _, error in outcomes:
        if error is not None:
            raise error
    return [first, *(cast(_T, result) for result, _ in outcomes)]


def split(n: int, threads: int, least: int) -> list[tuple[int, int]]:
    """``range(n)`` in at most ``threads`` consecutive (lo, hi) parts of nearly equal size, each of at
    least ``least`` items (one part when n < 2·least)."""
    count = max(1, min(threads, n // max(least, 1)))
    edges = [n * i // count for i in range(count + 1)]
    return list(itertools.pairwise(edges))
