"""build_report on a synthetic run folder (analysis injected): outputs, exact values, determinism."""

from __future__ import annotations

import contextlib
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import reports_synth as synth

from reports.build import build_report
from reports.errors import CriteriaError, RunFolderError
from reports.scope import Scope

NO_FIGURES = Scope(figures=False)  # the figures' own tests draw them


@pytest.fixture(scope="module")
def built(tmp_path_factory, synth_report):
    """The synthetic run's first report (the session's, tests/conftest.py), on this module's copy of its run
    folder: the tests here write revisions into it."""
    run_dir = tmp_path_factory.mktemp("runs") / synth.RUN_NAME
    shutil.copytree(synth_report.run_dir, run_dir)
    return synth.moved(synth_report, run_dir)


def test_outputs_exist(built) -> None:
    run = built.run_dir
    assert built.report_html == run / "report.html" and built.report_html.stat().st_size > 50_000
    assert built.certificate_json == run / "certificate.json"
    for name in (
        "position_errors",
        "iso9283",
        "length_errors",
        "sweep_bins",
        "quadratic_fit",
        "criteria",
        "calibration_residuals",
        "timing",
        "plate",
        "rotation_summary",
        "rotor_spectrum",
    ):
        assert (run / "tables" / f"{name}.csv").is_file(), name
    assert set(built.figures) == {
        "error_vectors",
        "error_vs_position",
        "amplitude_error_vs_frequency",
        "sweep_time_frequency",
        "phase_vs_frequency",
        "trajectory",
        "rotation_radius",
        "spectrum",
    }
    for path in built.figures.values():
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_certificate_values(built) -> None:
    cert = json.loads(built.certificate_json.read_text())
    assert cert["result"] == built.result == "PASS"
    rows = {r["id"]: r for r in cert["criteria"]}
    assert rows["position_max_mm"]["value"] == pytest.approx(np.sqrt(0.3**2 + 0.1**2 + 0.04**2), abs=1e-9)
    assert rows["position_max_mm"]["limit"] == 1.0  # from the run's rig snapshot, not the default
    # reference_u_mm default 0.02 → U = 0.04 on an exact measurement
    assert rows["position_max_mm"]["expanded_uncertainty"] == pytest.approx(0.04, abs=1e-9)
    c0, c2 = synth.SWEEP_COEFFS["trajectory"]
    assert rows["amplitude_error_pct"]["value"] == pytest.approx(abs(c0 + c2 * 15.0**2), abs=1e-8)
    # plate and rotor run at exactly their commanded frequencies
    assert rows["frequency_error_pct"]["value"] == pytest.approx(0.0, abs=1e-6)
    assert rows["frequency_error_pct"]["status"] == "PASS"
    budget = {c["component"]: c for c in rows["position_max_mm"]["budget"]}
    assert budget["reference position (robot AP / artefact)"] == {
        "component": "reference position (robot AP / artefact)",
        "type": "B",
        "u": 0.02,
    }
    assert rows["min_usable_frequency_hz"]["value"] == pytest.approx(max(synth.SWEEP_FREQS_HZ))
    assert rows["radius_error_mm"]["value"] == pytest.approx(0.3, abs=1e-9)
    assert rows["calibration_rms_px"]["value"] == pytest.approx(0.31)
    # timing.json's camera offset (0.02 ms); the analysis' controller clock is named beside it
    sync = rows["sync_uncertainty_ms"]
    assert sync["value"] == pytest.approx(0.02) and "controller clock" in sync["note"]
    assert "u = 0.01 ms at worst (segment 'sweep')" in sync["note"]
    assert cert["controller_clock"] == [{"segment": "sweep", "session": 0, "offset_s": 0.0,
                                         "u_offset_s": pytest.approx(1e-5),
                                         "source": "timing fiducial (synthetic)"}]
    # the synthetic tracks carry no delay: τ ≈ 0 within its budget, the clock's u as the analysis states it
    assert abs(cert["phase"]["delay_ms"]) <= 3 * cert["phase"]["u_delay_ms"]
    assert rows["phase_delay_ms"]["status"] == "PASS"
    assert rows["controller_clock_u_ms"]["value"] == pytest.approx(0.01)
    assert rows["detection_pct"]["value"] == 100.0
    lin = cert["usable_frequency"]["linear"]
    c0l, c2l = synth.SWEEP_COEFFS["linear"]
    assert lin["limit_hz"] == pytest.approx(np.sqrt((-5.0 - c0l) / c2l), rel=1e-8)
    assert lin["reached_within_tested_range"] is True
    cond = cert["conditions"]
    assert cond["run_id"] == built.run_dir.name and cond["date_utc"].startswith("2026-11-21T23:15")
    assert cond["sync_method"] == "trajectory" and cond["compared_sync_methods"] == ["linear"]
    assert cond["rig"]["criteria"]["min_usable_frequency_hz"] == 15.0
    assert cond["versions"]["rig-controller"] == "0.1.0"
    assert "ILAC-G8" in cert["decision_rule"]["text"]


