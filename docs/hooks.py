"""MkDocs hook: present the source folders as one ``mcpilco`` package to the API pages.

The repository installs its top-level folders under one import root through setuptools'
``package-dir`` mapping (``models/`` -> ``mcpilco.models`` and so on), so no ``mcpilco/``
folder exists for griffe's static analysis to read. This hook builds one, made of links to
the mapped folders, under ``build/api_src`` (git-ignored) before the pages are rendered;
``mkdocs.yml`` points the mkdocstrings handler at it. Nothing is imported.
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent  # the repository root
API_SRC = ROOT / "build" / "api_src"  # must match plugins.mkdocstrings...paths in mkdocs.yml


def package_dirs(pyproject: Path = ROOT / "pyproject.toml") -> dict[str, str]:
    """The ``[tool.setuptools] package-dir`` mapping: import name -> folder."""
    with pyproject.open("rb") as f:
        return tomllib.load(f)["tool"]["setuptools"]["package-dir"]


def link_packages(dest: Path = API_SRC) -> None:
    """Create ``dest/<a>/<b>`` -> ``<folder>`` links for every ``a.b`` of the mapping."""
    for name, folder in package_dirs().items():
        link = dest.joinpath(*name.split("."))
        target = (ROOT / folder).resolve()
        if link.is_symlink() and link.resolve() == target:
            continue
        link.parent.mkdir(parents=True, exist_ok=True)
        if link.is_symlink() or link.exists():
            link.unlink()
        os.symlink(target, link, target_is_directory=True)


def on_startup(command, dirty):
    """Link the folders before any plugin runs (the handler reads its paths on start)."""
    link_packages()
