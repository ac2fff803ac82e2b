"""The run's progress on the terminal (rig.dashboard.terminal): in place on a tty, log lines otherwise (one
per step and per 10 % of a long step), the plan's step count and time remaining; the closing summary table.
Streams are fakes (a tty or not) and the clock is injected: nothing depends on the machine's speed."""

from __future__ import annotations

import io
import json
import textwrap
from pathlib import Path

import pytest

from rig.cli import _print_summary, main
from rig.dashboard.state import DashboardState
from rig.dashboard.terminal import TerminalProgress, duration_text

PLAN = [("calibrate", 20.0), ("sweep", 100.0)]  # rig seconds


class FakeStream(io.StringIO):
    def __init__(self, tty: bool) -> None:
        super().__init__()
        self.tty = tty

    def isatty(self) -> bool:
        return self.tty


class FakeClock:
    def __init__(self) -> None:
        self.now_s = 1000.0

    def __call__(self) -> float:
        return self.now_s


def _wired(tty: bool) -> tuple[DashboardState, TerminalProgress, FakeStream, FakeClock]:
    state = DashboardState("certify", plan_steps=lambda start: PLAN)
    stream, clock = FakeStream(tty), FakeClock()
    return state, TerminalProgress(state, stream, clock=clock), stream, clock


def _doc(state: DashboardState, term: TerminalProgress, doc: dict) -> None:
    state.on_document(doc)  # the order of the runner's observers: the state first
    term.observe(doc)


def _progress(state: DashboardState, term: TerminalProgress, fraction: float | None,
              message: str = "") -> None:
    state.on_progress(fraction, message)
    term.progress(fraction, message)


def _step(name: str, status: str, time_s: float) -> dict:
    return {"type": "step", "name": name, "status": status, "time_s": time_s}


def test_captured_output_gets_a_line_per_step_and_per_tenth_of_a_long_step() -> None:
    state, term, stream, clock = _wired(tty=False)
    _doc(state, term, {"type": "start", "time_s": 0.0, "parameters": {}})
    _doc(state, term, _step("calibrate", "begin", 0.0))
    _progress(state, term, 0.5, "pose 3 of 6")  # a short step (20 s < 30 s): no line per 10 %
    clock.now_s += 25.0
    _doc(state, term, _step("calibrate", "done", 20.0))
    _doc(state, term, _step("sweep", "begin", 20.0))
    for fraction in (0.05, 0.12, 0.18, 0.57, 1.0):  # 10 % and 50 % are crossed (the end has its own line)
        _progress(state, term, fraction, "sweeping")
    clock.now_s += 100.0
    _doc(state, term, _step("sweep", "done", 120.0))
    lines = stream.getvalue().splitlines()
    assert "\r" not in stream.getvalue()
    assert lines == [
        "rig: +       0 s step 1 of 2: calibrate began (planned ≈ 20 s; ≈ 2 min 00 s left)",
        "rig: +      25 s step 1 of 2: calibrate done (≈ 1 min 40 s left)",
        "rig: +      25 s step 2 of 2: sweep began (planned ≈ 1 min 40 s; ≈ 1 min 40 s left)",
        "rig: +      25 s step 2 of 2: sweep 10 % — sweeping (≈ 1 min 28 s left)",
        "rig: +      25 s step 2 of 2: sweep 50 % — sweeping (≈ 43 s left)",
        "rig: +2 min 05 s step 2 of 2: sweep done (≈ 0 s left)",
    ]


def test_a_terminal_gets_one_line_redrawn_at_most_every_redraw_interval() -> None:
    state, term, stream, clock = _wired(tty=True)
    _doc(state, term, {"type": "start", "time_s": 0.0, "parameters": {}})
    _doc(state, term, _step("calibrate", "begin", 0.0))
    _doc(state, term, _step("calibrate", "done", 20.0))
    _doc(state, term, _step("sweep", "begin", 20.0))
    _progress(state, term, 0.25, "at 7.5 Hz")
    drawn = stream.getvalue().count("\r")
    _progress(state, term, 0.26, "too soon")  # the same clock instant: not redrawn
    assert stream.getvalue().count("\r") == drawn and "too soon" not in stream.getvalue()
    clock.now_s += 0.1
    _progress(state, term, 0.5, "at 15 Hz")
    last = stream.getvalue().rsplit("\r", 1)[1]
    # 20 s + 50 s of 120 s done; 50 s left
    assert last.startswith("[" + "#" * 17 + "-" * 13 + "]  58 % "
                           "step 2 of 2: sweep 50 % · ≈ 50 s left · at 15 Hz")
    assert "\n" not in stream.getvalue()
    drawn = stream.getvalue().count("\r")
    clock.now_s += 0.1  # any document redraws (throttled): a step without a fraction counts down by rig time
    _doc(state, term, {"type": "event", "time_s": 60.0, "stream": "exciter", "data": {}})
    assert stream.getvalue().count("\r") == drawn + 1
    term.close()
    assert stream.getvalue().endswith("\n")


