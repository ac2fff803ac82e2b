"""The run record: documents, JSON encoding, truncated last line, resume, observations, kill -9."""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import textwrap
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rig.record.jsonenc import dumps, to_jsonable
from rig.record.writer import RecordError, RunRecord, TruncatedRecordWarning, load_run, record_is_open

ROOT = Path(__file__).resolve().parents[1]


class FakeClock:
    """A settable clock (the record only reads it)."""

    def __init__(self, t_s: float = 100.0, virtual: bool = True) -> None:
        self.t_s = t_s
        self._virtual = virtual

    def now_s(self) -> float:
        return self.t_s

    def sleep_s(self, duration_s: float) -> None:
        self.t_s += duration_s

    @property
    def is_virtual(self) -> bool:
        return self._virtual


def _new(tmp_path: Path, clock: FakeClock | None = None) -> RunRecord:
    return RunRecord.create(tmp_path, "sweep", {"max_hz": 30.0, "n": np.int64(3)}, {"station": "sim"},
                            clock or FakeClock(), versions={"python": "x"})


def test_folder_name_and_start_document(tmp_path: Path) -> None:
    rec = _new(tmp_path)
    rec.close()
    assert re.fullmatch(r"\d{8}-\d{6}_sweep_[0-9a-f]{8}", rec.run_dir.name)
    doc = json.loads((rec.run_dir / "record.jsonl").read_text().splitlines()[0])
    assert doc["type"] == "start" and doc["run_id"] == rec.run_dir.name
    assert doc["parameters"] == {"max_hz": 30.0, "n": 3} and doc["rig"] == {"station": "sim"}
    assert doc["clock"] == "virtual" and doc["time_s"] == 100.0 and doc["session"] == 0
    assert doc["uid"].startswith(rec.run_dir.name[-8:])


def test_every_document_type_round_trips_through_load_run(tmp_path: Path) -> None:
    clock = FakeClock()
    rec = _new(tmp_path, clock)
    rec.step_begin("ramp")
    for i in range(3):
        clock.t_s += 1.0
        assert rec.event("exciter", {"frequency_hz": np.float32(10 + i), "setpoint_hz": 10.0 + i,
                                     "pose": np.arange(3.0), "nested": {"a": i}}) == i
    rec.step_done("ramp", outputs=["timing.json"])
    rec.event("arm", {"commanded_pose": [1, 2, 3, 0, 0, 0]})
    rec.interlock("exciter", "frequency 31 Hz above limit 30 Hz")
    rec.log("info", "hello")
    rec.stop("abort", "interlock")
    rec.close()
    run = load_run(rec.run_dir)
    assert not run.truncated_last_line
    assert run.exit_status == "abort" and run.stop["reason"] == "interlock" and run.stop["num_events"] == 4
    ex = run.events["exciter"]
    assert list(ex["seq"]) == [0, 1, 2] and list(ex["time_s"]) == [101.0, 102.0, 103.0]
    assert list(ex["frequency_hz"]) == [10.0, 11.0, 12.0] and list(ex["nested.a"]) == [0, 1, 2]
    assert list(ex["step"]) == ["ramp"] * 3 and ex["pose"][0] == [0.0, 1.0, 2.0]
    assert run.events["arm"]["seq"].tolist() == [0] and run.events["arm"]["step"].tolist() == [None]
    assert run.steps_completed == {"ramp": ["timing.json"]}
    assert run.interlocks["reason"].tolist() == ["frequency 31 Hz above limit 30 Hz"]
    assert run.logs["message"].tolist() == ["hello"]


def test_stop_twice_and_bad_status_raise(tmp_path: Path) -> None:
    rec = _new(tmp_path)
    with pytest.raises(ValueError, match="exit_status 'ok' not allowed; allowed: success, abort, fail"):
        rec.stop("ok")
    rec.stop("success")
    with pytest.raises(RecordError, match="stop already written"):
        rec.stop("fail")
    rec.close()
    with pytest.raises(RecordError, match="closed"):
        rec.event("x", {})


def test_nan_becomes_null_and_unknown_types_raise() -> None:
    assert json.loads(dumps({"type": "x", "v": [np.nan, math.inf, 1.5]}))["v"] == [None, None, 1.5]
    assert to_jsonable({1: np.bool_(True), "p": Path("a/b")}) == {"1": True, "p": "a/b"}
    with pytest.raises(TypeError, match="cannot record a value of type 'object'"):
        dumps({"type": "x", "v": object()})