def test_tables_have_units_and_exact_values(built) -> None:
    fits = pd.read_csv(built.tables["quadratic_fit"]).set_index("sync_method")
    for method, (c0, c2) in synth.SWEEP_COEFFS.items():
        assert fits.loc[method, "track_delay_ms"] == pytest.approx(
            1000 * synth.SWEEP_DELAY_S[method], abs=1e-6
        )
        assert fits.loc[method, "c0_pct"] == pytest.approx(c0, abs=1e-8)
        assert fits.loc[method, "c2_pct_per_hz2"] == pytest.approx(c2, abs=1e-10)
    bins = pd.read_csv(built.tables["sweep_bins"])
    assert {
        "frequency_hz",
        "amplitude_ref_mm",
        "amplitude_meas_mm",
        "amplitude_error_pct",
        "phase_deg",
    } <= set(bins.columns)
    for method, g in bins.groupby("sync_method"):
        np.testing.assert_allclose(
            g["amplitude_error_pct"], synth.sweep_error_pct(g["frequency_hz"], method), atol=1e-7
        )
    poses = pd.read_csv(built.tables["position_errors"])
    assert {"x_cmd_mm", "x_meas_mm", "ex_mm", "error_mm", "distance_mm", "off_axis_mm"} <= set(poses.columns)
    numeric = [c for c in pd.read_csv(built.tables["iso9283"]).columns if c not in ("target", "marker_id")]
    assert all(c.endswith(("_mm", "_cycles")) for c in numeric)


def test_rebuild_writes_a_byte_identical_revision_and_never_touches_the_issued_report(built) -> None:
    run = built.run_dir
    issued = sorted(
        [*run.glob("tables/*.csv"), *run.glob("figures/*.png"), run / "certificate.json", run / "report.html"]
    )
    before = {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in issued}
    again = build_report(run, analysis=synth.fake_analyse)
    assert [(p.read_bytes(), p.stat().st_mtime_ns) for p in issued] == list(before.values())
    assert again.revision is not None and again.revision.parent == run / "revisions"
    assert again.revision.name.endswith("-trajectory") and again.certificate_json.parent == again.revision
    assert again.result == built.result
    rebuilt = {p: again.revision / p.relative_to(run) for p in issued if p.suffix in (".csv", ".png")}
    assert [p.name for p, q in rebuilt.items() if p.read_bytes() != q.read_bytes()] == []
    revised = json.loads(again.certificate_json.read_text())
    notes = revised["conditions"].pop("notes")
    original = json.loads(built.certificate_json.read_text())
    assert original["conditions"].pop("notes") == [n for n in notes if not n.startswith("revision ")]
    assert revised == original
    changes = json.loads((again.revision / "changes.json").read_text())
    assert changes["criteria"] == [] and changes["summary"] == ["result PASS (same)"]


