"""rig.stereo has no import cycle: every import, at module level or inside a function, is an edge, and the
timing estimators take their shared types from timing_model, not from the timing module that dispatches to
them."""

from __future__ import annotations

import ast
from pathlib import Path

import rig.stereo

PACKAGE = Path(rig.stereo.__file__).parent


def _edges() -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {}
    submodules = {path.stem for path in PACKAGE.glob("*.py")}
    for path in PACKAGE.glob("*.py"):
        name = f"rig.stereo.{path.stem}" if path.stem != "__init__" else "rig.stereo"
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                module = node.module or ""
                if node.level:  # relative: from . import x, from .x import y
                    module = f"rig.stereo.{module}".rstrip(".")
                if module.startswith("rig.stereo"):
                    deps.add(module)
                if module == "rig.stereo":  # from rig.stereo import timing_model: an edge to the submodule
                    deps |= {f"rig.stereo.{a.name}" for a in node.names if a.name in submodules}
            elif isinstance(node, ast.Import):
                deps |= {a.name for a in node.names if a.name.startswith("rig.stereo")}
        graph[name] = deps - {name}
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}  # 1 = on the path, 2 = done

    def visit(node: str, path: list[str]) -> list[str] | None:
        state[node] = 1
        for dep in sorted(graph.get(node, ())):
            if dep == "rig.stereo":  # the package's __init__ re-exports; modules never import it back
                continue
            if state.get(dep) == 1:
                return [*path, node, dep]
            if dep not in state and (found := visit(dep, [*path, node])):
                return found
        state[node] = 2
        return None

    for start in sorted(graph):
        if start not in state and (found := visit(start, [])):
            return found
    return None


def test_rig_stereo_modules_import_each_other_without_a_cycle() -> None:
    graph = _edges()
    for estimator in ("rig.stereo.timing_joint", "rig.stereo.timing_rotor"):
        assert "rig.stereo.timing_model" in graph[estimator]
        assert "rig.stereo.timing" not in graph[estimator]
    # the package __init__ imports every module, so a module importing the package back closes a cycle
    back = sorted(module for module, deps in graph.items() if module != "rig.stereo" and "rig.stereo" in deps)
    assert back == []
    assert _cycle(graph) is None, " → ".join(_cycle(graph) or [])


def test_the_cycle_finder_finds_a_cycle() -> None:
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None
