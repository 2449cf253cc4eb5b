"""Robot description files (MJCF, URDF) read with their includes confined to the model's folder.

An MJCF may pull other files in with ``<include file="..."/>``. A robot file can come from
someone else, and the package copies what it reads into files it writes (``corrected.xml``,
saved diagnosis models, collision-detector files), so an include must not be able to pull
in an arbitrary file of the machine (``/etc/passwd``, another user's data). The rules:

* a robot file given by path is read by :func:`read_robot_file`: every ``<include>`` is
  resolved relative to the folder of the model file (as MuJoCo does), must lie inside the
  allowed root (the model's folder, or the folder the user names, ``--include-root``) once
  symbolic links are resolved, must be a regular file with a ``<mujoco>`` root, and is
  replaced by that root's children, recursively (at most :data:`MAX_INCLUDE_DEPTH` levels, no
  cycle). The returned text holds no ``<include>``: every later reader (MuJoCo from a
  string, pinocchio from a temporary file) sees exactly the files allowed here, and relative
  includes next to the model work wherever the process runs;
* a robot description given as text (or stored in a file of the package: a saved model, a
  detector) has no folder to resolve against: :func:`refuse_includes` refuses any
  ``<include>`` in it.

Refusals are ``ValueError`` naming the model file, the include and the flag to pass.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

from mcpilco.models.files import read_bytes

__all__ = [
    "MAX_INCLUDE_DEPTH",
    "MAX_ROBOT_FILE_BYTES",
    "read_robot_file",
    "refuse_includes",
]

MAX_ROBOT_FILE_BYTES = 64 << 20  # largest robot or included file read (64 MiB)
MAX_INCLUDE_DEPTH = 8  # deepest chain of includes (an include inside an included file, ...)


def _read_text(path: Path, what: str) -> str:
    try:
        data = read_bytes(path, what, MAX_ROBOT_FILE_BYTES)
    except FileNotFoundError:
        raise ValueError(f"no {what} at {path}") from None
    except OSError as err:
        raise ValueError(f"{what} {path} cannot be read ({err.strerror})") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise ValueError(f"{what} {path} is not text ({err.reason} at byte {err.start})") from None


def _has_include(root: ET.Element) -> bool:
    return any(e.tag == "include" for e in root.iter())


def _parse(text: str, source: str) -> ET.Element:
    try:
        return ET.fromstring(text)
    except ET.ParseError as err:
        raise ValueError(f"{source} is not well-formed XML ({err}); fix or replace it") from None


def _expand(
    parent: ET.Element, base: Path, root: Path, chain: tuple[Path, ...], model: Path
) -> None:
    """Replace every ``<include>`` below ``parent`` by the children of the included file's
    ``<mujoco>`` root (module docstring)."""
    children: list[ET.Element] = []
    for child in list(parent):
        if child.tag != "include":
            _expand(child, base, root, chain, model)
            children.append(child)
            continue
        name = child.get("file")
        if not name:
            raise ValueError(f"{model}: an <include> without a file attribute")
        real = (base / name).resolve()  # an absolute name stays absolute
        if not real.is_relative_to(root):
            raise ValueError(
                f"{model}: <include file={name!r}> resolves to {real}, outside {root}; an "
                "include must lie in the model's folder (pass --include-root FOLDER to allow "
                "a folder above it)"
            )
        if real in chain:
            raise ValueError(f"{model}: <include file={name!r}> includes itself (a cycle)")
        if len(chain) > MAX_INCLUDE_DEPTH:
            raise ValueError(f"{model}: includes nested deeper than {MAX_INCLUDE_DEPTH} levels")
        what = f"{model}: included file"
        sub = _parse(_read_text(real, what), f"{what} {real}")
        if sub.tag != "mujoco":
            raise ValueError(f"{what} {real} must have a <mujoco> root, not <{sub.tag}>")
        _expand(sub, base, root, (*chain, real), model)
        children.extend(list(sub))
    parent[:] = children


def read_robot_file(path: str | os.PathLike, include_root: str | os.PathLike | None = None) -> str:
    """The text of the robot file ``path`` with its includes expanded (module docstring).

    Args:
        path: an MJCF or URDF file.
        include_root: folder every include must lie in (None: the model's folder).

    Raises:
        ValueError: the file is missing, not a regular file, too large, not text or not
            well-formed XML, or an include is refused (named, with the flag to pass).
    """
    path = Path(path)
    text = _read_text(path.resolve(), "robot description")
    if "<include" not in text:
        return text
    tree = _parse(text, str(path))
    if not _has_include(tree):
        return text
    root = Path(include_root).resolve() if include_root is not None else path.resolve().parent
    if not root.is_dir():
        raise ValueError(f"--include-root {include_root} is not a folder")
    _expand(tree, path.resolve().parent, root, (path.resolve(),), path)
    return ET.tostring(tree, encoding="unicode")


def refuse_includes(text: str, source: str) -> None:
    """Raise ValueError when the robot description ``text`` (named ``source``) holds an
    ``<include>``: text has no folder its includes could be confined to."""
    if "<include" in text and _has_include(_parse(text, source)):
        raise ValueError(
            f"{source} holds an <include>, which a robot description given as text cannot "
            "have; give the model file's path (its includes are read from its folder)"
        )
