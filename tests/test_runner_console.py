"""What a run prints: each error once. The exit line (``rig: NAME: outcome (exit N): reason``) says what
ended the run; the interlock, the procedure's traceback and a failed close of the record go to ``rig.log``
only, not to the console before it as well."""

from __future__ import annotations

import errno
import io
import logging
import os
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from runner_dummy import make_module, station_factory

from rig.cli_logging import OwnLoggersOnly
from rig.config.rig_config import default_config
from rig.record.writer import RunRecord
from rig.run.runner import Runner

ROOT = Path(__file__).resolve().parents[1]

OVER_LIMIT = textwrap.dedent('''
    """Asks the exciter beyond its limit: the driver refuses before sending (an interlock)."""
    from dataclasses import dataclass

    NAME = "over_limit"

    @dataclass(frozen=True)
    class Parameters:
        pass

    def run(ctx, params):
        ctx.device("exciter").set_frequency(300.0)
        return {"passed": True, "summary": "not reached"}
''')


@pytest.fixture
def console() -> Iterator[io.StringIO]:
    """The console as ``rig`` sets it up (WARNING, the project's own loggers), on a string."""
    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    handler.setLevel(logging.WARNING)
    handler.addFilter(OwnLoggersOnly())
    root = logging.getLogger()
    root.addHandler(handler)
    try:
        yield stream
    finally:
        root.removeHandler(handler)


def test_driver_refusal_is_printed_once_without_traceback(tmp_path: Path) -> None:
    (tmp_path / "over_limit.py").write_text(OVER_LIMIT)
    done = subprocess.run([sys.executable, "-m", "rig.cli", "run", str(tmp_path / "over_limit.py"),
                           "--no-dashboard", "--runs-dir", str(tmp_path / "runs")],
                          capture_output=True, text=True, cwd=tmp_path, timeout=600, check=False,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert done.returncode == 3, done.stderr
    assert "Traceback" not in done.stderr, done.stderr
    said = [ln for ln in done.stderr.splitlines() if "exceeds the limit 32 Hz" in ln]
    assert len(said) == 1 and said[0].startswith("rig: over_limit: interlock (exit 3)"), done.stderr
    (run_dir,) = [p for p in (tmp_path / "runs").iterdir() if p.is_dir()]
    assert "Traceback" in (run_dir / "rig.log").read_text()  # kept, in rig.log


def test_watchdog_interlock_goes_to_rig_log_not_before_the_exit_line(tmp_path: Path,
                                                                      console: io.StringIO) -> None:
    runner = Runner(make_module("heartbeat"), config=default_config(),
                    station_factory=station_factory(tmp_path / "calls.txt"), runs_dir=tmp_path / "runs",
                    watchdog_period_s=0.02)
    out = runner.run({"tick_s": 0.01})
    assert out.exit_code == 3 and "device reports the link is down" in out.reason
    assert "link is down" not in console.getvalue() and "Traceback" not in console.getvalue(), \
        console.getvalue()
    log_text = (out.run_dir / "rig.log").read_text()
    assert "INTERLOCK on exciter: lost heartbeat: device reports the link is down" in log_text


def test_record_that_cannot_be_closed_is_reported_once(tmp_path: Path, console: io.StringIO,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """A full disk at the last flush: the close fails every time it is tried (the buffer stays)."""
    tries: list[int] = []

    def full_disk(self: RunRecord) -> None:
        tries.append(1)
        raise OSError(errno.ENOSPC, "No space left on device", str(self.path))

    monkeypatch.setattr(RunRecord, "close", full_disk)
    runner = Runner(make_module("normal"), config=default_config(),
                    station_factory=station_factory(tmp_path / "calls.txt"), runs_dir=tmp_path / "runs",
                    watchdog_period_s=0.02)
    out = runner.run({"ticks": 3, "tick_s": 0.0})
    assert out.exit_code == 3 and out.outcome == "fault", out.reason
    assert out.reason.count("closing the record failed") == 1, out.reason
    assert out.reason.startswith("dummy done; then closing the record failed: OSError: [Errno 28]")
    assert len(tries) == 1  # not tried again (it would fail and be reported again)
    assert "closing the record failed" not in console.getvalue(), console.getvalue()
