"""Loading a run folder into the reports' frames (through rig.record.writer.load_run)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import reports_synth as synth

from reports.errors import RunFolderError
from reports.load import accuracy_poses, calibration_residuals, load_record, stream_events
from rig.record.folder import Calibration


def test_events_and_side_files(tmp_path: Path) -> None:
    run = load_record(synth.write_run(tmp_path / "r"))
    assert run.run_id == "r" and run.exit_status == "success"
    assert run.events.groupby("stream").size().to_dict() == {
        "accuracy_pose": len(synth.accuracy_events()),
        "plate": 1,
        "rotation": 1,
        "sweep": 1,
    }
    assert stream_events(run.events, "sweep")[0]["profile"] == synth.sweep_profile()
    poses = accuracy_poses(run.events)
    assert len(poses) == len(synth.accuracy_events()) * len(synth.FRAME_MARKERS_MM)
    assert {"x_cmd_mm", "y_cmd_mm", "z_cmd_mm", "t_start_s", "t_stop_s"} <= set(poses.columns)
    assert run.calibration is not None and run.calibration.convention == "homogeneous-svd"
    assert run.timing is not None and run.timing.reference_camera == "left"
    res = calibration_residuals(run.calibration).set_index("camera")
    assert res.loc["right", "rms_px"] == pytest.approx(0.31)
    assert res.loc["left", "max_px"] == pytest.approx(0.2)


def test_documents_without_session_field(tmp_path: Path) -> None:
    """contracts.md does not require ``session``: a hand-written record must load the same."""
    run_dir = synth.write_run(tmp_path / "r")
    docs = [json.loads(x) for x in (run_dir / "record.jsonl").read_text().splitlines()]
    for d in docs:
        d.pop("session", None)
    (run_dir / "record.jsonl").write_text("".join(json.dumps(d) + "\n" for d in docs))
    run = load_record(run_dir)
    assert len(stream_events(run.events, "accuracy_pose")) == len(synth.accuracy_events())


def test_truncated_last_line_is_tolerated(tmp_path: Path) -> None:
    run_dir = synth.write_run(tmp_path / "r")
    with open(run_dir / "record.jsonl", "a") as fh:
        fh.write('{"type": "event", "stream": "sweep", "seq": 1, "da')
    with pytest.warns(UserWarning, match="truncated"):
        run = load_record(run_dir)
    assert run.truncated_last_line
    assert len(stream_events(run.events, "sweep")) == 1


def test_missing_folder_or_record_raises(tmp_path: Path) -> None:
    with pytest.raises(RunFolderError, match="no record"):
        load_record(tmp_path / "nowhere")
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "record.jsonl").write_text('{"type": "stop", "time_s": 0}\n')
    with pytest.raises(RunFolderError, match="start"):
        load_record(tmp_path / "r")


def test_bad_accuracy_event_names_the_field(tmp_path: Path) -> None:
    run_dir = synth.write_run(tmp_path / "r")
    run = load_record(run_dir)
    ev = run.events.copy()
    first = ev.index[ev["stream"] == "accuracy_pose"][0]
    ev.at[first, "data"] = dict(ev.at[first, "data"], markers={"frame0": [1.0, 2.0]})
    with pytest.raises(RunFolderError, match=r"markers\['frame0'\]"):
        accuracy_poses(ev)
    ev.at[first, "data"] = {"index": 0}
    with pytest.raises(RunFolderError, match="t_start_s"):
        accuracy_poses(ev)


def test_camera_centres_need_a_valid_p() -> None:
    from reports.load import camera_centres_mm

    calib = {"cameras": {"a": {"P": np.zeros((3, 4)).tolist()}, "b": {"P": [[1, 2]]}, "c": {}}}
    assert camera_centres_mm(Calibration.from_dict(calib)) == {}
