"""The package's internal import graph has no cycle (issue 11: data/generate ↔ data/ray_backend was one).

Every module of every package pyproject.toml ships is imported (each must import on its own) and
its source parsed; each import statement anywhere in it — at module level or inside a function,
since a lazy import ties two modules together just the same — is an edge to the most specific
module of the package it names. The cycle finder itself is checked on a package built with a lazy
cycle like the old one.
"""

from __future__ import annotations

import ast
import importlib
import pkgutil
import sys
import textwrap
from pathlib import Path

import tomllib

ROOT = Path(__file__).resolve().parents[1]


def modules_of(packages: list[str]) -> dict[str, Path]:
    """{module name: source file} of ``packages`` and their direct modules, each imported."""
    out = {}
    for name in packages:
        package = importlib.import_module(name)
        out[name] = Path(package.__file__)
        for info in pkgutil.iter_modules(package.__path__, name + "."):
            if not info.ispkg:
                out[info.name] = Path(importlib.import_module(info.name).__file__)
    return out


def import_graph(modules: dict[str, Path]) -> dict[str, set[str]]:
    """{module: the modules of ``modules`` it imports}."""
    graph = {}
    for name, path in modules.items():
        here = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        edges = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    base = ".".join(here[: len(here) - node.level + 1] + ([base] if base else []))
                # ``from pkg import name``: the module pkg.name if there is one, else pkg itself
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
            else:
                continue
            for target in targets:
                while target and target not in modules:
                    target = target.rpartition(".")[0]  # a name inside a module: that module
                if target and target != name:
                    edges.add(target)
        graph[name] = edges
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def shipped_packages() -> list[str]:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]


def test_the_package_import_graph_has_no_cycle():
    modules = modules_of(shipped_packages())
    assert {
        "ebr_mitsuba.data.generate",
        "ebr_mitsuba.data.ray_backend",
        "ebr_mitsuba.data.workers",
        "ebr_mitsuba.plugins",
        "ebr_mitsuba.train.trainer",
    } <= modules.keys()
    graph = import_graph(modules)
    assert "ebr_mitsuba.data.workers" in graph["ebr_mitsuba.data.generate"]
    assert not [m for m in graph["ebr_mitsuba.data.ray_backend"] if m.startswith("ebr_mitsuba.data")]
    found = cycles(graph)
    edges = [f"{a} -> {b}" for c in found for a in c for b in sorted(graph[a]) if b in c]
    assert found == [], f"import cycles (lazy imports count): {edges}"


def test_a_lazy_import_cycle_is_found(tmp_path, monkeypatch):
    package = tmp_path / "cyclepkg"
    (package / "sub").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "sub" / "__init__.py").write_text("")
    (package / "sub" / "gen.py").write_text("from . import backend\nVALUE = 1\n")
    (package / "sub" / "backend.py").write_text(
        textwrap.dedent("""
        def run():
            from .gen import VALUE  # the lazy half of the cycle
            return VALUE
    """)
    )
    (package / "leaf.py").write_text("import cyclepkg.sub.gen\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    try:
        graph = import_graph(modules_of(["cyclepkg", "cyclepkg.sub"]))
        assert graph["cyclepkg.leaf"] == {"cyclepkg.sub.gen"}
        assert cycles(graph) == [["cyclepkg.sub.backend", "cyclepkg.sub.gen"]]
        (package / "sub" / "backend.py").write_text("def run():\n    return 1\n")
        assert cycles(import_graph(modules_of(["cyclepkg", "cyclepkg.sub"]))) == []
    finally:
        for name in [n for n in sys.modules if n.startswith("cyclepkg")]:
            del sys.modules[name]
