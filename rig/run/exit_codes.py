"""The exit codes of ``rig`` and the stop signals: light (standard library only), so that building the
command line parser imports nothing of the run.

One meaning each (:func:`rig.cli.main` owns the mapping): 0 pass, 1 certificate failed (FAIL or INCOMPLETE:
not a pass), 2 aborted (a stop signal: SIGINT, SIGTERM, SIGHUP, SIGQUIT), 3 interlock, hardware or I/O
fault, 4 bad input (configuration, parameters, command line).
"""

from __future__ import annotations

import signal

__all__ = ["EXIT_ABORTED", "EXIT_BAD_INPUT", "EXIT_CERTIFICATE_FAILED", "EXIT_FAULT", "EXIT_PASS",
           "STOP_SIGNALS", "Interrupted"]

EXIT_PASS, EXIT_CERTIFICATE_FAILED, EXIT_ABORTED, EXIT_FAULT, EXIT_BAD_INPUT = 0, 1, 2, 3, 4
STOP_SIGNALS: tuple[signal.Signals, ...] = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)
"""Every catchable way a user, a terminal or a supervisor (systemd, docker, a CI timeout) ends ``rig``:
all go through the same safe stop."""


class Interrupted(KeyboardInterrupt):
    """A second stop signal: abort at once. ``signal_name`` e.g. ``"SIGTERM"``."""

    def __init__(self, signal_name: str = "SIGINT") -> None:
        super().__init__(signal_name)
        self.signal_name = signal_name
