"""The import layers of DESIGN.md, checked on the source (imports point down the list only)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# package prefix -> top-level modules it must never import
FORBIDDEN: dict[str, tuple[str, ...]] = {
    "rig/stereo": ("drivers", "procedures", "reports", "rig.runner", "rig.station", "rig.record",
                   "rig.config", "rig.cli", "rig.analysis", "rig.clock"),
    "drivers": ("rig", "procedures", "reports"),
    "reports": ("procedures", "rig.cli", "rig.runner", "rig.station"),
    "procedures": ("rig.cli",),
    "rig": ("procedures", "reports"),  # orchestration is below procedures and reports (cli excepted)
}
EXEMPT = {"rig/cli.py"}
PROJECT_PACKAGES = {"rig", "drivers", "procedures", "reports"}  # the command layer sits on top of everything


def _imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def test_stereo_core_imports_nothing_of_the_project_but_itself() -> None:
    """rig.stereo is the math layer: pure functions on arrays, no import of any other project module."""
    found = []
    for path in sorted((ROOT / "rig" / "stereo").rglob("*.py")):
        for name in _imported_modules(path):
            top = name.split(".")[0]
            if top in PROJECT_PACKAGES and not (name == "rig.stereo" or name.startswith("rig.stereo.")):
                found.append(f"{path.relative_to(ROOT).as_posix()} imports {name}")
    assert found == []


def _violations(prefix: str, forbidden: tuple[str, ...]) -> list[str]:
    found = []
    for path in sorted((ROOT / prefix).rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        if rel in EXEMPT:
            continue
        for name in _imported_modules(path):
            if any(name == f or name.startswith(f + ".") for f in forbidden):
                found.append(f"{rel} imports {name}")
    return found


@pytest.mark.parametrize("prefix", sorted(FORBIDDEN))
def test_layers_point_down_only(prefix: str) -> None:
    assert _violations(prefix, FORBIDDEN[prefix]) == []


def test_checker_sees_a_violation(tmp_path: Path) -> None:
    """The checker itself must fail on an upward import, or the test above proves nothing."""
    bad = tmp_path / "bad.py"
    bad.write_text("import drivers.sim.world\nfrom reports import html\n")
    assert {"drivers.sim.world", "reports"} <= _imported_modules(bad)
