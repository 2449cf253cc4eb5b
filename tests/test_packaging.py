"""Packaging contract: the top-level folders install under one import root, and the
dependency direction of DESIGN.md holds (envs import neither torch-heavy agents nor models)."""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TOP = {
    "envs": "mcpilco.envs",
    "agents": "mcpilco.agents",
    "models": "mcpilco.models",
    "scripts": "mcpilco.scripts",
    "experiments": "mcpilco.experiments",
}


def _declared_packages() -> set[str]:
    with open(ROOT / "pyproject.toml", "rb") as fh:
        return set(tomllib.load(fh)["tool"]["setuptools"]["packages"])


def _tree_packages() -> set[str]:
    found = set()
    for folder, root_name in TOP.items():
        for init in (ROOT / folder).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT / folder)
            parts = [] if str(rel) == "." else list(rel.parts)
            found.add(".".join([root_name, *parts]))
    return found


def test_every_subpackage_is_declared_in_pyproject() -> None:
    missing = _tree_packages() - _declared_packages()
    assert not missing, f"add these to [tool.setuptools].packages in pyproject.toml: {missing}"


def test_declared_packages_exist() -> None:
    stale = _declared_packages() - _tree_packages()
    assert not stale, f"pyproject.toml declares packages with no __init__.py: {stale}"


def test_envs_registration_imports_no_torch_nor_models() -> None:
    code = (
        "import sys, mcpilco.envs, gymnasium as gym; "
        "ids = [i for i in gym.registry if i.startswith('mcpilco/')]; "
        "bad = [m for m in ('torch', 'mcpilco.models', 'mcpilco.agents') if m in sys.modules]; "
        "print(len(ids), bad)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().endswith("[]"), out.stdout


def test_models_do_not_import_agents_or_envs() -> None:
    pattern = re.compile(r"^\s*(from|import)\s+mcpilco\.(agents|envs)\b", re.MULTILINE)
    offenders = []
    for path in (ROOT / "models").rglob("*.py"):
        if pattern.search(path.read_text()):
            offenders.append(str(path.relative_to(ROOT)))
    assert not offenders, f"models/ must not import agents/ or envs/: {offenders}"


def test_agents_and_models_do_not_import_experiments() -> None:
    pattern = re.compile(r"^\s*(from|import)\s+mcpilco\.experiments\b", re.MULTILINE)
    offenders = [
        str(path.relative_to(ROOT))
        for folder in ("agents", "models", "envs")
        for path in (ROOT / folder).rglob("*.py")
        if pattern.search(path.read_text())
    ]
    assert not offenders, f"agents/, models/ and envs/ must not import experiments/: {offenders}"


SCRIPT_IMPORT = re.compile(
    r"^\s*(from\s+mcpilco\.scripts\b|import\s+mcpilco\.scripts\b|from\s+mcpilco\s+import\s+scripts\b)",
    re.MULTILINE,
)  # an import of the command-line faces
MAX_SCRIPT_LINES = 300  # a console script parses arguments and calls the library


def test_nothing_imports_from_scripts() -> None:
    """Library code, other scripts and tests use the library; a command is run, not imported
    (tests run commands through the ``command`` fixture of tests/conftest.py)."""
    offenders = [
        str(path.relative_to(ROOT))
        for folder in ("agents", "models", "envs", "experiments", "scripts", "tests")
        for path in (ROOT / folder).rglob("*.py")
        if SCRIPT_IMPORT.search(path.read_text())
    ]
    assert not offenders, f"these import from mcpilco.scripts: {offenders}"


def test_scripts_are_thin() -> None:
    long = {
        path.name: n
        for path in (ROOT / "scripts").glob("*.py")
        if (n := len(path.read_text().splitlines())) > MAX_SCRIPT_LINES
    }
    assert not long, f"move the logic of these scripts into the library: {long}"
