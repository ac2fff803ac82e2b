"""One frame's marker work split over threads: a small persistent pool for the compiled kernels.

The marker kernels are compiled with numba ``nogil=True``: while one runs, other Python threads run too,
so the parts of a frame (row bands of the binarization, halves of the windows to measure) go to
``threads`` threads at once — the calling thread takes the first part, the pool's threads the others.
Each part writes only its own outputs, so the results are those of one thread, bit for bit.

The pool's threads are daemons waiting on a lock each (a hand-over costs ≈ 11 µs wall on this VM,
against ≈ 40 µs through ``concurrent.futures``); a call takes idle ones (starting new ones when
none is idle: calls from several threads at once each get their own) and gives them back when its parts
have finished. :func:`run_helped` is the other way, for tracking on two threads: the caller does not
wait for its helper, whose thread avoids the caller's CPU (on a busy machine a static split waits for a
preempted part: up to 2.4 ms a frame against 0.4 ms on one thread at load 5; the helper costs ≈ 0.1 ms
when no core is free, and takes about half the windows when one is). A forked child forgets its
parent's threads (it has none).
:func:`check_threads` is the option's check; 1 (the default everywhere) uses no pool: the right choice
where each camera already has a core (``rig measure`` reduces the two cameras' frames in parallel).
"""

from __future__ import annotations

import contextlib
import ctypes
import itertools
import os
import threading
from collections.abc import Callable, Sequence
from typing import Any, ClassVar, TypeVar, cast

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


class _Helper:
    """A daemon thread that runs optional parts (:func:`run_helped`) and goes back to the idle helpers by
    itself after each (its caller does not wait for it)."""

    started: ClassVar[int] = 0  # helper threads started in this process (at most MAX_THREADS − 1)

    def __init__(self) -> None:
        self._go = threading.Lock()
        self._go.acquire()
        self._job: tuple[Callable[..., Any], tuple[Any, ...]] | None = None
        self._cpus: set[int] | None = None  # the CPUs this thread may run on, when set by start
        thread = threading.Thread(target=self._loop, name="markers-helper", daemon=True)
        thread.start()
        self._tid = thread.native_id

    def start(self, fn: Callable[..., Any], args: tuple[Any, ...], caller_cpu: int | None) -> None:
        """Run ``fn(*args)``; ``caller_cpu``: the CPU the caller runs on, which this thread then avoids —
        woken there it would preempt the caller (both waiting for one core: slower than the caller
        alone) instead of waiting for another core to come free."""
        cpus = _ALL_CPUS - {caller_cpu} if caller_cpu is not None else None
        if cpus and cpus != self._cpus and self._tid is not None:
            try:
                os.sched_setaffinity(self._tid, cpus)
                self._cpus = cpus
            except OSError:  # e.g. a CPU outside the process's cgroup: left where the scheduler puts it
                pass
        self._job = (fn, args)
        self._go.release()

    def _loop(self) -> None:
        while True:
            self._go.acquire()
            assert self._job is not None
            (fn, args), self._job = self._job, None
            with contextlib.suppress(BaseException):  # it wrote only its own arrays, which nobody reads
                fn(*args)
            del fn, args  # the finished part's arrays are not kept alive by an idle thread
            with _lock:
                _idle_helpers.append(self)


def _cpu_reader() -> Callable[[], int] | None:
    """libc's sched_getcpu (the CPU this thread runs on; a few ns through the vDSO), or None without it."""
    if not hasattr(os, "sched_setaffinity"):
        return None
    try:
        return cast(Callable[[], int], ctypes.CDLL(None, use_errno=True).sched_getcpu)
    except (OSError, AttributeError):
        return None


_ALL_CPUS = set(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else set()
_current_cpu = _cpu_reader() if len(_ALL_CPUS) > 1 else None
_lock = threading.Lock()
_idle: list[_Worker] = []
_idle_helpers: list[_Helper] = []


def _forget_workers() -> None:
    global _lock, _idle, _idle_helpers
    _lock, _idle, _idle_helpers = threading.Lock(), [], []
    _Helper.started = 0


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


def run_helped(fn: Callable[..., Any], first: tuple[Any, ...], helpers: Sequence[tuple[Any, ...]]) -> None:
    """``fn(*first)`` in this thread, helped by ``fn(*h)`` for each of ``helpers`` on idle pool threads
    (at most MAX_THREADS − 1 helper threads in all; without an idle one, a helper part is not run).

    For work that the first part completes by itself and that a helper's writes cannot disturb after the
    first part has finished: :func:`rig.stereo.markers_kernel.track_frame`, whose helper measures into
    its own rows and whose caller copies those it finds finished. This returns when the first part has
    returned, without waiting for the helpers (a helper part not started by then is dropped; a helper's
    exception is lost: it only wrote its own arrays). A helper avoids the CPU this thread runs on: woken
    there it would preempt this thread instead of waiting for another core.
    """
    with _lock:
        count = min(len(helpers), len(_idle_helpers) + MAX_THREADS - 1 - _Helper.started)
        taken = [_idle_helpers.pop() for _ in range(min(count, len(_idle_helpers)))]
        new = count - len(taken)
        _Helper.started += new
    taken += [_Helper() for _ in range(new)]
    cpu = _current_cpu() if _current_cpu is not None and taken else -1
    for helper, part in zip(taken, helpers, strict=False):
        helper.start(fn, part, cpu if cpu >= 0 else None)
    fn(*first)


def split(n: int, threads: int, least: int) -> list[tuple[int, int]]:
    """``range(n)`` in at most ``threads`` consecutive (lo, hi) parts of nearly equal size, each of at
    least ``least`` items (one part when n < 2·least)."""
    count = max(1, min(threads, n // max(least, 1)))
    edges = [n * i // count for i in range(count + 1)]
    return list(itertools.pairwise(edges))
