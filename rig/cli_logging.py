"""The console log of ``rig``: our own messages at the chosen verbosity, third-party noise only with ``-v``.

At the default verbosity the console shows warnings and errors of the project's own loggers (``rig``,
``drivers``, ``procedures``, ``reports``) only: pymodbus' connection chatter, matplotlib's font cache,
asyncio's, are dropped from the console (a run's ``rig.log`` still gets them: the filter is on the console
handler, not on the loggers). Native libraries that write to stderr themselves are quietened through their
environment variables, read when they are first loaded (so set here, before any of them is imported):
OpenCV's own log (``OPENCV_LOG_LEVEL``), FFmpeg's under OpenCV (``OPENCV_FFMPEG_LOGLEVEL``, e.g. "moov atom
not found": our drivers say what is wrong with a video in their own words), and Dask distributed's handlers
(``DASK_LOGGING__DISTRIBUTED``, which reach the worker processes too). A variable the user set is kept.
``-v`` shows everything at INFO, ``-vv`` at DEBUG.
"""

from __future__ import annotations

import logging
import os
from typing import TextIO

__all__ = ["NATIVE_QUIET", "OWN_PACKAGES", "OwnLoggersOnly", "configure_logging"]

OWN_PACKAGES = ("rig", "drivers", "procedures", "reports", "__main__")
NATIVE_QUIET = {
    "OPENCV_LOG_LEVEL": "ERROR",
    "OPENCV_FFMPEG_LOGLEVEL": "-8",  # AV_LOG_QUIET
    "DASK_LOGGING__DISTRIBUTED": "error",
}


class OwnLoggersOnly(logging.Filter):
    """Pass the records of the project's own loggers (:data:`OWN_PACKAGES`) only."""

    def filter(self, record: logging.LogRecord) -> bool:
        return record.name.split(".", 1)[0] in OWN_PACKAGES


def configure_logging(verbose: int, stream: TextIO) -> None:
    """The console handler on ``stream`` at WARNING (0), INFO (1) or DEBUG (≥ 2); third-party records and
    native libraries' output only from ``verbose`` ≥ 1 (see the module docstring)."""
    level = (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbose, 2)]
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s", stream=stream)
    logging.raiseExceptions = False  # a log line lost to a full disk is not worth a traceback per line
    for handler in logging.getLogger().handlers:  # the console keeps its level when rig.log wants more
        if isinstance(handler, logging.StreamHandler) and not isinstance(handler, logging.FileHandler):
            handler.setLevel(level)
            for old in [f for f in handler.filters if isinstance(f, OwnLoggersOnly)]:
                handler.removeFilter(old)
            if verbose == 0:
                handler.addFilter(OwnLoggersOnly())
    if verbose == 0:
        for name, value in NATIVE_QUIET.items():
            os.environ.setdefault(name, value)
