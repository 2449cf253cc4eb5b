"""Safe files of tensors and plain data: atomic writes, loads that cannot run code.

Files written by :func:`atomic_torch_save` hold only what ``torch.load(weights_only=True)``
accepts: tensors, ``int``/``float``/``bool``/``str``/``None`` and dicts, lists and tuples of
them. Numpy arrays are stored as tensors inside a tagged dict (``{"__ndarray__": tensor}``)
and numpy scalars as Python numbers; :func:`load_torch_file` turns the tags back into
arrays. A file from someone else therefore cannot execute code when it is loaded.

Every failure to read a file becomes a ``ValueError`` (``FileNotFoundError`` when it does
not exist) that names the file, says what is wrong with it and what to do.
"""

from __future__ import annotations

import io
import os
import pickle
import re
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mcpilco.models.files import atomic_open, read_bytes

__all__ = ["atomic_torch_save", "from_safe", "load_torch_bytes", "load_torch_file", "to_safe"]

_NDARRAY_TAG = "__ndarray__"  # key of the dict that stands for a numpy array in a file
MAX_TORCH_FILE_BYTES = 4 << 30  # largest file read (4 GiB)


def to_safe(obj: Any) -> Any:
    """``obj`` with numpy arrays as tagged tensors and numpy scalars as Python numbers.

    Raises:
        TypeError: a value that is neither a tensor, plain data nor numpy (names its type).
    """
    if isinstance(obj, torch.Tensor) or obj is None or isinstance(obj, (bool, int, float, str)):
        return obj.item() if isinstance(obj, np.generic) else obj
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind not in "biuf":
            raise TypeError(f"cannot store a numpy array of dtype {obj.dtype} safely")
        return {_NDARRAY_TAG: torch.from_numpy(np.ascontiguousarray(obj)).clone()}
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, dict):
        return {k: to_safe(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [to_safe(v) for v in obj]
    if isinstance(obj, tuple):
        return tuple(to_safe(v) for v in obj)
    raise TypeError(
        f"cannot store a {type(obj).__name__} in a safe file: use tensors, numpy arrays or "
        "plain data (numbers, strings, lists, dicts)"
    )


def from_safe(obj: Any) -> Any:
    """Inverse of :func:`to_safe`: tagged tensors back to numpy arrays."""
    if isinstance(obj, dict):
        if set(obj) == {_NDARRAY_TAG} and isinstance(obj[_NDARRAY_TAG], torch.Tensor):
            return obj[_NDARRAY_TAG].numpy()
        return {k: from_safe(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [from_safe(v) for v in obj]
    if isinstance(obj, tuple):
        return tuple(from_safe(v) for v in obj)
    return obj


def atomic_torch_save(obj: Any, path: str | os.PathLike) -> None:
    """Write ``to_safe(obj)`` to ``path`` through ``<path>.tmp`` (the partial file a resume
    check looks for), :func:`~mcpilco.models.files.atomic_open`: a process killed while
    writing leaves the previous file intact."""
    path = Path(path)
    payload = to_safe(obj)
    with atomic_open(path, tmp=path.with_name(path.name + ".tmp")) as fh:
        torch.save(payload, fh)


def load_torch_file(
    path: str | os.PathLike, what: str, remedy: str, *, follow_links: bool = True
) -> Any:
    """Load a file written by :func:`atomic_torch_save` (or ``torch.save`` of tensors and
    plain data) with ``weights_only=True``.

    Args:
        path: the file.
        what: what the file is, for messages (e.g. ``"checkpoint"``).
        remedy: what the user can do when it cannot be read (ends the message).
        follow_links: read through a symbolic link at ``path``; False (a run folder's
            files): a link is refused (:func:`mcpilco.models.files.read_bytes`).

    Raises:
        FileNotFoundError: no file at ``path``.
        ValueError: ``path`` is a folder, empty, truncated, not a torch file, or holds
            objects other than tensors and plain data.
    """
    path = Path(path)
    if not path.exists() and not path.is_symlink():
        raise FileNotFoundError(f"{what} {path} does not exist; {remedy}")
    if follow_links and not path.is_file():
        raise ValueError(f"{what} {path} is not a file; {remedy}")
    target = path.resolve() if follow_links else path
    try:
        data = read_bytes(target, what, MAX_TORCH_FILE_BYTES)
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} {path} does not exist; {remedy}") from None
    return load_torch_bytes(data, f"{what} {path}", remedy)


def load_torch_bytes(data: bytes, what: str, remedy: str) -> Any:
    """:func:`load_torch_file` of the bytes ``data`` (``what`` names them in messages).

    Raises:
        ValueError: empty, truncated, not a torch file, or objects other than tensors and
            plain data.
    """
    if not data:
        raise ValueError(f"{what} is empty (0 bytes); {remedy}")
    if not zipfile.is_zipfile(io.BytesIO(data)):
        raise ValueError(
            f"{what} is damaged or truncated (not the zip archive torch.save writes); {remedy}"
        )
    try:
        payload = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as err:
        found = re.search(r"Unsupported global: GLOBAL (\S+)", str(err))
        which = f" ({found.group(1)})" if found else ""
        raise ValueError(
            f"{what} holds objects other than tensors and plain data{which}, which are not "
            f"loaded because loading them could run code; {remedy}"
        ) from err
    except Exception as err:  # noqa: BLE001 - any failure of a crafted archive is "damaged"
        raise ValueError(
            f"{what} is damaged or truncated ({type(err).__name__}: "
            f"{' '.join(str(err).split())[:200]}); {remedy}"
        ) from err
    return from_safe(payload)
