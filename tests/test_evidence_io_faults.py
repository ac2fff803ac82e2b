"""I/O faults end to end: a full disk (a small tmpfs) and a read-only folder (a read-only mount) under
`rig calibrate`, `rig measure`, `rig report` and `rig run` → exit 3 with a one-line message, no traceback,
and no result left 0-byte or half-written under its final name; an issued certificate is never touched.
Plus the atomic writer under injected faults (no mount needed)."""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from fs_faults import fill, half_written, remount_read_only, tmpfs, tree

from reports.build import build_report
from rig.cli import main
from rig.record import atomic
from rig.record.writer import load_run

ROOT = Path(__file__).resolve().parents[1]

FILLER_PROCEDURE = textwrap.dedent('''
    """Runs the exciter, then its result file meets a disk that another writer filled."""
    from dataclasses import dataclass

    NAME = "filler"

    @dataclass(frozen=True)
    class Parameters:
        pass

    def run(ctx, params):
        ctx.device("exciter").set_frequency(3.0)
        with open(ctx.run_dir / "filler.bin", "wb", buffering=0) as fh:  # someone else fills the disk
            try:
                while True:
                    fh.write(b"x" * 4096)
            except OSError:
                pass
        with ctx.step("result") as step:
            step.output(ctx.write_json("result.json", {"samples": list(range(20000))}))
        return {"passed": True, "summary": "done"}
''')


def _one_line_error(err: str, *needles: str) -> None:
    """stderr is one line, no traceback, naming every needle."""
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert "Traceback" not in err and len(lines) == 1, err
    assert all(n in lines[0] for n in needles), lines[0]


# ---------------------------------------------------------------------------------- the atomic writer
def test_atomic_write_keeps_the_old_file_when_the_writer_or_the_rename_fails(tmp_path: Path,
                                                                             monkeypatch) -> None:
    target = atomic.write_text(tmp_path / "timing.json", "old\n")
    with pytest.raises(RuntimeError, match="writer died"), atomic.atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("writer died")
    assert target.read_text() == "old\n" and [p.name for p in tmp_path.iterdir()] == ["timing.json"]

    def no_rename(src, dst):
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(atomic.os, "replace", no_rename)
    with pytest.raises(OSError, match="Input/output"):
        atomic.write_json(target, {"new": 1})
    assert target.read_text() == "old\n" and [p.name for p in tmp_path.iterdir()] == ["timing.json"]


def test_atomic_write_keeps_its_format_suffix_and_replaces_whole(tmp_path: Path) -> None:
    seen = []
    with atomic.atomic_path(tmp_path / "summary.csv") as tmp:
        seen.append(tmp)
        tmp.write_text("a,b\n1,2\n")
    assert seen[0].suffix == ".csv" and seen[0].parent == tmp_path and seen[0].name.startswith(".")
    assert (tmp_path / "summary.csv").read_text() == "a,b\n1,2\n" and not seen[0].exists()


def test_atomic_write_on_a_full_disk_leaves_the_old_file_whole(tmp_path: Path) -> None:
    with tmpfs(tmp_path / "disk", 64 * 1024) as disk:
        old = atomic.write_text(disk / "calibration.json", '{"old": true}\n')
        fill(disk)
        with pytest.raises(OSError) as info:
            atomic.write_text(old, "x" * 200_000)
        assert info.value.errno == errno.ENOSPC
        assert old.read_text() == '{"old": true}\n'
        assert sorted(p.name for p in disk.iterdir()) == ["calibration.json", "filler.bin"]


# ---------------------------------------------------------------------------------- videos
@pytest.fixture(scope="module")
def site(mjpg_site: dict) -> dict:
    return mjpg_site  # built once per session (tests/conftest.py)


def _calibrate(site: dict, out: Path) -> int:
    f = site["folder"]
    return main(["calibrate", str(f / "cal_left.avi"), str(f / "cal_right.avi"), "--target",
                 str(site["target"]), "--out", str(out)])


def _measure(site: dict, out: Path) -> int:
    f = site["folder"]
    return main(["measure", str(site["paths"][0]), str(site["paths"][1]), "--calibration",
                 str(f / "calibration.json"), "--timing", str(f / "timing.json"), "--out", str(out)])


