"""The one YAML loader of the package: safe, bounded, YAML 1.2 numbers, errors that name the file.

Every YAML the package reads (task files, config files, ``--set`` values, the baselines'
hyperparameter files, comparison specs) goes through :func:`parse_yaml` or
:func:`read_yaml`. A YAML file may come from someone else (a shared machine, a shared data
set), so the loader

* constructs only plain data (``SafeLoader``: mappings, lists, strings, numbers, booleans,
  null); a Python tag (``!!python/object``) is refused, so loading cannot run code;
* refuses a file larger than :data:`MAX_YAML_BYTES`, a path that is not a regular file (a
  FIFO or a device would block or never end), nesting deeper than :data:`MAX_DEPTH`, more
  than :data:`MAX_ALIASES` aliases, a recursive alias, and a document whose size with every
  alias expanded exceeds :data:`MAX_NODES` nodes: an alias bomb ("billion laughs", ``k``
  levels of ``n`` aliases expand to ``n^k`` nodes) is refused while composing, before
  anything is expanded;
* refuses a key given twice in one mapping (the second would silently win);
* reads numbers as YAML 1.2 does: ``1e-4``, ``-1e3``, ``.5``, ``5.``, ``+2`` are numbers
  (YAML 1.1, PyYAML's default, reads ``1e-4`` as a string), ``.inf`` / ``-.inf`` / ``.nan``
  are floats (refused later where a finite number is needed, :mod:`mcpilco.envs.numbers`),
  ``true`` / ``false`` are the only booleans (``yes``, ``no``, ``on``, ``off`` stay
  strings), ``010`` is ten, and dates stay strings.

Errors are ``ValueError`` naming the file (or the ``--set`` key) and the line, never the
value: an expanded alias bomb is never printed.
"""

from __future__ import annotations

import math
import os
import re
import stat
from pathlib import Path
from typing import Any

import yaml
from yaml.nodes import MappingNode, Node, SequenceNode

__all__ = [
    "MAX_ALIASES",
    "MAX_DEPTH",
    "MAX_NODES",
    "MAX_YAML_BYTES",
    "YAMLInputError",
    "parse_overrides",
    "parse_yaml",
    "read_regular_file",
    "read_yaml",
]

MAX_YAML_BYTES = 1 << 20  # largest YAML text read (1 MiB; the package's files are < 10 kB)
MAX_DEPTH = 64  # deepest nesting of mappings and lists, aliases expanded
MAX_ALIASES = 256  # most aliases (``*name``) in one document
MAX_NODES = 100_000  # most nodes of one document with every alias expanded


class YAMLInputError(ValueError):
    """A YAML text or file was refused; the message names it and says why."""


class _LimitError(Exception):
    """A limit of the loader was passed while composing (turned into YAMLInputError)."""


# YAML 1.2 core schema scalars (https://yaml.org/spec/1.2.2/#1032-tag-resolution)
_BOOL = re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$")
_NULL = re.compile(r"^(?:~|null|Null|NULL|)$")
_INT = re.compile(r"^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$")
_FLOAT = re.compile(
    r"^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
    r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$"
)
_FIRST_CHARS = {
    "tag:yaml.org,2002:bool": "tTfF",
    "tag:yaml.org,2002:null": ["~", "n", "N", ""],
    "tag:yaml.org,2002:int": "-+0123456789",
    "tag:yaml.org,2002:float": "-+.0123456789",
    "tag:yaml.org,2002:merge": "<",
}


class _Loader(yaml.SafeLoader):
    """SafeLoader with YAML 1.2 core scalars and the limits of the module docstring."""

    yaml_implicit_resolvers: dict = {}

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0
        self._aliases = 0

    def compose_node(self, parent: Node | None, index: Any) -> Node:
        if self.check_event(yaml.AliasEvent):
            self._aliases += 1
            if self._aliases > MAX_ALIASES:
                raise _LimitError(f"more than {MAX_ALIASES} aliases")
        self._depth += 1
        try:
            if self._depth > MAX_DEPTH:
                raise _LimitError(f"nested deeper than {MAX_DEPTH} levels")
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_mapping(self, node: MappingNode, deep: bool = False) -> dict:
        seen: set = set()
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=True)
            try:
                duplicate = key in seen
                seen.add(key)
            except TypeError:
                raise yaml.constructor.ConstructorError(
                    None, None, "a mapping key is not a plain value", key_node.start_mark
                ) from None
            if duplicate:
                raise yaml.constructor.ConstructorError(
                    None, None, f"key {str(key)[:60]!r} is given twice", key_node.start_mark
                )
        return super().construct_mapping(node, deep=deep)


