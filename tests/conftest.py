"""Suite-wide test settings.

Hypothesis runs derandomized under CI (``CI`` set in the environment), so a CI result can be reproduced
exactly; a developer's run explores new examples each time and keeps failures in ``.hypothesis/``.
``RIG_TEST_LOAD=1`` (``make test-load``) runs the suite under CPU load: a busy loop on every core.

Under pytest-xdist (``make test``: ``-n auto --dist loadfile``) each test file runs whole on one worker, the
costliest files first (``file_costs.tsv``, recorded by ``make test-times``), and what several files read (the
twin's calibrated sites, a rotation run, the synthetic run's report) is built once per session for all
workers (``built_once``).
"""

from __future__ import annotations

import fcntl
import os
import pickle
import shutil
import subprocess
import sys
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
from hypothesis import HealthCheck, settings

if TYPE_CHECKING:
    from reports.build import ReportResult

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


def _is_xdist_worker(config: pytest.Config) -> bool:
    """True in a pytest-xdist worker: the load loops belong to the controlling process only."""
    return hasattr(config, "workerinput")


def pytest_sessionstart(session: pytest.Session) -> None:
    if _is_xdist_worker(session.config):
        return
    for _ in range(_load_processes()):
        _busy.append(subprocess.Popen([sys.executable, "-c", "while True: pass"],
                                      stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL))


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    while _busy:
        proc = _busy.pop()
        proc.kill()
        proc.wait()


def pytest_report_header(config: pytest.Config) -> str | None:
    n = 0 if _is_xdist_worker(config) else _load_processes()
    return f"CPU load: {n} busy loop(s) (RIG_TEST_LOAD)" if n else None


# ----------------------------------------------------------------------------- per-test CPU (RIG_TEST_TIMES)
# RIG_TEST_TIMES=FILE appends one line per test (nodeid, wall s, CPU s of the worker process and of the
# children it waited for — their own waited-for children included, e.g. a `rig` subprocess's mocks —, the
# xdist worker): on a shared, loaded machine the CPU seconds, unlike --durations' wall time,
# say what a test costs, and a file's sum is what it adds to its xdist worker. Written as each test ends.
def _cpu_s() -> float:
    import resource

    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Any:
    path = os.environ.get("RIG_TEST_TIMES")
    if not path:
        return (yield)
    import time

    wall0, cpu0 = time.perf_counter(), _cpu_s()
    try:
        return (yield)
    finally:
        worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
        line = f"{item.nodeid}\t{time.perf_counter() - wall0:.3f}\t{_cpu_s() - cpu0:.3f}\t{worker}\n"
        with open(path, "a", encoding="utf-8") as out:  # one short append per test: whole lines
            out.write(line)


# ----------------------------------------------------------------------------- workers (xdist: -n auto)
# `-n auto` (make test) starts WORKERS_PER_CORE workers per core, not one: a third of the suite's worker time
# is waiting, not computing (real-time mocks, watchdog and time-out bounds, subprocesses starting), and a
# worker that waits leaves its core to another. PYTEST_XDIST_AUTO_NUM_WORKERS=N, or -n N, sets N.
WORKERS_PER_CORE = 1.5


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int | None:
    """``-n auto``: ``WORKERS_PER_CORE`` × the cores this process may use (its affinity, capped by a
    container's CPU quota: :func:`drivers.cores.usable_cores`); None (xdist's own count) when
    ``PYTEST_XDIST_AUTO_NUM_WORKERS`` is set."""
    if os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS"):
        return None
    from drivers.cores import usable_cores

    return max(1, round(WORKERS_PER_CORE * usable_cores()))


# ----------------------------------------------------------------------------- order (xdist: longest first)
# tests/file_costs.tsv: per test file, the CPU seconds (the worker's and its children's) and the wall seconds
# of one `make test-times` run (RIG_TEST_TIMES summed per file). A file's cost to its worker is its CPU plus
# what it waits (real-time mocks, watchdog bounds). On the recorded run, wall = CPU × load + waits, with the
# load that run had (the median wall/CPU ratio): waits = wall − CPU × load; a file whose children ran in
# parallel (wall < CPU) costs its CPU.
FILE_COSTS = Path(__file__).with_name("file_costs.tsv")


