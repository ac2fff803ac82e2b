"""``[report]`` of rig.toml (what a report computes beyond the certificate): validated like every field, and
honoured by the report — figures = false draws no PNG and says so; comparison = [] runs no second analysis
and leaves every criterion of the certificate as it is with the comparison."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
import reports_synth as synth

from reports.build import build_report
from rig.config.rig_config import ConfigError, default_config, override


@pytest.mark.parametrize(("value", "field", "says"), [
    (["bogus"], "report.comparison[0]", "'trajectory', 'bandlimited', 'cubic', 'linear'"),
    (["linear", "linear"], "report.comparison[1]", "listed twice"),
    ("linear", "report.comparison", "an array"),
])
def test_a_bad_comparison_names_the_field_and_the_allowed_values(value: Any, field: str, says: str) -> None:
    with pytest.raises(ConfigError) as exc:
        override(default_config(), "report.comparison", value)
    assert exc.value.field == field and says in str(exc.value)


def test_rig_check_refuses_a_bad_report_table_with_exit_4(tmp_path: Path, capsys) -> None:
    from certify_support import write_config

    from rig.cli import main

    path = write_config(tmp_path)
    path.write_text(re.sub(r"^figures = .*$", 'figures = "no"', path.read_text(), flags=re.M))
    assert main(["check", "--config", str(path), "--no-devices"]) == 4
    assert "report.figures: 'no' has the wrong type; allowed: true or false" in capsys.readouterr().err


def _run(tmp_path: Path, name: str, **report: Any) -> Path:
    return synth.write_run(tmp_path / name, rig={**synth.RIG, "report": report} if report else None)


def test_figures_false_writes_no_png_and_says_so(tmp_path: Path) -> None:
    res = build_report(_run(tmp_path, "run_nofig", figures=False), analysis=synth.fake_analyse)
    assert res.figures == {} and not list(res.run_dir.rglob("*.png"))
    page = res.report_html.read_text(encoding="utf-8")
    assert "figures not drawn: [report] figures = false" in page and "data:image/png" not in page
    assert "figures not drawn: [report] figures = false" in res.certificate["conditions"]["notes"]


def test_no_figures_overrides_a_run_that_draws_them_and_says_why(tmp_path: Path) -> None:
    res = build_report(_run(tmp_path, "run_cli_nofig", figures=True), analysis=synth.fake_analyse,
                       no_figures_why="--no-figures")
    assert res.figures == {} and not list(res.run_dir.rglob("*.png"))
    assert "figures not drawn: --no-figures" in res.certificate["conditions"]["notes"]


def test_no_comparison_leaves_the_criteria_as_they_are_with_it(tmp_path: Path) -> None:
    analyse = synth.fake_analyse  # its linear tracks differ from its trajectory tracks (synth.SWEEP_COEFFS)
    full = build_report(_run(tmp_path, "run_full", figures=False), analysis=analyse)
    alone = build_report(_run(tmp_path, "run_alone", comparison=[], figures=False), analysis=analyse)
    assert full.certificate["conditions"]["compared_sync_methods"] == ["linear"]  # the comparison ran there
    assert alone.certificate["conditions"]["compared_sync_methods"] == []
    assert alone.certificate["criteria"] == full.certificate["criteria"] and alone.result == full.result
    for table in ("quadratic_fit", "sweep_bins", "sweep_means"):
        methods = set(pd.read_csv(alone.tables[table])["sync_method"])
        assert methods == {"trajectory"}, table
        assert set(pd.read_csv(full.tables[table])["sync_method"]) == {"trajectory", "linear"}, table
    assert set(alone.certificate["usable_frequency"]) == {"trajectory"}
    assert ("no sync method analysed for comparison: [report] comparison = []"
            in alone.certificate["conditions"]["notes"])