def _construct_int(loader: _Loader, node: Node) -> int:
    text = loader.construct_scalar(node)
    sign = -1 if text.startswith("-") else 1
    digits = text.lstrip("+-")
    if digits.startswith("0o"):
        return int(digits[2:], 8)
    if digits.startswith("0x"):
        return int(digits[2:], 16)
    return sign * int(digits, 10)


def _construct_float(loader: _Loader, node: Node) -> float:
    text = loader.construct_scalar(node).lower()
    if text.endswith(".inf"):
        return -math.inf if text.startswith("-") else math.inf
    if text == ".nan":
        return math.nan
    return float(text)


for _tag, _pattern in (
    ("tag:yaml.org,2002:bool", _BOOL),
    ("tag:yaml.org,2002:null", _NULL),
    ("tag:yaml.org,2002:int", _INT),
    ("tag:yaml.org,2002:float", _FLOAT),
    ("tag:yaml.org,2002:merge", re.compile(r"^<<$")),
):
    _Loader.add_implicit_resolver(_tag, _pattern, list(_FIRST_CHARS[_tag]))
_Loader.add_constructor("tag:yaml.org,2002:int", _construct_int)
_Loader.add_constructor("tag:yaml.org,2002:float", _construct_float)


def _children(node: Node) -> list[Node]:
    if isinstance(node, SequenceNode):
        return list(node.value)
    if isinstance(node, MappingNode):
        return [n for pair in node.value for n in pair]
    return []


def _check_expansion(root: Node) -> None:
    """Refuse a node graph (aliases are shared nodes) that is recursive, deeper than
    :data:`MAX_DEPTH` or larger than :data:`MAX_NODES` once expanded. Iterative post-order
    walk with memoised sizes and depths: linear in the distinct nodes."""
    size: dict[int, int] = {}
    depth: dict[int, int] = {}
    on_path: set[int] = set()
    stack: list[tuple[Node, bool]] = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        if done:
            kids = _children(node)
            size[key] = 1 + sum(size[id(k)] for k in kids)
            depth[key] = 1 + max((depth[id(k)] for k in kids), default=0)
            on_path.discard(key)
            if size[key] > MAX_NODES:
                raise _LimitError(f"more than {MAX_NODES} nodes once its aliases are expanded")
            if depth[key] > MAX_DEPTH:
                raise _LimitError(f"nested deeper than {MAX_DEPTH} levels once expanded")
            continue
        if key in size:
            continue
        if key in on_path:
            raise _LimitError("a recursive alias (a node that contains itself)")
        on_path.add(key)
        stack.append((node, True))
        stack.extend((k, False) for k in _children(node) if id(k) not in size)


def parse_yaml(text: str | bytes, source: str) -> Any:
    """The plain data of one YAML document ``text`` (None for an empty one).

    Args:
        text: the YAML (bytes are decoded as UTF-8).
        source: what the text is, for messages (a file path, ``"--set num_particles"``).

    Raises:
        YAMLInputError: too large, not UTF-8, not YAML, a Python tag, a duplicate key, or a
            limit of the module docstring passed; the message names ``source``.
    """
    if len(text) > MAX_YAML_BYTES:
        raise YAMLInputError(
            f"{source}: larger than {MAX_YAML_BYTES} bytes; a YAML input of the package is small"
        )
    if isinstance(text, bytes):
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError as err:
            raise YAMLInputError(f"{source}: not UTF-8 text (byte {err.start})") from None
    loader = None
    try:
        loader = _Loader(text)
        node = loader.get_single_node()
        if node is None:
            return None
        _check_expansion(node)
        return loader.construct_document(node)
    except _LimitError as err:
        raise YAMLInputError(f"{source}: refused, {err}; write the values out plainly") from None
    except yaml.MarkedYAMLError as err:
        mark = err.problem_mark or err.context_mark
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark else ""
        what = err.problem or err.context or "not valid YAML"
        if "could not determine a constructor" in what:
            what = "a tag the package does not read (only plain data is loaded)"
        raise YAMLInputError(f"{source}: {what}{where}") from None
    except yaml.reader.ReaderError as err:
        raise YAMLInputError(
            f"{source}: character #x{err.character:04x} at position {err.position} is not "
            "allowed in YAML"
        ) from None
    except yaml.YAMLError as err:
        raise YAMLInputError(f"{source}: not valid YAML ({type(err).__name__})") from None
    except (ValueError, OverflowError, RecursionError) as err:
        # e.g. an integer of more digits than Python converts
        raise YAMLInputError(f"{source}: a value cannot be read ({type(err).__name__})") from None
    finally:
        if loader is not None:
            loader.dispose()