def file_costs_s(path: Path = FILE_COSTS) -> dict[str, float]:
    """{test file: estimated seconds a worker is busy with it}, from ``path`` (empty when it is missing)."""
    if not path.is_file():
        return {}
    rows = [line.split("\t") for line in path.read_text(encoding="utf-8").splitlines()
            if line.strip() and not line.startswith("#")]
    costs = {name: (float(cpu_s), float(wall_s)) for name, cpu_s, wall_s in rows}
    ratios = sorted(wall_s / cpu_s for cpu_s, wall_s in costs.values() if cpu_s >= 1.0)
    load = ratios[len(ratios) // 2] if ratios else 1.0
    return {name: cpu_s + max(0.0, wall_s - cpu_s * load) for name, (cpu_s, wall_s) in costs.items()}


def _skip_quiet_machine_cases(items: list[pytest.Item]) -> None:
    """Cases marked ``quiet_machine`` are skipped, saying why, unless ``RIG_TEST_QUIET=1`` (make test-lab):
    next to the suite's workers the lab renders too few frames in real time and the run measures the load."""
    if os.environ.get("RIG_TEST_QUIET") == "1":
        return
    skip = pytest.mark.skip(reason="needs the machine to itself: run `make test-lab` (RIG_TEST_QUIET=1) on a "
                                   "quiet machine")
    for item in items:
        if item.get_closest_marker("quiet_machine"):
            item.add_marker(skip)


def pytest_collection_modifyitems(session: pytest.Session, config: pytest.Config,
                                  items: list[pytest.Item]) -> None:
    """Files not recorded yet in ``file_costs.tsv`` first (their cost is unknown: starting early is safe),
    by their slow-marked cases; then the recorded ones, costliest first; ties in collection order. A file's
    tests stay together in their own order (module fixtures are built once). With ``--dist loadfile`` the
    workers take files in this order (longest processing time first): the long files start early and the
    short ones fill the end evenly."""
    _skip_quiet_machine_cases(items)
    costs = file_costs_s()
    files = {item.nodeid: item.nodeid.split("::", 1)[0] for item in items}
    slow = Counter(files[item.nodeid] for item in items if item.get_closest_marker("slow"))
    first_seen = {f: k for k, f in reversed(list(enumerate(files[item.nodeid] for item in items)))}

    def key(item: pytest.Item) -> tuple[bool, float, int, int]:
        f = files[item.nodeid]
        return f in costs, -costs.get(f, 0.0), -slow[f], first_seen[f]

    items.sort(key=key)


# ----------------------------------------------------------------------------- artefacts shared by files
def built_once(tmp_path_factory: pytest.TempPathFactory, name: str, build: Callable[[Path], Any]) -> Any:
    """``build(folder)``'s value, built once per test session in ``folder`` and shared by every xdist worker
    (the workers' temporary folders share a parent; a file lock makes the others wait for the first).
    The value must pickle; tests read the folder and write their own outputs under their ``tmp_path``."""
    base = tmp_path_factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    folder, done = root / f"shared-{name}", root / f"shared-{name}.pickle"
    with open(root / f"shared-{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if done.is_file():
            return pickle.loads(done.read_bytes())
        shutil.rmtree(folder, ignore_errors=True)  # a build that failed in another worker
        folder.mkdir()
        value = build(folder)
        done.write_bytes(pickle.dumps(value))
        return value


@pytest.fixture(scope="session")
def calibrated_site(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """``tests/measure_twin.calibrated_site`` (mp4v plate videos through ``rig calibrate``), read-only."""
    import measure_twin as mt

    return built_once(tmp_path_factory, "calibrated_site", mt.calibrated_site)


@pytest.fixture(scope="session")
def mjpg_site(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """``tests/measure_twin.mjpg_site`` (Motion-JPEG plate and measurement videos, calibrated), read-only."""
    import measure_twin as mt

    return built_once(tmp_path_factory, "mjpg_site", mt.mjpg_site)


@pytest.fixture(scope="session")
def rotation_run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """``tests/certify_support.rotation_run`` (a whole ``rig run rotation`` on the simulated rig), read-only:
    checked by test_procedures_e2e_plate_rotation, reported on (copies) by test_evidence_io_faults."""
    import certify_support as cs

    return built_once(tmp_path_factory, "rotation_run", cs.rotation_run)


@pytest.fixture(scope="session")
def synth_report(tmp_path_factory: pytest.TempPathFactory) -> ReportResult:
    """``tests/reports_synth.built_report`` (the synthetic run's first report, figures included), read-only:
    test_reports_build works on a copy of its run folder, test_reports_html_chromium renders its page."""
    import reports_synth as synth

    return built_once(tmp_path_factory, "synth_report", synth.built_report)