def test_a_later_report_with_another_sync_is_a_revision_saying_what_changed(tmp_path: Path) -> None:
    run = synth.write_run(tmp_path / "run_revised")
    issued = build_report(run, analysis=synth.fake_analyse, scope=NO_FIGURES)
    assert issued.result == "PASS" and issued.revision is None and issued.changes is None
    cert_bytes = (run / "certificate.json").read_bytes()
    first = build_report(run, sync="linear", analysis=synth.fake_analyse, scope=NO_FIGURES)
    second = build_report(run, sync="linear", analysis=synth.fake_analyse, scope=NO_FIGURES)
    assert (run / "certificate.json").read_bytes() == cert_bytes  # PASS stays the issued result
    assert first.revision == run / "revisions" / "1-linear"
    assert second.revision == run / "revisions" / "2-linear"
    assert first.result == "FAIL" and json.loads(first.certificate_json.read_text())["result"] == "FAIL"
    changes = json.loads((first.revision / "changes.json").read_text())
    assert changes == first.changes
    assert changes["issued_result"] == "PASS" and changes["revised_result"] == "FAIL"
    rows = {c["id"]: c for c in changes["criteria"]}
    assert rows["min_usable_frequency_hz"]["issued_status"] == "PASS"
    assert rows["min_usable_frequency_hz"]["revised_status"] == "FAIL"
    assert rows["min_usable_frequency_hz"]["revised_value"] == pytest.approx(np.sqrt(5.0 / 0.08), rel=1e-8)
    assert "position_max_mm" not in rows  # the same value and decision under both methods
    assert changes["summary"][0] == "result PASS → FAIL"
    assert any(n.startswith("revision 1 (sync 'linear')") for n in first.notes)
    assert "revision 1 (sync &#x27;linear&#x27;)" in first.report_html.read_text()
    assert sorted(p.name for p in (run / "revisions").iterdir()) == ["1-linear", "2-linear"]  # no staging


def test_a_revision_that_cannot_be_finished_leaves_nothing(tmp_path: Path, monkeypatch) -> None:
    """A disk that fills while a revision is written: no revision folder, no staging, issued untouched."""
    import errno

    from reports import build as build_module

    run = synth.write_run(tmp_path / "run_full")
    build_report(run, analysis=synth.fake_analyse, scope=NO_FIGURES)
    issued = {p: p.read_bytes() for p in run.rglob("*") if p.is_file()}

    def full_disk(path, text, encoding="utf-8"):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(build_module, "write_text", full_disk)
    with pytest.raises(OSError, match="No space left"):
        build_report(run, sync="linear", analysis=synth.fake_analyse, scope=NO_FIGURES)
    assert list((run / "revisions").iterdir()) == []
    assert {p: p.read_bytes() for p in run.rglob("*") if p.is_file()} == issued


def test_the_first_report_of_a_run_killed_before_its_report_issues_the_certificate(tmp_path: Path) -> None:
    run = synth.write_run(tmp_path / "run_killed")
    (run / "tables").mkdir()
    (run / "tables" / "criteria.csv").write_text("half a table")  # what a kill mid-report may leave
    (run / "report.html").write_text("<html>cut")
    res = build_report(run, analysis=synth.fake_analyse, scope=NO_FIGURES)
    assert res.revision is None and res.certificate_json == run / "certificate.json"
    assert "half a table" not in (run / "tables" / "criteria.csv").read_text()
    assert res.report_html.read_text().startswith("<!DOCTYPE html>")
    assert not (run / "revisions").exists()


def test_report_is_self_contained(built) -> None:
    text = built.report_html.read_text()
    assert text.startswith("<!DOCTYPE html>")
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:|//)""", text)
    assert "@import" not in text and "url(" not in text
    assert text.count("data:image/png;base64,") == len(built.figures)
    # the verdict comes first, before any section
    assert text.index('class="verdict PASS"') < text.index("<section")
    assert "Trusted up to at least 23.5 Hz" in text


def test_sync_option_changes_the_primary_method(tmp_path: Path) -> None:
    run = synth.write_run(tmp_path / "run_linear")
    res = build_report(run, sync="linear", analysis=synth.fake_analyse, scope=NO_FIGURES)
    rows = {r["id"]: r for r in res.certificate["criteria"]}
    # the paper's method loses 5 % at 7.9 Hz: it cannot be trusted up to the required 15 Hz
    assert rows["min_usable_frequency_hz"]["status"] == "FAIL"
    assert rows["min_usable_frequency_hz"]["value"] == pytest.approx(np.sqrt(5.0 / 0.08), rel=1e-8)
    assert res.result == "FAIL"
    assert res.certificate["conditions"]["compared_sync_methods"] == []