def test_calibrate_on_a_full_disk_exits_3_and_leaves_no_calibration(
        site: dict, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with tmpfs(tmp_path / "disk", 64 * 1024) as disk:
        fill(disk)
        capsys.readouterr()
        assert _calibrate(site, disk / "calibration.json") == 3
        _one_line_error(capsys.readouterr().err, f"No space left on device: {disk / 'calibration.json'}")
        assert sorted(p.name for p in disk.iterdir()) == ["filler.bin"]  # no 0-byte calibration.json


def test_calibrate_into_a_read_only_folder_exits_3(site: dict, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    with tmpfs(tmp_path / "disk", 1 << 20) as disk:
        remount_read_only(disk)
        capsys.readouterr()
        assert _calibrate(site, disk / "calibration.json") == 3
        _one_line_error(capsys.readouterr().err, f"Read-only file system: {disk / 'calibration.json'}")


def test_measure_on_a_disk_that_fills_exits_3_with_every_written_file_whole(
        site: dict, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    full = tmp_path / "reference"
    assert _measure(site, full) == 0
    need = sum(len(b) for b in tree(full).values())
    with tmpfs(tmp_path / "disk", need // 2) as disk:  # the disk fills half-way through the outputs
        capsys.readouterr()
        assert _measure(site, disk / "out") == 3
        _one_line_error(capsys.readouterr().err, "No space left on device")
        written = tree(disk / "out")
        assert written and half_written(disk / "out") == []
        reference = tree(full)
        for name, data in written.items():  # what carries a final name is complete (the same bytes)
            if name.endswith(".csv"):
                assert data == reference[name], name
            elif name.endswith(".json"):
                json.loads(data)


def test_measure_into_a_read_only_folder_exits_3(site: dict, tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    with tmpfs(tmp_path / "disk", 1 << 20) as disk:
        remount_read_only(disk)
        capsys.readouterr()
        assert _measure(site, disk / "out") == 3
        _one_line_error(capsys.readouterr().err, "Read-only file system")


# ---------------------------------------------------------------------------------- a run and its report
def _rig(*argv: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """``rig`` in its own process: what a user sees on the console (the logging set up by rig itself)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "rig.cli", *argv], capture_output=True, text=True, env=env,
                          cwd=cwd, timeout=600, check=False)


def test_run_on_a_disk_that_fills_makes_the_devices_safe_and_exits_3(tmp_path: Path) -> None:
    proc = tmp_path / "filler.py"
    proc.write_text(FILLER_PROCEDURE)
    with tmpfs(tmp_path / "disk", 256 * 1024) as disk:
        done = _rig("run", str(proc), "--no-dashboard", "--runs-dir", str(disk), cwd=tmp_path)
        assert done.returncode == 3, done.stderr
        lines = done.stderr.strip().splitlines()
        assert "Traceback" not in done.stderr, done.stderr
        assert "[Errno 28] No space left on device" in lines[-1], lines
        # besides the exit line, only the steps' progress lines (stderr is not a terminal) and one-line
        # warnings (e.g. the catalogue of runs could not be updated)
        assert all(ln.startswith(("WARNING ", "rig: +")) for ln in lines[:-1]), lines
        (run_dir,) = [p for p in disk.iterdir() if p.is_dir()]  # beside it, maybe the catalogue of runs
        assert not (run_dir / "result.json").exists() and half_written(run_dir) == []
        run = load_run(run_dir)  # readable up to its last line
        if run.stop is not None:  # written when the disk still had room for it (the runner's contract)
            assert run.stop["outcome"] == "fault" and "No space left on device" in run.stop["reason"]
        assert "Traceback" in (run_dir / "rig.log").read_text()  # the traceback is kept, in rig.log only


def test_run_into_a_read_only_runs_folder_exits_3_before_any_device(tmp_path: Path) -> None:
    proc = tmp_path / "filler.py"
    proc.write_text(FILLER_PROCEDURE)
    with tmpfs(tmp_path / "disk", 1 << 20) as disk:
        remount_read_only(disk)
        done = _rig("run", str(proc), "--no-dashboard", "--runs-dir", str(disk), cwd=tmp_path)
        assert done.returncode == 3, done.stderr
        assert "Traceback" not in done.stderr and "Read-only file system" in done.stderr.splitlines()[-1]
        assert list(disk.iterdir()) == []


@pytest.fixture(scope="module")
def real_run(rotation_run: dict) -> Path:
    """A rotation run on the simulated rig (calibrate, sync, rotation, report): its certificate issued. The
    session's (tests/conftest.py), read-only: the tests report on copies of it. Its reports (and the tests'
    `rig report`s of its copies) compute the certificate only: [report] no comparison, no figure
    (certify_support.write_config) — these tests are about the disk, not what a report draws."""
    run_dir: Path = rotation_run["run_dir"]
    assert rotation_run["code"] in (0, 1)  # 1: a single procedure's certificate is INCOMPLETE
    assert (run_dir / "certificate.json").is_file()
    return run_dir


def _copy_run(run_dir: Path, disk: Path, *, issued: bool) -> Path:
    copy = disk / run_dir.name
    shutil.copytree(run_dir, copy)
    if not issued:  # a run killed before its report: the first `rig report` issues the certificate
        for name in ("certificate.json", "report.html"):
            (copy / name).unlink()
        shutil.rmtree(copy / "tables")  # (no figures/: [report] figures = false)
    return copy


def _disk_size(run_dir: Path) -> int:
    return sum(p.stat().st_size for p in run_dir.rglob("*") if p.is_file()) + (1 << 20)


@pytest.mark.slow
@pytest.mark.parametrize("issued", [True, False], ids=["revision", "first_report"])
def test_report_on_a_full_disk_exits_3_and_writes_nothing_half(real_run: Path, tmp_path: Path, issued: bool,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    with tmpfs(tmp_path / "disk", _disk_size(real_run)) as disk:
        run = _copy_run(real_run, disk, issued=issued)
        before = tree(run)
        filler = fill(disk)
        capsys.readouterr()
        assert main(["report", str(run), "--sync", "linear"]) == 3
        _one_line_error(capsys.readouterr().err, "No space left on device")
        analysed: list[object] = []  # refused before the analysis (minutes on a long run), not after it
        with pytest.raises(OSError, match="No space left on device"):
            build_report(run, analysis=lambda *args, **kwargs: analysed.append(args))
        assert analysed == []
        after = tree(run)
        assert half_written(run) == []
        assert {k: v for k, v in after.items() if k in before} == before  # nothing rewritten
        if issued:
            assert set(after) == set(before)  # no revision folder, no staging left
            revisions = run / "revisions"  # refused before the analysis: not even created
            assert not revisions.exists() or sorted(p.name for p in revisions.iterdir()) == []
        else:
            assert "certificate.json" not in after  # not issued: the next `rig report` issues it
            filler.unlink()
            result = json.loads((real_run / "certificate.json").read_text())["result"]
            assert main(["report", str(run)]) == (0 if result == "PASS" else 1)
            assert json.loads((run / "certificate.json").read_text())["result"] == result


@pytest.mark.slow
def test_report_of_a_read_only_run_exits_3(real_run: Path, tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    with tmpfs(tmp_path / "disk", _disk_size(real_run)) as disk:
        run = _copy_run(real_run, disk, issued=True)
        remount_read_only(disk)
        capsys.readouterr()
        assert main(["report", str(run)]) == 3
        _one_line_error(capsys.readouterr().err, "Read-only file system")
        analysed: list[object] = []  # refused before the analysis (minutes on a long run), not after it
        with pytest.raises(OSError, match="Read-only file system"):
            build_report(run, analysis=lambda *args, **kwargs: analysed.append(args))
        assert analysed == []


@pytest.mark.slow
def test_report_of_an_issued_run_writes_a_revision_and_says_so(real_run: Path, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / real_run.name
    shutil.copytree(real_run, run)
    before = tree(run)
    capsys.readouterr()
    code = main(["report", str(run), "--sync", "linear"])
    out = capsys.readouterr().out
    assert {k: v for k, v in tree(run).items() if not k.startswith("revisions/")} == before
    issued = json.loads((run / "certificate.json").read_text())["result"]
    assert f"already has an issued certificate ({issued}); it is not rewritten" in out
    changes = json.loads((run / "revisions" / "1-linear" / "changes.json").read_text())
    assert f"Revision 1 (sync linear): {changes['revised_result']}" in out
    assert code == (0 if changes["revised_result"] == "PASS" else 1)
    assert changes["issued_result"] == issued and changes["sync_method"] == "linear"
    assert os.path.isfile(run / "revisions" / "1-linear" / "certificate.json")
