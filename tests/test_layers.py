"""The import layers of DESIGN.md and docs/architecture.md, checked on the source: imports point down the
layers only, and no module imports itself back through any chain (function-level imports included)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROJECT_PACKAGES = ("rig", "drivers", "procedures", "reports")

# The layers from the bottom up. A package may import those below it (and itself), never those above.
# rig.stereo (math) and drivers (devices and the twin) are independent foundations: neither imports the other.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("rig.stereo",),
    ("drivers",),
    ("rig.record", "rig.config"),
    ("rig.analysis",),
    ("rig.run", "rig.deploy"),
    ("rig.dashboard",),
    ("reports",),
    ("procedures",),
    ("rig.cli", "rig.cli_measure", "rig.cli_logging", "rig.preview", "rig.demo",
     "rig.warm_kernels"),
)
# Packages of one layer that must not import each other either.
SIBLINGS_APART = {("rig.record", "rig.config"), ("rig.run", "rig.deploy")}
# rig.stereo and drivers share no code in either direction (the twin must not share the measurement's
# camera model, or the tests would prove nothing); the record and config import no device code.
EXTRA_FORBIDDEN: dict[str, tuple[str, ...]] = {
    "rig.stereo": ("drivers",),
    "rig.record": ("drivers",),
    "rig.analysis": ("drivers",),
    "reports": ("rig.run", "rig.dashboard", "drivers"),  # reports are pure functions of a folder
}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _project_modules() -> dict[str, Path]:
    found: dict[str, Path] = {}
    for top in PROJECT_PACKAGES:
        for path in sorted((ROOT / top).rglob("*.py")):
            found[_module_name(path)] = path
    return found


MODULES = _project_modules()


def _imported_modules(path: Path, package: str = "") -> set[str]:
    """Every project module ``path`` imports, at any depth in the file; ``from p import m`` counts as an
    import of the module ``p.m`` when ``p.m`` is a module, else of ``p``."""
    tree = ast.parse(path.read_text(), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            for alias in node.names:
                full = f"{base}.{alias.name}"
                names.add(full if full in MODULES else base)
    return {n for n in names if n.split(".")[0] in PROJECT_PACKAGES}


def _layer_of(module: str) -> int | None:
    for index, layer in enumerate(LAYERS):
        if any(module == p or module.startswith(p + ".") for p in layer):
            return index
    return None


def _package_of(module: str) -> str | None:
    for layer in LAYERS:
        for p in layer:
            if module == p or module.startswith(p + "."):
                return p
    return None


def test_every_module_has_a_layer() -> None:
    assert [m for m in MODULES if m not in ("rig", "rig.__main__") and _layer_of(m) is None] == []


def _upward_imports() -> list[str]:
    found = []
    for module, path in MODULES.items():
        own, own_package = _layer_of(module), _package_of(module)
        if own is None:
            continue
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        for name in _imported_modules(path, package):
            target, target_package = _layer_of(name), _package_of(name)
            if target is None or target_package == own_package:
                continue
            if target > own or (own_package, target_package) in SIBLINGS_APART \
                    or (target_package, own_package) in SIBLINGS_APART \
                    or any(name == f or name.startswith(f + ".")
                           for f in EXTRA_FORBIDDEN.get(own_package or "", ())):
                found.append(f"{module} imports {name}")
    return found


def test_imports_point_down_the_layers_only() -> None:
    assert _upward_imports() == []


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan), each a cycle of imports."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in graph.get(node, ()):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                top = stack.pop()
                on_stack.discard(top)
                component.append(top)
                if top == node:
                    break
            if len(component) > 1:
                components.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return components


def _import_graph() -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {}
    for module, path in MODULES.items():
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        graph[module] = {n for n in _imported_modules(path, package) if n in MODULES and n != module}
    return graph


def test_no_import_cycles_anywhere() -> None:
    assert _cycles(_import_graph()) == []


def test_checker_sees_a_violation_and_a_cycle(tmp_path: Path) -> None:
    """The checkers must fail on an upward import and on a cycle, or the tests above prove nothing."""
    bad = tmp_path / "bad.py"
    bad.write_text("import drivers.sim.world\nfrom reports import html\n")
    assert {"drivers.sim.world", "reports.html"} <= _imported_modules(bad)
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _layer_of("rig.run.runner") is not None and _layer_of("reports.html") is not None
    assert _layer_of("rig.run.runner") < _layer_of("reports.html")  # type: ignore[operator]