@given(st.recursive(st.none() | st.booleans() | st.integers(-2**62, 2**62) | st.text(max_size=8)
                    | st.floats(allow_nan=False, allow_infinity=False),
                    lambda kids: st.lists(kids, max_size=4)
                    | st.dictionaries(st.text(max_size=5), kids, max_size=4),
                    max_leaves=20))
def test_plain_json_values_round_trip_exactly(value: object) -> None:
    assert json.loads(dumps({"type": "t", "v": value}))["v"] == value


def test_truncated_last_line_is_dropped_with_a_warning(tmp_path: Path) -> None:
    rec = _new(tmp_path)
    rec.event("exciter", {"frequency_hz": 1.0})
    rec.close()
    with open(rec.path, "ab") as fh:
        fh.write(b'{"type":"event","stream":"exc')
    with pytest.warns(TruncatedRecordWarning, match="last line truncated"):
        run = load_run(rec.run_dir)
    assert run.truncated_last_line and len(run.events["exciter"]) == 1 and run.stop is None


def test_corrupt_line_in_the_middle_raises_naming_it(tmp_path: Path) -> None:
    rec = _new(tmp_path)
    rec.close()
    lines = rec.path.read_bytes() + b"garbage\n" + b'{"type":"log","session":0}\n'
    rec.path.write_bytes(lines)
    with pytest.raises(RecordError, match="line 2 is not a valid record document"):
        load_run(rec.run_dir)


def test_resume_repairs_the_record_and_continues_seq_and_sessions(tmp_path: Path) -> None:
    clock = FakeClock()
    rec = _new(tmp_path, clock)
    rec.step_begin("a")
    rec.event("s", {"v": 0})
    rec.step_done("a")
    rec.step_begin("b")
    rec.event("s", {"v": 1})
    obs = rec.observation_writer("left")
    obs.append({"frame_index": [0, 0], "timestamp_s": [0.0, 0.0], "u_px": [1.0, 2.0], "v_px": [3.0, 4.0]})
    obs.flush()
    rec._fh.write(b'{"type":"ev')  # killed mid-line
    rec._fh.flush()
    rec2 = RunRecord.resume(rec.run_dir, clock, rig_snapshot={"station": "sim"}, versions={})
    assert rec2.session == 1 and rec2.completed_steps == {"a": []} and rec2.procedure == "sweep"
    rec2.step_begin("b")
    assert rec2.event("s", {"v": 2}) == 2
    w = rec2.observation_writer("left")
    w.append({"frame_index": [5], "timestamp_s": [0.1], "u_px": [9.0], "v_px": [9.0]})
    rec2.step_done("b")
    rec2.stop("success")
    rec2.close()
    run = load_run(rec.run_dir)
    assert not run.truncated_last_line and len(run.starts) == 2 and run.starts[1]["resume"] is True
    assert run.exit_status == "success" and run.stop["num_events"] == 3
    assert "truncated last line was removed" in run.logs["message"].iloc[0]
    # the first, interrupted attempt at step b is superseded by the completed one
    assert run.events["s"]["v"].tolist() == [0, 2]
    assert run.observations["left"]["frame_index"].tolist() == [5]
    full = load_run(rec.run_dir, include_superseded=True)
    assert full.events["s"]["v"].tolist() == [0, 1, 2] and len(full.observations["left"]) == 3
    with pytest.raises(RecordError, match="already completed successfully"):
        RunRecord.resume(rec.run_dir, clock, rig_snapshot={})


def test_observation_parts_and_leftover_tmp(tmp_path: Path) -> None:
    rec = _new(tmp_path)
    rec.step_begin("plate")
    w = rec.observation_writer("right", chunk_rows=4)
    markers = np.zeros(3, dtype=[("u_px", "f8"), ("v_px", "f8"), ("area_px", "f8"), ("roundness", "f8"),
                                 ("contrast", "f8"), ("flags", "u1")])
    markers["u_px"] = [1, 2, 3]
    for n in range(3):
        w.append(markers, frame_index=n, timestamp_s=n / 60)
    parts = sorted((rec.run_dir / "observations" / "right").glob("part-*.parquet"))
    assert [p.name for p in parts] == ["part-00000.parquet"]  # 6 rows ≥ 4 → one chunk, 3 buffered
    (rec.run_dir / "observations" / "right" / "part-00001.parquet.tmp").write_bytes(b"PAR1 half")
    rec.stop("success")
    rec.close()
    obs = load_run(rec.run_dir).observations["right"]
    assert len(obs) == 9 and obs["frame_index"].tolist() == [0, 0, 0, 1, 1, 1, 2, 2, 2]
    assert set(obs["segment"]) == {"plate"} and obs["row_time_s"].isna().all()
    assert obs["flags"].dtype == np.uint8
    with pytest.raises(ValueError, match="lack required column"):
        rec.observation_writer("x").append(pd.DataFrame({"u_px": [1.0]}))
    with pytest.raises(ValueError, match="camera name"):
        rec.observation_writer("../evil")


