"""Import hygiene of the package: no module reaches into another module's private names, and
the fast rollouts (``agents/mc_pilco/fast/``) sit beside the algorithm, not inside it.

Rules checked on every ``.py`` file of ``envs/``, ``agents/``, ``models/``, ``experiments/``
and ``scripts/`` (parsed with :mod:`ast`, nothing imported):

* ``from mcpilco.a.b import _x`` (or a relative import) of a private name of another module
  is refused; so is ``mod._x`` where ``mod`` names another package module bound by an
  import (``import mcpilco.a.b as mod``, ``from mcpilco.a import b``).
* A private module (``_base.py``, a leading underscore in its name) may be imported only by
  the modules of its own package (``models/kernels/_base.py`` by ``models/kernels/*``).
* Dunder names (``__version__``) are public.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("envs", "agents", "models", "experiments", "scripts")  # the package's top folders
FAST = "mcpilco.agents.mc_pilco.fast"  # the fast rollouts' package
PARTS = (  # the differentiable parts of a rollout step: they never import the fast rollouts
    "mcpilco.agents.mc_pilco.policy",
    "mcpilco.agents.mc_pilco.features",
    "mcpilco.agents.mc_pilco.dynamics",
    "mcpilco.agents.mc_pilco.cost",
    "mcpilco.agents.mc_pilco.loss",
    "mcpilco.models.gp.fused",
)


def is_private(name: str) -> bool:
    """A leading underscore, not a dunder."""
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def module_name(path: Path, root: Path = ROOT) -> str:
    """``agents/mc_pilco/loss.py`` -> ``mcpilco.agents.mc_pilco.loss`` (a package's
    ``__init__.py`` -> the package)."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(["mcpilco", *parts])


def package_of(path: Path, module: str) -> str:
    """The package a module lives in (a package's ``__init__`` is in itself)."""
    return module if path.name == "__init__.py" else module.rpartition(".")[0]


def is_module(dotted: str, root: Path = ROOT) -> bool:
    """Whether ``dotted`` (``mcpilco.x.y``) is a module or package of the tree."""
    parts = dotted.split(".")[1:]
    if not parts:
        return True
    base = root.joinpath(*parts)
    return base.with_suffix(".py").is_file() or (base / "__init__.py").is_file()


def resolve(node: ast.ImportFrom, package: str) -> str:
    """The absolute module of ``from <node.module> import ...`` (relative ones resolved)."""
    if not node.level:
        return node.module or ""
    base = package.split(".")
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def private_module_owner(dotted: str) -> str | None:
    """The package owning the first private module on ``dotted``'s path (None: none is)."""
    parts = dotted.split(".")
    for i, part in enumerate(parts):
        if is_private(part):
            return ".".join(parts[:i])
    return None


def violations(path: Path, root: Path = ROOT) -> list[str]:
    """Every import of a private name across modules in one file (of the tree at ``root``),
    as ``file:line: what``."""
    module = module_name(path, root)
    package = package_of(path, module)
    tree = ast.parse(path.read_text(), filename=str(path))
    found: list[str] = []
    where = f"{path.relative_to(root)}"

    def check_module(dotted: str, line: int) -> None:
        owner = private_module_owner(dotted)
        if owner is not None and not (package == owner or package.startswith(owner + ".")):
            found.append(f"{where}:{line}: private module {dotted} imported from outside {owner}")

    bound: dict[str, str] = {}  # local name -> package module it is bound to
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if not alias.name.startswith("mcpilco."):
                    continue
                check_module(alias.name, node.lineno)
                if alias.asname:
                    bound[alias.asname] = alias.name
        elif isinstance(node, ast.ImportFrom):
            source = resolve(node, package)
            if not source.startswith("mcpilco"):
                continue
            check_module(source, node.lineno)
            for alias in node.names:
                target = f"{source}.{alias.name}"
                if is_module(target, root):  # a submodule: its own name is checked as a module
                    check_module(target, node.lineno)
                    bound[alias.asname or alias.name] = target
                elif is_private(alias.name) and source != module:
                    found.append(f"{where}:{node.lineno}: {alias.name} of {source}")
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Name)
            and node.value.id in bound
            and is_private(node.attr)
            and bound[node.value.id] != module
            and not is_module(f"{bound[node.value.id]}.{node.attr}", root)
        ):
            found.append(f"{where}:{node.lineno}: {node.attr} of {bound[node.value.id]}")
    return found


def package_files() -> list[Path]:
    return sorted(p for folder in FOLDERS for p in (ROOT / folder).rglob("*.py"))


def imported_modules(path: Path) -> set[str]:
    """The package modules one file imports (``from a import b`` gives ``a`` and ``a.b``)."""
    module = module_name(path)
    package = package_of(path, module)
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            source = resolve(node, package)
            out.add(source)
            out.update(f"{source}.{a.name}" for a in node.names)
    return {m for m in out if m.startswith("mcpilco")}


def test_no_module_imports_another_modules_private_names() -> None:
    found = [v for path in package_files() for v in violations(path)]
    assert not found, "private names imported across modules (make them public):\n" + "\n".join(
        found
    )


def test_the_checker_sees_each_kind_of_private_import(tmp_path) -> None:
    """The rules above on a small tree of their own: each kind of offence is found, each
    allowed form is not."""
    pkg = tmp_path / "models" / "kernels"
    pkg.mkdir(parents=True)
    (tmp_path / "models" / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("from mcpilco.models.kernels._base import Kernel\n")
    (pkg / "_base.py").write_text("class Kernel: ...\n_helper = 1\n")
    (pkg / "own.py").write_text("from ._base import Kernel\n_local = 1\nprint(_local)\n")
    (tmp_path / "models" / "bad.py").write_text(
        "from mcpilco.models.kernels._base import Kernel\n"  # private module from outside
        "from mcpilco.models.kernels.own import _local\n"  # private name
        "from mcpilco.models.kernels import own\n"
        "import mcpilco.models.kernels.own as o\n"
        "print(own._local, o._local, own.__name__)\n"  # two private attributes, one dunder
    )
    got = {p.name: violations(p, tmp_path) for p in (tmp_path / "models").rglob("*.py")}
    assert got["__init__.py"] == [] and got["own.py"] == [] and got["_base.py"] == []
    bad = "\n".join(got["bad.py"])
    assert len(got["bad.py"]) == 4, bad
    assert "private module mcpilco.models.kernels._base" in bad and "_local of" in bad


def test_fast_rollouts_import_only_public_names_and_no_part_imports_them() -> None:
    fast_files = sorted((ROOT / "agents" / "mc_pilco" / "fast").rglob("*.py"))
    assert fast_files, "agents/mc_pilco/fast/ is missing"
    for path in fast_files:  # no private name of any module, own package included
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("mcpilco"):
                private = [a.name for a in node.names if is_private(a.name)]
                assert not private, f"{path.relative_to(ROOT)} imports {private}"
            # nor a private attribute of another object (the loss's, a part's): own ones only
            if isinstance(node, ast.Attribute) and is_private(node.attr):
                owner = ast.unparse(node.value)
                assert owner in ("self", "cls"), (
                    f"{path.relative_to(ROOT)}:{node.lineno} reads {owner}.{node.attr}"
                )
    for path in package_files():
        module = module_name(path)
        if module in PARTS:
            fast = {m for m in imported_modules(path) if m == FAST or m.startswith(FAST + ".")}
            assert not fast, f"{module} imports the fast rollouts {sorted(fast)}"


@pytest.mark.parametrize("part", PARTS)
def test_each_part_module_exists(part: str) -> None:
    assert is_module(part), f"{part} is listed as a rollout part but does not exist"
