"""The catalogue of runs: an SQLite index synced with the run folders, never the only copy of anything."""

from __future__ import annotations

import json
import os
import shutil
import sqlite3
from pathlib import Path

from reports.trend import trend_frame, write_trend
from rig.cli import main
from rig.record import catalogue

PROCEDURE = '''
"""A procedure that only records one event: enough for a run folder on the simulated rig."""
from dataclasses import dataclass

NAME = "note"

@dataclass(frozen=True)
class Parameters:
    pass

def run(ctx, params):
    with ctx.step("note"):
        ctx.event("note", {"text": "hello"})
    return {"passed": True, "summary": "noted"}
'''


def _criterion(cid: str, value: float | None, limit: float, status: str) -> dict:
    return {"id": cid, "description": cid.replace("_", " "), "unit": "mm", "value": value,
            "expanded_uncertainty": None if value is None else 0.01, "limit": limit, "comparison": "<=",
            "status": status}


def _run(runs: Path, name: str, *, setup: str = "bench A", started: str = "2026-11-20T10:00:00+00:00",
         result: str | None = "PASS", position_max_mm: float = 0.05, stop: bool = True,
         simulated: bool = False) -> Path:
    """A run folder as the runner writes it: record.jsonl (start, stop) and an issued certificate."""
    folder = runs / name
    folder.mkdir(parents=True)
    docs = [{"type": "start", "time_s": 0.0, "wall_utc": started, "session": 0, "run_id": name,
             "procedure": "certify", "parameters": {},
             "rig": {"station": {"name": setup, "simulated": simulated}}}]
    if stop:
        docs.append({"type": "stop", "time_s": 60.0, "wall_utc": started.replace("10:00", "10:01"),
                     "session": 0, "exit_status": "success", "reason": ""})
    (folder / "record.jsonl").write_text("".join(json.dumps(d) + "\n" for d in docs))
    if result is not None:
        status = "PASS" if result == "PASS" else "FAIL"
        criteria = [_criterion("position_max_mm", position_max_mm, 1.5, status),
                    _criterion("radius_error_mm", None, 0.5, "NOT EVALUATED")]
        (folder / "certificate.json").write_text(json.dumps(
            {"certificate_version": 1, "result": result, "simulated": simulated, "criteria": criteria}))
    return folder


def _rows(runs: Path) -> list[tuple]:
    with sqlite3.connect(catalogue.catalogue_path(runs)) as conn:
        return conn.execute("SELECT * FROM runs ORDER BY run_id").fetchall() + conn.execute(
            "SELECT * FROM criteria ORDER BY run_id, criterion").fetchall()


