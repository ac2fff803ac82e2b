"""The record's typed documents (rig.record.events): round trips, old (unversioned) data, errors that name
the field; the writer records them and the reader decodes them back."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.sim.clock import VirtualClock
from rig.record.events import (
    EVENT_SCHEMA_VERSION,
    EVENT_TYPES,
    VERSION_KEY,
    AccuracyPoseEvent,
    CameraEvent,
    EventSchemaError,
    StartDocument,
    StopDocument,
    SweepEvent,
)
from rig.record.reader import load_run
from rig.record.writer import RunRecord

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


sweeps = st.builds(
    SweepEvent, t_start_s=finite, t_stop_s=finite, amplitude_mm=finite,
    axis=st.lists(finite, min_size=3, max_size=3),
    profile=st.lists(st.lists(finite, min_size=2, max_size=2), min_size=2, max_size=5),
    segment=st.one_of(st.none(), st.text(max_size=8)),
    amplitude_vpp=st.one_of(st.none(), finite, st.lists(finite, max_size=3)))


@given(ev=sweeps)
def test_sweep_round_trips_through_json(ev: SweepEvent) -> None:
    data = json.loads(json.dumps(ev.to_dict()))
    assert data[VERSION_KEY] == EVENT_SCHEMA_VERSION
    assert SweepEvent.from_dict(data) == ev


def test_unversioned_data_of_an_old_record_decodes() -> None:
    old = {"t_start_s": 1.0, "t_stop_s": 2.0, "amplitude_mm": 5, "axis": [1, 0, 0], "marker_ids": ["col0"],
           "profile": [[1, 1.5], [2, 3]], "segment": "sweep", "recording": [0.9, 2.1]}
    ev = SweepEvent.from_dict(old)
    assert ev.amplitude_mm == 5.0 and isinstance(ev.amplitude_mm, float) and ev.body == "exciter"
    assert ev.profile == [[1.0, 1.5], [2.0, 3.0]] and ev.extra == {}


def test_unknown_fields_are_kept_and_written_back() -> None:
    data = {"camera": "left", "action": "start", "t_s": 3.0, "first_timestamp_s": 0.5, "gain_db": 6}
    ev = CameraEvent.from_dict(data)
    assert ev.extra == {"gain_db": 6} and ev.to_dict()["gain_db"] == 6


@pytest.mark.parametrize(("data", "match"), [
    ({"index": 0, "t_stop_s": 1.0, "markers": {}}, r"accuracy_pose: missing field 't_start_s'"),
    ({"index": 0, "t_start_s": "soon", "t_stop_s": 1.0, "markers": {}}, r"accuracy_pose\.t_start_s.*number"),
    ({"index": 0.5, "t_start_s": 0, "t_stop_s": 1.0, "markers": {}}, r"accuracy_pose\.index.*integer"),
    ({"index": 0, "t_start_s": 0, "t_stop_s": 1, "markers": {"a": [1, "x", 3]}}, r"markers\.a\[1\]"),
    ({"index": 0, "t_start_s": 0, "t_stop_s": 1, "markers": {}, VERSION_KEY: EVENT_SCHEMA_VERSION + 1},
     r"schema_version .* update rig-controller"),
])
def test_a_bad_document_names_the_field(data, match) -> None:
    with pytest.raises(EventSchemaError, match=match):
        AccuracyPoseEvent.from_dict(data)


def test_every_stream_type_names_its_stream() -> None:
    assert set(EVENT_TYPES) == {"sweep", "band_sweep", "accuracy_pose", "calibration_position", "plate",
                                "rotation", "arm", "camera"}


def test_writer_records_typed_documents_and_the_reader_decodes_them(tmp_path) -> None:
    rec = RunRecord.create(tmp_path, "demo", {"n": 1}, {"cameras": {}}, VirtualClock(), versions={})
    rec.step_begin("sweep")
    ev = SweepEvent(t_start_s=0.0, t_stop_s=1.0, amplitude_mm=5.0, axis=[1.0, 0.0, 0.0],
                    profile=[[0.0, 1.0], [1.0, 2.0]], segment="sweep")
    rec.event("sweep", ev)
    with pytest.raises(ValueError, match="stream 'sweep', not 'camera'"):
        rec.event("camera", ev)
    rec.step_done("sweep")
    rec.stop("success", "done")
    rec.close()
    run = load_run(rec.run_dir)
    assert SweepEvent.from_dict(run.event_documents("sweep")[0]["data"]) == ev
    start = StartDocument.from_dict(run.start)
    assert start.procedure == "demo" and start.clock == "virtual" and start.resume is False
    stop = StopDocument.from_dict(run.stop or {})
    assert stop.exit_status == "success" and stop.num_events == 1
    assert math.isclose(run.events["sweep"]["amplitude_mm"].iloc[0], 5.0)
