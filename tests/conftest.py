"""Suite-wide test settings.

Hypothesis runs derandomized under CI (``CI`` set in the environment), so a CI result can be reproduced
exactly; a developer's run explores new examples each time and keeps failures in ``.hypothesis/``.
``RIG_TEST_LOAD=1`` (``make test-load``) runs the suite under CPU load: a busy loop on every core.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from hypothesis import HealthCheck, settings

settings.register_profile(
    "ci", derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow], print_blob=True
)
settings.register_profile("dev", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("ci" if os.environ.get("CI") else "dev")


# ----------------------------------------------------------------------------- CPU load (make test-load)
# RIG_TEST_LOAD=1 runs the suite with one busy loop per core (RIG_TEST_LOAD=N: N loops), started before
# the first test and stopped after the last, so timing-sensitive tests show whether they depend on an idle
# machine. The loops are this session's own child processes, ended by their pid.
_busy: list[subprocess.Popen[bytes]] = []


def _load_processes() -> int:
    value = os.environ.get("RIG_TEST_LOAD", "").strip()
    if not value or value == "0":
        return 0
    return (os.cpu_count() or 1) if value == "1" else max(0, int(value))


def pytest_sessionstart(session: pytest.Session) -> None:
    for _ in range(_load_processes()):
        _busy.append(subprocess.Popen([sys.executable, "-c", "while True: pass"],
                                      stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL))


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    while _busy:
        proc = _busy.pop()
        proc.kill()
        proc.wait()


def pytest_report_header(config: pytest.Config) -> str | None:
    n = _load_processes()
    return f"CPU load: {n} busy loop(s) (RIG_TEST_LOAD)" if n else None
