"""``rig list`` reads each procedure's light declaration (procedures/params/): the same procedures, with the
same ``NAME``, ``DESCRIPTION`` and ``Parameters`` objects, as importing the procedure modules themselves."""

from __future__ import annotations

import dataclasses
import textwrap
from pathlib import Path

import pytest

import procedures
from rig.cli import discover_procedures, main
from rig.run.procedure import parameter_table


def test_the_declarations_are_the_procedures_own() -> None:
    light, full = discover_procedures(declarations=True), discover_procedures()
    assert list(light) == list(full) == ["accuracy", "calibrate", "certify", "plate", "rotation", "sweep",
                                         "sync"]
    for name, module in full.items():
        declaration = light[name]
        assert declaration.__name__ == f"procedures.params.{module.__name__.rpartition('.')[2]}"
        assert declaration.Parameters is module.Parameters
        assert (declaration.NAME, declaration.DESCRIPTION) == (module.NAME, module.DESCRIPTION)


def test_rig_list_prints_every_parameter(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for name, module in discover_procedures().items():
        assert f"{name}: {module.DESCRIPTION}" in out
        for row in parameter_table(module):
            assert f"    {row['name']} = {row['default']!r}" in out
    assert "    distortion = 'k1' (one of 'none', 'k1', 'k1k2', 'full')" in out


def test_a_procedure_without_a_declaration_is_listed_from_its_module(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    (tmp_path / "spin_only.py").write_text(textwrap.dedent("""
        from dataclasses import dataclass, field
        from rig.run.procedure import param
        NAME = "spin-only"
        @dataclass(frozen=True)
        class Parameters:
            hz: float = field(default=2.0, metadata=param(lo=0.1, hi=5.0))
        def run(ctx, params):
            return None
    """))
    monkeypatch.setattr(procedures, "__path__", [*procedures.__path__, str(tmp_path)])
    listed = discover_procedures(declarations=True)
    assert listed["spin-only"].__name__ == "procedures.spin_only"
    assert [f.name for f in dataclasses.fields(listed["spin-only"].Parameters)] == ["hz"]
