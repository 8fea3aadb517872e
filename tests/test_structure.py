"""The structure has no import circle (issue 36 item 5): the import graph of kexp's modules, built from their source
(every ``from .x import``, ``from ..x import``, ``import kexp.x``, function-level imports included), is a DAG; the
experiment command (kexp.app) and the results tooling (kexp.results) do not import each other."""
from __future__ import annotations

import ast
from pathlib import Path

import kexp

ROOT = Path(kexp.__file__).parent


def _module(path: Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _resolve(name: str, modules: set[str]) -> str | None:
    """The kexp module ``name`` refers to (a package's attribute import resolves to the package)."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def graph(root: Path = ROOT) -> dict[str, set[str]]:
    """{module: the kexp modules it imports}, from the source of every ``*.py`` under ``root``."""
    files = {_module(p): p for p in root.rglob("*.py")}
    modules = set(files)
    edges: dict[str, set[str]] = {m: set() for m in modules}
    for mod, path in files.items():
        package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names if a.name.split(".")[0] == "kexp"]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")
                    base = base[:len(base) - (node.level - 1)]
                    stem = ".".join(base + ([node.module] if node.module else []))
                elif (node.module or "").split(".")[0] == "kexp":
                    stem = node.module
                else:
                    continue
                # `from . import reproduce` imports a module; `from .x import name` imports from module x
                targets = [f"{stem}.{a.name}" if f"{stem}.{a.name}" in modules else stem for a in node.names]
            for t in targets:
                r = _resolve(t, modules)
                if r and r != mod:
                    edges[mod].add(r)
    return edges


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted: the import circles."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges[v]):
            if w not in index:
                visit(w)
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
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def test_the_graph_sees_lazy_and_relative_imports():
    """The graph is real: results.cli's function-level imports and relative imports are edges (a graph that saw
    nothing would have no cycle either)."""
    g = graph()
    assert {"kexp.results.table", "kexp.results.csvfiles", "kexp.results.reproduce", "kexp.results.robustness",
            "kexp.results.plants_view"} <= g["kexp.results.cli"]
    assert "kexp.results.aggregate" in g["kexp.results.csvfiles"]
    assert "kexp.errors" in g["kexp.results.reproduce"]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


# circles known and left (not in the app/results rooms), each with its reason; a new circle fails the test, and so
# does an allowed one that is gone (delete its line)
ALLOWED = {
    ("kexp.recording.mcap_read", "kexp.recording.reader"):
        "mcap_read raises reader's LogError from a function-level import (LogError belongs in mcap_read)",
}


def test_kexp_has_no_import_circle():
    assert {tuple(c) for c in cycles(graph())} == set(ALLOWED)


def test_the_experiment_and_the_results_rooms_do_not_import_each_other():
    """kexp.app (the experiment command: it writes run folders) imports nothing from kexp.results (which reads them
    back), and kexp.results nothing from kexp.app: the run folder's files are their only contract."""
    g = graph()
    crossing = sorted((m, t) for m, ts in g.items() for t in ts
                      if (m.startswith("kexp.app") and t.startswith("kexp.results"))
                      or (m.startswith("kexp.results") and t.startswith("kexp.app")))
    assert crossing == []


def test_the_controllers_do_not_import_the_experiment_command():
    """kexp.control (the controllers, the compile cache) sits below kexp.app: the cache folder they share comes from
    kexp.cachedir, not from the app (a package-level circle app -> control -> app before)."""
    g = graph()
    up = sorted((m, t) for m, ts in g.items() for t in ts if m.startswith("kexp.control") and t.startswith("kexp.app"))
    assert up == []
    assert "kexp.cachedir" in g["kexp.control.jit_cache"] and "kexp.cachedir" in g["kexp.app.cache"]


def test_results_cli_is_the_only_module_that_imports_the_tables():
    """Inside kexp.results the dispatch is one way: only cli imports table, robustness, plants_view and reproduce."""
    g = graph()
    leaves = {"kexp.results.table", "kexp.results.robustness", "kexp.results.plants_view", "kexp.results.reproduce"}
    importers = sorted(m for m, ts in g.items() if m.startswith("kexp.results") and ts & leaves)
    assert importers == ["kexp.results.cli"]


def test_every_module_of_the_two_rooms_says_what_it_holds():
    """Each module of kexp.app and kexp.results (their __init__ included) starts with a docstring; the packages'
    say which room they are."""
    missing = [str(p.relative_to(ROOT)) for room in ("app", "results") for p in sorted((ROOT / room).glob("*.py"))
               if not (ast.get_docstring(ast.parse(p.read_text(encoding="utf-8"))) or "").strip()]
    assert missing == []
    assert ast.get_docstring(ast.parse((ROOT / "app" / "__init__.py").read_text())).startswith(
        "The experiment room: the ``kexp`` command")
    assert ast.get_docstring(ast.parse((ROOT / "results" / "__init__.py").read_text())).startswith(
        "The results room")
