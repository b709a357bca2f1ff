"""No import cycle among the project's modules (docs/code.md): every import a module makes when it is loaded, those
under ``if TYPE_CHECKING:`` too (a checker or an IDE loads them), read from the sources with :mod:`ast`, forms no
cycle. Imports inside functions are made when called, after every module has loaded: they are left out."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("quadsitl", "sitl", "autopilot", "groundstation", "benchmarks")


def modules(root: Path = ROOT, packages: tuple[str, ...] = PACKAGES) -> dict[str, Path]:
    """Every module of ``packages`` under ``root`` by its dotted name (a package by its own: ``sitl`` is
    ``sitl/__init__.py``)."""
    found = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def load_time_imports(tree: ast.Module) -> list[ast.Import | ast.ImportFrom]:
    """The import statements run when the module loads: at its top level, in its ``if``, ``try`` and ``with`` blocks
    and class bodies, not in a function's body."""
    found: list[ast.Import | ast.ImportFrom] = []

    def walk(nodes: list[ast.stmt]) -> None:
        for node in nodes:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                found.append(node)
            for field in ("body", "orelse", "finalbody", "handlers"):
                walk(getattr(node, field, None) or [])

    walk(tree.body)
    return found


def imported(name: str, path: Path, known: dict[str, Path]) -> set[str]:
    """The project's modules that loading module ``name`` (its file ``path``) loads directly: each imported module and
    the packages above it (``from a.b import c``: ``a``, ``a.b``, and ``a.b.c`` when that is a module)."""
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    targets: list[str] = []
    for node in load_time_imports(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            targets += [alias.name for alias in node.names]
            continue
        base = node.module or ""
        if node.level:  # relative: from the package, up level − 1
            base = ".".join(package[: len(package) - node.level + 1] + ([base] if base else []))
        targets += [f"{base}.{alias.name}" if f"{base}.{alias.name}" in known else base for alias in node.names]
    found = set()
    for target in targets:
        parts = target.split(".")
        found |= {".".join(parts[:i]) for i in range(1, len(parts) + 1)} & known.keys()
    return found - {name}


def import_graph(root: Path = ROOT, packages: tuple[str, ...] = PACKAGES) -> dict[str, set[str]]:
    """Each module → the project's modules it loads when it loads."""
    known = modules(root, packages)
    return {name: imported(name, path, known) for name, path in known.items()}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The graph's strongly connected components of more than one module (each a cycle or several), sorted
    (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            v, successors = work[-1]
            for w in successors:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    component = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        component.append(w)
                        if w == v:
                            break
                    if len(component) > 1:
                        found.append(sorted(component))
    return sorted(found)


def test_no_module_of_the_project_takes_part_in_an_import_cycle():
    graph = import_graph()
    assert {"sitl.process", "groundstation.gcs", "groundstation.sweep.run", "benchmarks.bench"} <= graph.keys()
    assert "sitl.lockstep" in graph["sitl.process"] and "sitl" in graph["sitl.process"]
    assert cycles(graph) == []


@pytest.mark.parametrize(
    ("sources", "want"),
    [
        ({"a/__init__.py": "", "a/x.py": "from a import y\n", "a/y.py": "import a.x\n"}, [["a.x", "a.y"]]),
        # under TYPE_CHECKING: loaded by a type checker, a cycle all the same
        ({"a/__init__.py": "", "a/x.py": "from a.y import f\n",
          "a/y.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from a.x import g\n"}, [["a.x", "a.y"]]),
        # relative imports, and a package whose __init__ loads a module that loads it
        ({"a/__init__.py": "from .x import f\n", "a/x.py": "from . import y\n", "a/y.py": "import a\n"},
         [["a", "a.x", "a.y"]]),
        # an import inside a function runs when called: no cycle
        ({"a/__init__.py": "", "a/x.py": "import a.y\n", "a/y.py": "def f():\n    import a.x\n"}, []),
        ({"a/__init__.py": "", "a/x.py": "import a.y\n", "a/y.py": "import json\n"}, []),
    ],
)  # fmt: skip
def test_the_check_finds_a_cycle_where_there_is_one(tmp_path, sources, want):
    for name, text in sources.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    assert cycles(import_graph(tmp_path, ("a",))) == want
