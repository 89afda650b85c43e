"""The import structure of ``softsbi.workflows``: no module imports itself through others, and an import inside a
function says why it is not at the module's top."""
from __future__ import annotations

import ast
from pathlib import Path

import grimp
import pytest

import softsbi.workflows

WORKFLOWS = Path(softsbi.workflows.__file__).parent


def import_cycles(graph: grimp.ImportGraph, package: str) -> list[list[str]]:
    """The strongly connected components of more than one module among ``package``'s modules (Tarjan)."""
    mods = {m for m in graph.modules if m == package or m.startswith(package + ".")}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.find_modules_directly_imported_by(v) & mods):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for m in sorted(mods):
        if m not in index:
            visit(m)
    return out


def test_import_cycles_finds_a_cycle():
    graph = grimp.ImportGraph()
    for m in ("p", "p.a", "p.b", "p.c"):
        graph.add_module(m)
    graph.add_import(importer="p.a", imported="p.b")
    graph.add_import(importer="p.b", imported="p.a")
    graph.add_import(importer="p.c", imported="p.a")
    assert import_cycles(graph, "p") == [["p.a", "p.b"]]


def test_workflows_have_no_import_cycle():
    graph = grimp.build_graph("softsbi", cache_dir=None)
    assert import_cycles(graph, "softsbi.workflows") == []


def local_imports(path: Path) -> list[tuple[int, str]]:
    """``(line, text)`` of each import statement inside a function of ``path``, with the line above it."""
    text = path.read_text()
    lines = text.splitlines()
    found = {}
    for fn in ast.walk(ast.parse(text)):
        if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for node in ast.walk(fn):
                if isinstance(node, (ast.Import, ast.ImportFrom)):
                    found[node.lineno] = "\n".join(lines[node.lineno - 2: node.lineno])
    return sorted(found.items())


def test_function_local_imports_say_why():
    unexplained = [f"{p.name}:{line}" for p in sorted(WORKFLOWS.glob("*.py")) for line, text in local_imports(p)
                   if "#" not in text]
    assert unexplained == []


def test_every_workflows_module_is_in_a_room_of_the_import_contract():
    """The rooms contract of pyproject.toml orders only the modules it names: a module left out of it (the ArviZ
    export, datatree, was) may import any room, above it or below, without ``lint-imports`` failing."""
    tomllib = pytest.importorskip("tomllib")
    config = tomllib.loads((WORKFLOWS.parents[1] / "pyproject.toml").read_text())
    rooms = next(c for c in config["tool"]["importlinter"]["contracts"] if c.get("containers") == ["softsbi.workflows"])
    named = {m.strip() for layer in rooms["layers"] for m in layer.split(":")}
    modules = {p.stem for p in WORKFLOWS.glob("*.py") if p.stem != "__init__"} | {
        p.parent.name for p in WORKFLOWS.glob("*/__init__.py")}
    assert sorted(modules - named) == [] and "datatree" in named