def test_without_a_plan_steps_are_counted_as_they_begin() -> None:
    state = DashboardState("probe")
    stream = FakeStream(tty=False)
    term = TerminalProgress(state, stream, clock=FakeClock())
    for doc in ({"type": "start", "time_s": 0.0}, _step("move", "begin", 0.0)):
        _doc(state, term, doc)
    assert stream.getvalue() == "rig: +       0 s step 1: move began (≈ 0 s left)\n"


def test_a_step_the_plan_does_not_time_is_counted_where_it_runs() -> None:
    """``rig run sync`` calibrates first when it has no calibration: a step outside sync's plan."""
    state = DashboardState("sync", plan_steps=lambda start: [("sync", 13.0)])
    stream = FakeStream(tty=False)
    term = TerminalProgress(state, stream, clock=FakeClock())
    for doc in ({"type": "start", "time_s": 0.0}, _step("calibrate", "begin", 0.0),
                _step("calibrate", "done", 3.0), _step("sync", "begin", 3.0)):
        _doc(state, term, doc)
    assert [line.split(" step ", 1)[1] for line in stream.getvalue().splitlines()] == [
        "1 of 2: calibrate began (≈ 13 s left)", "1 of 2: calibrate done (≈ 13 s left)",
        "2 of 2: sync began (planned ≈ 13 s; ≈ 13 s left)"]


@pytest.mark.parametrize(("procedure", "parameters"), [("certify", {"preset": "fast"}), ("plate", {})])
def test_the_step_count_is_known_from_the_start_report_included(procedure: str, parameters: dict) -> None:
    """The report is the last step of the plan: "step n of n: report", never a step count growing by one."""
    from rig.cli import load_config, load_procedure
    from rig.dashboard.live_run import run_state

    module = load_procedure(procedure)
    state = run_state(module, load_config(None))
    stream = FakeStream(tty=False)
    term = TerminalProgress(state, stream, clock=FakeClock())
    _doc(state, term, {"type": "start", "time_s": 0.0, "procedure": procedure, "parameters": parameters})
    names = state.overview().step_names
    # certify: the fast preset's plan keeps the band step, stated as left out (it is entered and left)
    assert names[-1] == "report" and len(names) == (8 if procedure == "certify" else 4)
    for t_s, name in enumerate(names):
        _doc(state, term, _step(name, "begin", float(t_s)))
        _doc(state, term, _step(name, "done", t_s + 0.5))
    labels = [line.split(" step ", 1)[1].split(":")[0] for line in stream.getvalue().splitlines()]
    assert labels == [f"{i} of {len(names)}" for i in range(1, len(names) + 1) for _ in ("begin", "done")]


@pytest.mark.parametrize(("seconds", "text"),
                         [(None, "—"), (0.4, "0 s"), (59.6, "1 min 00 s"), (3725, "62 min 05 s")])
def test_duration_text(seconds: float | None, text: str) -> None:
    assert duration_text(seconds) == text


