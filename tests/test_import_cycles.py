"""No import cycle among the package's modules: every import arrow points one way.

The graph is read from the source with :mod:`ast` (nothing imported): an edge ``a -> b`` for
every import of package module ``b`` in module ``a``, at the top level or inside a function
(a lazy import is still an arrow); ``from p import name`` is an edge to ``p.name`` when that is
a module, else to ``p``. Imports under ``if TYPE_CHECKING:`` are annotations, never run, and
are left out. A package's ``__init__`` is the package's own module: a submodule that imports
its package's ``__init__`` while the ``__init__`` imports it is a cycle.
"""

from __future__ import annotations

import ast
from pathlib import Path

from tests.test_private_imports import ROOT, is_module, module_name, package_of, resolve


def type_checking_nodes(tree: ast.AST) -> set[int]:
    """The ids of every node under an ``if TYPE_CHECKING:`` block."""
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            skip.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    return skip


def imports_of(path: Path, root: Path = ROOT) -> set[str]:
    """The package modules one file imports at run time (module docstring)."""
    module = module_name(path, root)
    package = package_of(path, module)
    tree = ast.parse(path.read_text(), filename=str(path))
    skip = type_checking_nodes(tree)
    out: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.startswith("mcpilco."))
        elif isinstance(node, ast.ImportFrom):
            source = resolve(node, package)
            if source.startswith("mcpilco"):
                for alias in node.names:
                    target = f"{source}.{alias.name}"
                    out.add(target if is_module(target, root) else source)
    out.discard(module)
    return out


def import_graph(root: Path = ROOT, folders: tuple[str, ...] | None = None) -> dict[str, set[str]]:
    """Module -> the package modules it imports, over every ``.py`` file under ``folders``."""
    from tests.test_private_imports import FOLDERS

    files = sorted(p for f in folders or FOLDERS for p in (root / f).rglob("*.py"))
    return {module_name(p, root): imports_of(p, root) for p in files}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm,
    iterative), each sorted: every module of one lies on an import cycle with the others."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, it = work[-1]
            w = next((w for w in it if w in graph), None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    found.append(sorted(comp))
    return found


def test_no_import_cycle_among_the_package_modules() -> None:
    graph = import_graph()
    assert "mcpilco.models.diagnosis.model" in graph  # the tree was read
    found = cycles(graph)
    assert not found, "import cycles (make the arrows point one way):\n" + "\n".join(
        " <-> ".join(c) for c in found
    )


def test_the_checker_sees_top_level_and_lazy_cycles_and_skips_type_checking(tmp_path) -> None:
    """On a small tree of its own: a top-level cycle, a cycle closed by a function-level
    import and a package ``__init__`` cycle are found; an arrow back under TYPE_CHECKING and
    a one-way chain are not."""
    pkg = tmp_path / "models" / "diag"
    pkg.mkdir(parents=True)
    (tmp_path / "models" / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("from mcpilco.models.diag.work import run\n")
    (pkg / "work.py").write_text("def run():\n    from mcpilco.models.diag import thing\n")
    (pkg / "a.py").write_text("from mcpilco.models.diag.b import f\n")
    (pkg / "b.py").write_text("def f():\n    from mcpilco.models.diag import a\n")
    (pkg / "c.py").write_text("from .d import g\n")
    (pkg / "d.py").write_text("from .c import h\n")
    (pkg / "e.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .f import F\n"
    )
    (pkg / "f.py").write_text("from mcpilco.models.diag.e import E\n")
    (pkg / "g.py").write_text("from mcpilco.models.diag.f import F\n")
    got = cycles(import_graph(tmp_path, ("models",)))
    assert sorted(got) == [
        ["mcpilco.models.diag", "mcpilco.models.diag.work"],
        ["mcpilco.models.diag.a", "mcpilco.models.diag.b"],
        ["mcpilco.models.diag.c", "mcpilco.models.diag.d"],
    ]
