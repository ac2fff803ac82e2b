"""A run folder of the format before the typed schema (tests/data/run_v0: a simulated `rig certify` run
trimmed to a few segments, its events without ``schema_version``) still loads and reports."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from reports.load import load_record, typed_events
from rig.cli import main
from rig.record.events import AccuracyPoseEvent, SweepEvent
from rig.record.folder import load_folder

OLD_RUN = Path(__file__).parent / "data" / "run_v0"


def test_old_folder_decodes() -> None:
    folder = load_folder(OLD_RUN)
    assert folder.timing is not None and folder.timing.reference_camera in folder.timing.offset_s
    assert folder.calibration is not None and set(folder.calibration.cameras) == {"left", "right"}
    data = load_record(OLD_RUN)
    (sweep,) = typed_events(data.events, SweepEvent)
    assert sweep.segment == "sweep" and sweep.body == "exciter" and len(sweep.profile) >= 2
    assert len(typed_events(data.events, AccuracyPoseEvent)) == 4


def test_rig_report_on_an_old_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "run_v0"
    shutil.copytree(OLD_RUN, run)
    code = main(["report", str(run)])
    out = capsys.readouterr()
    assert "certificate issued" in out.out, out.err
    cert = json.loads((run / "certificate.json").read_text())
    rows = {r["id"]: r for r in cert["criteria"]}
    # this trimmed run keeps 4 accuracy poses, 4 s of the sweep and the rotation: the poses, the rotor and
    # the calibration are evaluated, the repeatability (one cycle) is not, the short sweep fails
    assert code == 1 and cert["result"] == "FAIL"
    for cid in ("position_max_mm", "position_rms_mm", "length_error_mm", "radius_error_mm",
                "frequency_error_pct", "calibration_rms_px", "sync_uncertainty_ms"):
        assert rows[cid]["status"] == "PASS", rows[cid]
    assert rows["repeatability_mm"]["status"] == "NOT EVALUATED"
    assert rows["detection_pct"]["value"] == 100.0
    # the analysis' controller-clock offsets reach the certificate, one per analysed segment
    assert {c["segment"] for c in cert["controller_clock"]} == {"accuracy_frame", "sweep", "sync"}
    assert all(c["u_offset_s"] > 0 for c in cert["controller_clock"])