def test_a_simulated_run_is_labelled_in_the_certificate_and_the_report(tmp_path: Path, built) -> None:
    run = synth.write_run(tmp_path / "run_sim", rig={**synth.RIG, "station": {"simulated": True}})
    res = build_report(run, analysis=synth.fake_analyse, scope=NO_FIGURES)
    assert res.certificate["simulated"] is True
    page = res.report_html.read_text()
    assert "id='simulated'" in page and "not a certificate of hardware" in page
    assert "(simulated rig)" in page.split("</h1>")[0]
    # the bench run of the module fixture is not labelled
    assert json.loads(built.certificate_json.read_text())["simulated"] is False
    assert "id='simulated'" not in built.report_html.read_text()


def test_failing_comparison_method_is_a_visible_note(tmp_path: Path) -> None:
    run = synth.write_run(tmp_path / "run_note")

    def analyse(run_dir, *, sync):
        if sync == "linear":
            raise RuntimeError("not implemented here")
        return synth.fake_analyse(run_dir, sync=sync)

    res = build_report(run, analysis=analyse, scope=NO_FIGURES)
    assert any("linear" in n and "not implemented here" in n for n in res.notes)
    assert "not implemented here" in res.report_html.read_text()


def test_aborted_run_without_sweep_is_incomplete(tmp_path: Path) -> None:
    run = synth.write_run(tmp_path / "run_abort", exit_status="abort")
    lines = [ln for ln in (run / "record.jsonl").read_text().splitlines() if '"stream": "sweep"' not in ln]
    (run / "record.jsonl").write_text("\n".join(lines) + "\n" + '{"type": "event", "stream": "arm", "se')
    with pytest.warns(UserWarning, match="truncated"):
        res = build_report(run, analysis=synth.fake_analyse)
    assert res.result == "INCOMPLETE"
    rows = {r["id"]: r for r in res.certificate["criteria"]}
    assert rows["min_usable_frequency_hz"]["status"] == "NOT EVALUATED"
    assert rows["position_max_mm"]["status"] == "PASS"
    assert "amplitude_error_vs_frequency" not in res.figures
    assert any("cut short" in n for n in res.notes)


def test_bad_run_folder_and_config_raise(tmp_path: Path) -> None:
    with pytest.raises(RunFolderError, match=r"record\.jsonl"):
        build_report(tmp_path, analysis=synth.fake_analyse)
    run = synth.write_run(tmp_path / "run_badcfg", rig={"criteria": {"max_error": 1}})
    with pytest.raises(CriteriaError, match="max_error"):
        build_report(run, analysis=synth.fake_analyse)


def test_command_line_entry_names_what_is_missing(tmp_path: Path, capsys) -> None:
    """The synthetic run folder has no observations: the real analysis refuses, the command says why."""
    from reports.__main__ import main

    run = synth.write_run(tmp_path / "run_cli")
    code = main([str(run), "--no-figures"])
    err = capsys.readouterr().err
    assert code == 3
    assert "sync 'trajectory'" in err and "observations" in err


def test_failing_primary_analysis_raises_a_report_error(tmp_path: Path) -> None:
    from reports.errors import AnalysisFailedError

    run = synth.write_run(tmp_path / "run_fail_primary")

    def analyse(run_dir, *, sync):
        raise FileNotFoundError("calibration.json missing: run `rig run calibrate` first")

    with pytest.raises(AnalysisFailedError, match=r"sync 'trajectory'.*calibration\.json missing"):
        build_report(run, analysis=analyse, scope=NO_FIGURES)


def test_report_built_before_the_stop_document_follows_the_criteria(tmp_path: Path) -> None:
    """The procedures build the report as the run's last step, before the runner writes `stop`."""
    run = synth.write_run(tmp_path / "run_inprogress")
    lines = (run / "record.jsonl").read_text().splitlines()
    (run / "record.jsonl").write_text("\n".join(ln for ln in lines if '"type": "stop"' not in ln) + "\n")
    res = build_report(run, analysis=synth.fake_analyse, scope=NO_FIGURES)
    assert res.result == "PASS"
    assert any("no stop document" in n for n in res.notes)