def test_sync_indexes_new_changed_and_removed_folders(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    _run(runs, "r1", started="2026-11-20T10:00:00+00:00", position_max_mm=0.05)
    _run(runs, "r2", started="2026-11-21T10:00:00+00:00", position_max_mm=0.07)
    _run(runs, "r3", started="2026-11-22T10:00:00+00:00", result=None, stop=False)  # killed before a report
    report = catalogue.sync(runs)
    assert sorted(report.indexed) == ["r1", "r2", "r3"] and not report.removed and not report.unreadable

    entries = catalogue.list_runs(runs)
    assert [e.run_id for e in entries] == ["r1", "r2", "r3"]  # oldest first
    assert (entries[0].setup, entries[0].result, entries[0].exit_status) == ("bench A", "PASS", "success")
    assert entries[2].result is None and entries[2].exit_status is None and entries[2].criteria == ()
    assert [c.value for c in entries[1].criteria] == [0.07, None]

    assert catalogue.sync(runs).indexed == []  # nothing changed: no folder read again

    cert = runs / "r2" / "certificate.json"
    doc = json.loads(cert.read_text())
    doc["criteria"][0]["value"] = 0.09
    cert.write_text(json.dumps(doc))
    os.utime(cert, ns=(cert.stat().st_atime_ns, cert.stat().st_mtime_ns + 10**9))
    shutil.rmtree(runs / "r1")
    report = catalogue.sync(runs)
    assert report.indexed == ["r2"] and report.removed == ["r1"]
    assert [c.value for c in catalogue.find_run(runs, "r2").criteria] == [0.09, None]
    assert catalogue.find_run(runs, "r1") is None


def test_the_index_is_rebuilt_from_the_folders_alone(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    for k in range(3):
        _run(runs, f"r{k}", started=f"2026-11-2{k}T10:00:00+00:00", position_max_mm=0.01 * (k + 1))
    catalogue.sync(runs)
    before = [row[:-1] if len(row) == 11 else row for row in _rows(runs)]  # freshness aside
    catalogue.catalogue_path(runs).unlink()
    catalogue.sync(runs)
    assert [row[:-1] if len(row) == 11 else row for row in _rows(runs)] == before
    with sqlite3.connect(catalogue.catalogue_path(runs)) as conn:  # an index of an older schema version
        conn.execute("PRAGMA user_version = 0")
    assert sorted(catalogue.sync(runs).indexed) == ["r0", "r1", "r2"]


def test_an_unreadable_run_is_reported_and_the_others_are_indexed(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    _run(runs, "good")
    bad = _run(runs, "bad")
    with (bad / "record.jsonl").open("a") as f:
        f.write("{not json\n")
        f.write(json.dumps({"type": "log", "message": "after the damage"}) + "\n")
    report = catalogue.sync(runs)
    assert report.indexed == ["good"] and "bad" in report.unreadable
    assert "line 3" in report.unreadable["bad"]


def test_trend_of_a_setup_over_time(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    for k, value in enumerate((0.05, 0.06, 0.08)):
        _run(runs, f"a{k}", started=f"2026-11-2{k}T10:00:00+00:00", position_max_mm=value)
    _run(runs, "other", setup="bench B", position_max_mm=1.0)
    catalogue.sync(runs)
    frame = trend_frame(catalogue.list_runs(runs, setup="bench A"))
    evaluated = frame[frame["criterion"] == "position_max_mm"]
    assert evaluated["value"].tolist() == [0.05, 0.06, 0.08]
    assert set(frame["run_id"]) == {"a0", "a1", "a2"}
    csv_path, png_path = write_trend(frame, "bench A", tmp_path / "out")
    assert csv_path.name == "trend_bench_A.csv" and png_path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_rig_runs_lists_shows_and_trends(tmp_path: Path, capsys) -> None:
    runs = tmp_path / "runs"
    _run(runs, "r1", started="2026-11-20T10:00:00+00:00", simulated=True)
    _run(runs, "r2", started="2026-11-21T10:00:00+00:00", result="FAIL", position_max_mm=2.0)
    assert main(["runs", "--runs-dir", str(runs)]) == 0
    listing = capsys.readouterr().out
    assert "r1" in listing and "PASS (sim)" in listing and "FAIL" in listing and "1/2" in listing
    assert main(["runs", "show", "r2", "--runs-dir", str(runs)]) == 0
    shown = capsys.readouterr().out
    assert "certificate: FAIL" in shown and "position_max_mm" in shown
    assert main(["runs", "trend", "bench A", "--runs-dir", str(runs), "--out", str(tmp_path / "t")]) == 0
    assert (tmp_path / "t" / "trend_bench_A.png").is_file()
    assert main(["runs", "show", "nope", "--runs-dir", str(runs)]) == 4
    assert main(["runs", "trend", "no such setup", "--runs-dir", str(runs)]) == 4
    assert main(["runs", "show", "--runs-dir", str(runs)]) == 4


def test_a_finished_run_is_in_the_catalogue(tmp_path: Path) -> None:
    proc = tmp_path / "note.py"
    proc.write_text(PROCEDURE)
    runs = tmp_path / "runs"
    assert main(["run", str(proc), "--runs-dir", str(runs)]) == 0
    (folder,) = catalogue.run_folders(runs)
    with sqlite3.connect(catalogue.catalogue_path(runs)) as conn:  # written by the run, not by a sync
        (row,) = conn.execute("SELECT run_id, setup, procedure, exit_status, simulated FROM runs").fetchall()
    assert row == (folder.name, "simulated rig", "note", "success", 1)


def test_the_catalogue_lives_beside_the_runs_and_is_not_taken_for_one(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    _run(runs, "r1")
    catalogue.sync(runs)
    assert (runs / "catalogue.sqlite").is_file() and [p.name for p in catalogue.run_folders(runs)] == ["r1"]