def test_the_closing_summary_lists_each_criterion_with_value_u_limit_and_decision(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "20261201-120000_certify_ab12cd34"
    run.mkdir()
    (run / "record.jsonl").write_text(json.dumps({"type": "start", "time_s": 0.0, "procedure": "certify",
                                                  "rig": {"station": {"simulated": True}}}) + "\n")
    criteria = [{"id": "position_max_mm", "unit": "mm", "value": 0.0412, "expanded_uncertainty": 0.0031,
                 "limit": 0.5, "comparison": "<=", "status": "PASS"},
                {"id": "amplitude_error_pct", "unit": "%", "value": 3.2, "expanded_uncertainty": 0.4,
                 "limit": 2.0, "comparison": "<=", "status": "FAIL"}]
    (run / "certificate.json").write_text(json.dumps({"result": "FAIL", "simulated": True,
                                                      "criteria": criteria}))
    _print_summary(run)
    assert capsys.readouterr().out == textwrap.dedent(f"""\
        certificate: FAIL (simulated rig — not a certificate of hardware)
          criterion             value       U  unit  limit   decision
          position_max_mm      0.0412  0.0031  mm    <= 0.5  PASS
          amplitude_error_pct     3.2     0.4  %     <= 2    FAIL
        run folder: {run}
        """)


PROBE = textwrap.dedent('''
    """Two steps, no plan."""
    from dataclasses import dataclass

    NAME = "probe"

    @dataclass(frozen=True)
    class Parameters:
        pass

    def run(ctx, params):
        with ctx.step("first"):
            ctx.progress(0.5, "half")
        with ctx.step("second"):
            pass
        return {"passed": True, "summary": "probe done"}
''')


def test_a_run_with_output_captured_logs_its_steps_and_names_its_folder(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    proc = tmp_path / "probe.py"
    proc.write_text(PROBE)
    assert main(["run", str(proc), "--runs-dir", str(tmp_path / "runs"), "--no-dashboard"]) == 0
    out, err = capsys.readouterr()
    assert "step 1: first began" in err and "step 2: second done" in err and "\r" not in err
    # no certificate, so no criteria table: the outcome line names the folder
    assert "run folder: " not in out and "pass (exit 0)" in out and str(tmp_path / "runs") in out


def test_the_reduction_after_the_motion_is_shown_as_such_not_as_a_finished_step_with_0_s_left() -> None:
    from rig.run.progress import Processing

    for tty in (True, False):
        state, term, stream, clock = _wired(tty=tty)
        _doc(state, term, {"type": "start", "time_s": 0.0, "parameters": {}})
        _doc(state, term, _step("calibrate", "begin", 0.0))
        _doc(state, term, _step("calibrate", "done", 20.0))
        _doc(state, term, _step("sweep", "begin", 20.0))
        clock.now_s += 1.0
        _progress(state, term, 1.0, "sweep: 30.00 Hz")  # the motion's end
        clock.now_s += 1.0
        _progress(state, term, None, Processing("sweep: reducing frames", 1234, 2880, approximate=True))
        _progress(state, term, None, Processing("sweep: reducing frames", 1240, 2880, approximate=True))
        overview = state.overview()
        assert overview.processing == (1240, 2880) and overview.fraction is None
        assert state.patch({})[0]["progress"]["processing"] == {"done": 1240, "total": 2880}
        text = stream.getvalue()
        if tty:
            last = text.rsplit("\r", 1)[1]  # 1,240 came too soon to be redrawn
            assert last.startswith("[" + "#" * 13 + "-" * 17 + "]       step 2 of 2: sweep · "
                                   "sweep: reducing frames 1,234/≈2,880 · the plan's last step")
            assert "left" not in last and "%" not in last
        else:
            assert text.splitlines()[-1] == ("rig: +       2 s step 2 of 2: sweep — sweep: reducing frames "
                                             "1,234/≈2,880 (not timed by the plan)")
        if not tty:  # one line per 10 %; a short reduction (a calibration pose's 20 frames) is not logged
            assert sum("reducing frames" in line for line in text.splitlines()) == 1
            _progress(state, term, None, Processing("calibrate: reducing frames", 12, 20, approximate=True))
            assert stream.getvalue() == text
        # a plain message after the reduction: the step's estimate by rig time again
        _progress(state, term, None, "sweep: 2,880 frames reduced")
        assert state.overview().processing is None


def test_while_a_step_reduces_the_time_left_counts_it_as_its_motion_last_reported() -> None:
    from rig.run.progress import Processing

    state = DashboardState("certify", plan_steps=lambda start: [("sweep", 100.0), ("report", 30.0)])
    state.on_document({"type": "start", "time_s": 0.0, "parameters": {}})
    state.on_document(_step("sweep", "begin", 0.0))
    state.on_progress(0.5, "calibrate-like: pose 3 of 6")  # a step recording several times
    state.on_progress(None, Processing("sweep: reducing frames", 1, 20))
    assert state.overview().remaining_s == pytest.approx(80.0)  # not the rest of the step dropped
    state.on_progress(1.0, "sweep: 30 Hz")
    assert state.overview().remaining_s == pytest.approx(30.0)
    state.on_progress(None, Processing("sweep: reducing frames", 10, 20))
    assert state.overview().remaining_s == pytest.approx(30.0)
    stream = FakeStream(tty=True)
    term = TerminalProgress(state, stream, clock=FakeClock())
    term.progress(None, "")
    assert "sweep: reducing frames 10/20 · then ≈ 30 s left" in stream.getvalue()