def test_timing_table_has_values_with_uncertainties(built) -> None:
    timing = pd.read_csv(built.tables["timing"]).set_index("camera")
    assert timing.loc["right", "offset_s"] == pytest.approx(0.0041)
    assert timing.loc["right", "u_offset_s"] == pytest.approx(2.0e-5)
    assert np.isnan(timing.loc["left", "u_offset_s"]) and np.isnan(timing.loc["right", "u_drift_ppm"])
    assert timing.loc["right", "drift_ppm"] == pytest.approx(3.0)


@pytest.mark.parametrize(
    ("targets", "title", "entries"),
    [
        (["arm", "frame_0", "frame_1"], "target", {"arm", "frame_0", "frame_1"}),
        (["arm", *(f"frame_{i}" for i in range(12))], "kind of target",
         {"arm (1 target)", "frame (12 targets)"}),
        ([f"t{i}x" for i in range(14)], "targets", {"all 14 targets"}),
    ],
)
def test_every_colour_of_the_error_figure_has_a_legend_entry(targets, title, entries) -> None:
    from reports.figures import MAX_DISTINCT_COLOURS, _legend_groups

    groups, legend_title = _legend_groups(pd.Series(targets))
    assert legend_title == title and set(groups) == entries
    assert groups.nunique() <= MAX_DISTINCT_COLOURS


class _StepContext:
    """The part of a procedure context the report step uses (a run folder and recorded steps)."""

    def __init__(self, run_dir: Path) -> None:
        from rig.run.procedure import Step

        self.run_dir, self.steps, self._step = run_dir, [], Step

    def progress(self, fraction, message) -> None:
        pass

    def checkpoint(self) -> None:
        pass  # no abort requested

    @contextlib.contextmanager
    def step(self, name: str):
        step = self._step(name=name, skipped=False)
        yield step
        self.steps.append((name, list(step.outputs)))


def test_the_report_step_issues_the_certificate_once(tmp_path: Path, monkeypatch) -> None:
    """A run resumed after its certificate was issued keeps it: the step reads it, never rebuilds it."""
    from procedures import _report
    from reports import build as build_module

    run = synth.write_run(tmp_path / "run_step")
    ctx = _StepContext(run)
    monkeypatch.setattr(build_module, "_default_analyse", lambda: synth.fake_analyse)
    first = _report.report_step(ctx, NO_FIGURES)
    issued = (run / "certificate.json").read_bytes()
    assert first["passed"] and ctx.steps == [("report", ["report.html", "certificate.json"])]

    def no_rebuild(*args, **kwargs):
        raise AssertionError("the issued certificate was rebuilt")

    monkeypatch.setattr(build_module, "build_report", no_rebuild)
    again = _report.report_step(ctx, NO_FIGURES)
    assert again == first and (run / "certificate.json").read_bytes() == issued
    assert not (run / "revisions").exists()


def test_an_abort_at_the_reports_checkpoint_stops_it_before_any_analysis(tmp_path: Path) -> None:
    """The run's report step passes its checkpoint: an abort requested during the report (a Ctrl-C) ends it
    before the next analysis — the report's CPU, minutes on a long run — not only before the certificate."""
    run = synth.write_run(tmp_path / "run_abort")
    analysed: list[str] = []

    def analyse(run_dir, *, sync):
        analysed.append(sync)
        return synth.fake_analyse(run_dir, sync=sync)

    class AbortedError(Exception):
        pass

    def abort_requested() -> None:
        raise AbortedError

    with pytest.raises(AbortedError):
        build_report(run, analysis=analyse, scope=Scope(comparison=("linear",), figures=False), in_run=True,
                     checkpoint=abort_requested)
    assert analysed == [] and not (run / "certificate.json").exists()
    calls: list[int] = []  # a checkpoint before each analysis and the certificate: the primary, linear, issue
    build_report(run, analysis=analyse, scope=Scope(comparison=("linear",), figures=False), in_run=True,
                 checkpoint=lambda: calls.append(len(analysed)))
    assert calls == [0, 1, 2] and (run / "certificate.json").is_file()