_KEY = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*)*$")  # dotted field name


def parse_overrides(items: list[str] | None, flag: str = "--set") -> dict[str, Any]:
    """``["a=1", "opt.max_steps=500", "cost_length_scales={x: 1}"]`` -> a nested dict of
    overrides; each value is one YAML document (:func:`parse_yaml`; errors name
    ``<flag> <key>``).

    Raises:
        ValueError: an item without ``=``, a key that is not a dotted field name, a key
            set twice, a key below one that holds a value, or a value :func:`parse_yaml`
            refuses.
    """
    out: dict[str, Any] = {}
    for item in items or []:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not _KEY.match(key):
            raise ValueError(
                f"{flag} takes key=value with a dotted field name as key (opt.max_steps=300), "
                f"got {item[:80]!r}"
            )
        value = parse_yaml(text, f"{flag} {key}")
        node = out
        *parents, leaf = key.split(".")
        for depth, p in enumerate(parents):
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise ValueError(
                    f"{flag} {key}: {'.'.join(parents[: depth + 1])} is set to a value above"
                )
        if leaf in node:
            raise ValueError(f"{flag} {key} is given twice; give it once")
        node[leaf] = value
    return out


def read_regular_file(path: str | os.PathLike, what: str, max_bytes: int) -> bytes:
    """The bytes of the regular file ``path`` (at most ``max_bytes``).

    The file is opened non-blocking and checked to be a regular file before it is read, so a
    FIFO, a device (``/dev/zero``) or a folder is refused instead of blocking or never ending.

    Raises:
        FileNotFoundError: no file at ``path``.
        ValueError: not a regular file, or larger than ``max_bytes`` (names ``what``).
    """
    path = Path(path)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY)
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} {path} does not exist") from None
    except IsADirectoryError:
        raise ValueError(f"{what} {path} is a folder; give a file") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            kind = "a folder" if stat.S_ISDIR(info.st_mode) else "not a regular file"
            raise ValueError(f"{what} {path} is {kind}; give a file")
        if info.st_size > max_bytes:
            raise ValueError(f"{what} {path} is larger than {max_bytes} bytes")
        with os.fdopen(os.dup(fd), "rb") as fh:
            data = fh.read(max_bytes + 1)
    finally:
        os.close(fd)
    if len(data) > max_bytes:
        raise ValueError(f"{what} {path} is larger than {max_bytes} bytes")
    return data


def read_yaml(path: str | os.PathLike, what: str = "YAML file", *, mapping: bool = True) -> Any:
    """The plain data of the YAML file ``path`` (:func:`parse_yaml`).

    Args:
        path: the file.
        what: what the file is, for messages (``"task file"``).
        mapping: the document must be a non-empty mapping (an empty file is an error).

    Raises:
        FileNotFoundError: no file at ``path``.
        ValueError: the file is refused (see :func:`parse_yaml` and
            :func:`read_regular_file`), or ``mapping`` and it is empty or not a mapping.
    """
    source = f"{what} {path}"
    data = parse_yaml(read_regular_file(path, what, MAX_YAML_BYTES), source)
    if mapping and data is None:
        raise YAMLInputError(f"{source} is empty; it must hold a mapping of fields")
    if mapping and not isinstance(data, dict):
        raise YAMLInputError(
            f"{source} must hold a mapping of fields (key: value), not a {type(data).__name__}"
        )
    return data