WRITER = textwrap.dedent("""
    import sys, time
    import numpy as np
    from rig.record.writer import RunRecord
    class C:
        is_virtual = False
        def now_s(self): return time.monotonic()
    rec = RunRecord.create(sys.argv[1], "soak", {}, {}, C(), versions={})
    w = rec.observation_writer("left", chunk_rows=50)
    print(rec.run_dir, flush=True)
    i = 0
    while True:
        rec.event("tick", {"i": i, "payload": "x" * 200})
        w.append({"frame_index": [i], "timestamp_s": [i / 60], "u_px": [1.0], "v_px": [2.0]})
        i += 1
""")


def test_kill_9_leaves_a_readable_record(tmp_path: Path) -> None:
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(tmp_path)], stdout=subprocess.PIPE, text=True,
                            cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    run_dir = Path(proc.stdout.readline().strip())
    time.sleep(0.8)
    assert record_is_open(run_dir)  # the run is still going: `rig report` refuses it
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=10)
    proc.stdout.close()
    assert not record_is_open(run_dir)  # killed: the kernel released its lock
    with warnings.catch_warnings():  # the kill may or may not land mid-line; both must load
        warnings.simplefilter("ignore", TruncatedRecordWarning)
        run = load_run(run_dir)
    ticks = run.events["tick"]["i"].tolist()
    assert len(ticks) > 10 and ticks == list(range(len(ticks)))
    obs = run.observations["left"]
    assert len(obs) % 50 == 0 and obs["frame_index"].tolist() == list(range(len(obs)))
    assert run.stop is None


def test_a_quiet_record_is_still_fsynced_within_the_interval(tmp_path: Path,
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    synced: list[int] = []
    real_fsync = os.fsync
    monkeypatch.setattr("rig.record.writer.os.fsync", lambda fd: (synced.append(fd), real_fsync(fd))[1])
    rec = RunRecord.create(tmp_path, "quiet", {}, {}, FakeClock(), versions={}, fsync_interval_s=0.05)
    n_after_start = len(synced)
    rec.event("s", {"v": 1})  # within the interval of the start's fsync: not synced by the write itself
    deadline = time.monotonic() + 5.0
    while (len(synced) == n_after_start or rec._dirty) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert len(synced) > n_after_start and not rec._dirty
    rec.close()


def test_extra_columns_are_kept_and_missing_values_are_null(tmp_path: Path) -> None:
    rec = _new(tmp_path)
    w = rec.observation_writer("left", segment="s1")
    w.append(pd.DataFrame({"frame_index": [0, 0], "timestamp_s": [0.0, 0.0], "u_px": [1.0, 2.0],
                           "v_px": [1.0, 2.0]}))
    w.append({"frame_index": [1], "timestamp_s": [0.1], "u_px": [3.0], "v_px": [3.0], "marker_id": ["arm"]})
    w.append({"frame_index": 2, "timestamp_s": 0.2, "u_px": 4.0, "v_px": 4.0})  # scalars: one row
    with pytest.raises(ValueError, match="observation columns differ in length"):
        w.append({"frame_index": [3, 3], "timestamp_s": [0.3], "u_px": [5.0, 5.0], "v_px": [5.0, 5.0]})
    rec.stop("success")
    rec.close()
    obs = load_run(rec.run_dir).observations["left"]
    assert obs["frame_index"].tolist() == [0, 0, 1, 2] and obs["u_px"].tolist() == [1.0, 2.0, 3.0, 4.0]
    assert obs["marker_id"].isna().tolist() == [True, True, False, True] and obs["marker_id"][2] == "arm"
    assert set(obs["segment"]) == {"s1"} and obs["flags"].tolist() == [0, 0, 0, 0]
