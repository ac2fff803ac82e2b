"""The linear algebra's threads: one.

numpy's and scipy's BLAS (each wheel ships its own OpenBLAS) start a thread per core, and after every call
the idle threads spin. Our analyses are thousands of small solves (3-D tracks, trajectories, calibration,
timing), none with a matrix large enough to gain from a second thread, so it only spins. Measured on 2
cores: `rig measure`'s 3-D tracks 0.36 → 0.26 CPU-s on a 20-s 1080p pair (same wall clock, same bytes);
importing numpy and scipy.linalg 0.27–0.33 → 0.13 CPU-s. OpenMP (numba, OpenCV) is not concerned. The
`rig` command sets the libraries' variables before numpy loads (``rig.cli.BLAS_THREAD_VARIABLES``).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["one_blas_thread"]


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """The loaded BLAS libraries on one thread inside, the caller's setting restored after (threadpoolctl;
    process-wide while inside). A library first loaded inside is not limited: scipy.linalg, whose OpenBLAS
    is scipy's own, is imported first."""
    import scipy.linalg  # noqa: F401  (its BLAS loaded now, so that the limit reaches it)
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield
