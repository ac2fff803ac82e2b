"""The drivers' compiled kernels (numba): one decorator, so every kernel is built alike.

``nogil_kernel(what)`` compiles a function with ``numba.njit`` without the GIL (a camera's reader threads
and the twin's cameras run kernels at once) and caches the machine code on disk next to its source file;
where that location is not writable it warns, naming ``what``, and compiles once per process. Imported
only by the kernel modules, so importing a driver does not import numba.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba

__all__ = ["nogil_kernel"]

_F = TypeVar("_F", bound=Callable[..., Any])


def nogil_kernel(what: str) -> Callable[[_F], _F]:
    """Decorator: ``numba.njit(nogil=True)`` with the on-disk cache where writable (``what`` names the
    kernel in the warning when it is not)."""
    def compile_kernel(fn: _F) -> _F:
        try:
            return cast(_F, numba.njit(cache=True, nogil=True)(fn))
        except RuntimeError as exc:  # numba: "cannot cache function ...: no locator available"
            warnings.warn(f"{what} kernel not cached on disk ({exc}); compiling it in this process",
                          RuntimeWarning, stacklevel=2)
            return cast(_F, numba.njit(nogil=True)(fn))
    return compile_kernel
