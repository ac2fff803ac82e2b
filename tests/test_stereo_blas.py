"""One BLAS thread: the `rig` command's default unless the user set it (rig.cli), and rig.stereo.blas's limit
inside and the caller's setting after it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from rig import cli
from rig.stereo import blas


def test_blas_defaults_to_one_thread_without_overriding_what_the_user_set() -> None:
    environ = {"MKL_NUM_THREADS": "4"}
    cli.single_threaded_blas_by_default(environ)
    assert environ == {"OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "4", "BLIS_NUM_THREADS": "1"}


_RIG_THEN_BLAS = """
import sys
sys.argv = ["rig", "list"]
from rig.cli import main
main()
import os, numpy, scipy.linalg
from threadpoolctl import threadpool_info
print(os.environ.get("OPENBLAS_NUM_THREADS"),
      sorted({pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"}))
"""


# the variable, then the threads of each BLAS pool: OpenBLAS caps the environment's value at the cores
_KEPT = f"2 [{min(2, os.cpu_count() or 1)}]"


@pytest.mark.parametrize(("given", "expected"), [(None, "1 [1]"), ("2", _KEPT)])
def test_the_rig_command_starts_numpy_and_scipy_with_one_blas_thread(given: str | None,
                                                                     expected: str) -> None:
    """As the process's command, `rig` sets the BLAS variables before any BLAS is loaded (numpy is not
    imported by the command's start): numpy's and scipy's OpenBLAS then run one thread. A value the user
    gave (here 2) is kept."""
    env = {k: v for k, v in os.environ.items() if k not in cli.BLAS_THREAD_VARIABLES}
    if given is not None:
        env["OPENBLAS_NUM_THREADS"] = given
    root = Path(__file__).resolve().parents[1]
    done = subprocess.run([sys.executable, "-c", _RIG_THEN_BLAS], cwd=root, capture_output=True, text=True,
                          check=True, env={**env, "PYTHONPATH": str(root)})
    assert done.stdout.strip().splitlines()[-1] == expected


def test_one_blas_thread_inside_and_the_callers_setting_after() -> None:
    import scipy.linalg  # noqa: F401  (its own OpenBLAS loaded: the caller's limit reaches it too)
    from threadpoolctl import threadpool_info, threadpool_limits

    def blas_threads() -> set[int]:
        return {pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"}

    with threadpool_limits(limits=3, user_api="blas"):
        with blas.one_blas_thread():
            inside = blas_threads()
        after = blas_threads()
    assert inside == {1} and after == {3}
