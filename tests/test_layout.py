"""The package's layers: every import points down (or within its own layer), no cycles.

Layers, lowest first, each a subpackage (or a module) of ``qpatrol``; data flows one way,
config -> map -> world + strategies -> measures and records -> CSV -> plots, and each
layer imports only layers below it (README, "Layout"). Imports made only for type hints
(under ``TYPE_CHECKING``) are not counted; imports inside functions are.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "qpatrol"

#: Layer of each top-level name under qpatrol, lowest first.
LAYERS = {
    "__init__": 0,
    "util": 0,
    "config": 1,
    "maps": 2,
    "world": 3,
    "measures": 4,
    "strategies": 5,
    "engines": 6,
    "run": 7,
    "study": 8,
    "envs": 8,
    "cli": 9,
    "learners": 9,
}


def modules() -> dict[str, Path]:
    """Dotted module name -> file, for every module of the package."""
    out = {}
    for f in PACKAGE.rglob("*.py"):
        parts = list(f.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = f
    return out


def imports(name: str, path: Path, mods: dict[str, Path]) -> set[str]:
    """The package's modules that module ``name`` imports at run time."""
    found: set[str] = set()
    is_pkg = path.name == "__init__.py"

    def target(dotted: str) -> str | None:
        while dotted and dotted not in mods:
            dotted = dotted.rpartition(".")[0]
        return dotted or None

    def visit(node: ast.AST, type_only: bool) -> None:
        for child in ast.iter_child_nodes(node):
            t = type_only or (
                isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test)
            )
            if isinstance(child, ast.Import) and not t:
                found.update(filter(None, (target(a.name) for a in child.names)))
            elif isinstance(child, ast.ImportFrom) and not t:
                base = child.module or ""
                if child.level:
                    here = name.split(".") if is_pkg else name.split(".")[:-1]
                    here = here[: len(here) - child.level + 1]
                    base = ".".join(here + ([base] if base else []))
                for a in child.names:
                    sub = f"{base}.{a.name}"
                    # importing a submodule needs that module, not its package's names
                    found.add(sub if sub in mods else target(base) or "")
            visit(child, t)

    visit(ast.parse(path.read_text(encoding="utf-8")), False)
    found.discard("")
    found.discard(name)
    return {m for m in found if m.split(".")[0] == "qpatrol"}


def layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


MODS = modules()
GRAPH = {m: imports(m, f, MODS) for m, f in MODS.items()}


def test_every_module_has_a_layer():
    assert {layer(m) for m in MODS} <= set(LAYERS), sorted({layer(m) for m in MODS} - set(LAYERS))


@pytest.mark.parametrize("module", sorted(MODS))
def test_imports_point_down(module):
    """A module imports its own layer or lower ones, never a layer above or beside it."""
    mine = layer(module)
    wrong = [
        m
        for m in sorted(GRAPH[module])
        if layer(m) != mine and LAYERS[layer(m)] >= LAYERS[mine] and layer(m) != "__init__"
    ]
    assert not wrong, f"{module} ({mine}) imports {wrong}"


def test_no_import_cycles():
    """No module imports itself through others (eager or inside functions)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    cycles: list[list[str]] = []

    def strong(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in GRAPH[v]:
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in sorted(GRAPH):
        if v not in index:
            strong(v)
    assert not cycles, cycles


def test_the_check_sees_an_upward_import(tmp_path):
    """The checks are not vacuous: a world module that imports the run layer inside a
    function is seen, and one that does so only for type hints is not."""
    f = tmp_path / "fake.py"
    f.write_text(
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n    from qpatrol.study import sweep\n"
        "def g():\n    from qpatrol.run import simulate\n"
        "from qpatrol.world import battery\n"
    )
    found = imports("qpatrol.world.fake", f, MODS)
    assert found == {"qpatrol.run", "qpatrol.world.battery"}
