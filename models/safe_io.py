"""File access that follows no symbolic link: the writes and reads of a run folder.

A run folder (the ``--out`` of a run) may sit on a shared machine where someone else can
put files into it. A symbolic link named like a run's file (``run.lock``,
``checkpoint.pt.tmp``, ``records.json.tmp``) would make a plain ``open`` write through the
link into a file outside the folder. The functions here never follow a link in the last
component of a path:

* :func:`create_new` creates a file with ``O_CREAT | O_EXCL | O_NOFOLLOW`` (a link, or a
  file that appeared in between, makes it fail) after removing a stale regular file of that
  name (left by a killed process); a symbolic link there is refused, not removed, so the
  user sees what was put into the folder;
* :func:`atomic_write` writes through :func:`create_new` on ``<path>.tmp``, fsyncs, and
  moves the file over ``path`` with ``os.replace`` (which replaces a link at ``path``
  itself, never its target);
* :func:`read_bytes` opens with ``O_NOFOLLOW | O_NONBLOCK`` and reads only a regular file of
  at most ``max_bytes`` (a FIFO or a device would block or never end).

Every refusal is a ``ValueError`` naming the file and what to do.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

__all__ = ["LinkError", "atomic_write", "create_new", "open_nofollow", "read_bytes"]


class LinkError(ValueError):
    """A path of a run folder is a symbolic link (or not a regular file) and was refused."""


def _link_error(path: Path) -> LinkError:
    return LinkError(
        f"{path} is a symbolic link; a run folder holds no links (one could redirect a write "
        "or a read outside the folder): remove it, or choose another folder"
    )


def open_nofollow(path: str | os.PathLike, flags: int, mode: int = 0o644) -> int:
    """``os.open(path, flags | O_NOFOLLOW | O_CLOEXEC)`` for a regular file; the descriptor.

    Raises:
        LinkError: ``path`` is a symbolic link or not a regular file (the descriptor is
            closed).
        FileNotFoundError: no file at ``path`` and ``flags`` has no ``O_CREAT``.
    """
    path = Path(path)
    try:
        fd = os.open(path, flags | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK, mode)
    except OSError as err:
        if path.is_symlink():
            raise _link_error(path) from None
        if isinstance(err, IsADirectoryError):
            raise LinkError(f"{path} is a folder where a file is expected; remove it") from None
        raise
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise LinkError(f"{path} is not a regular file; remove it, or choose another folder")
    os.set_blocking(fd, True)
    return fd


def create_new(path: str | os.PathLike) -> int:
    """A new, empty regular file at ``path`` opened for writing (its descriptor); a stale
    regular file of that name is removed first, a symbolic link is refused.

    Raises:
        LinkError: ``path`` is a symbolic link or a folder.
        FileExistsError: another process created ``path`` in between.
    """
    path = Path(path)
    if path.is_symlink():
        raise _link_error(path)
    if path.exists():
        if not path.is_file():
            raise LinkError(f"{path} is not a regular file; remove it, or choose another folder")
        path.unlink()
    return open_nofollow(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL)


def atomic_write(path: str | os.PathLike, data: bytes | str) -> None:
    """Write ``data`` to ``path`` atomically: ``<path>.tmp`` (:func:`create_new`), fsync,
    ``os.replace`` (a process killed meanwhile leaves the previous file intact)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    payload = data.encode() if isinstance(data, str) else data
    fd = create_new(tmp)
    with os.fdopen(fd, "wb") as fh:
        fh.write(payload)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def read_bytes(path: str | os.PathLike, what: str, max_bytes: int) -> bytes:
    """The bytes of the regular file ``path`` (not a link), at most ``max_bytes``.

    Raises:
        FileNotFoundError: no file at ``path``.
        LinkError: a symbolic link, a folder, a FIFO or a device.
        ValueError: larger than ``max_bytes``.
    """
    path = Path(path)
    try:
        fd = open_nofollow(path, os.O_RDONLY | os.O_NOCTTY)
    except LinkError as err:
        raise LinkError(f"{what} {err}") from None
    with os.fdopen(fd, "rb") as fh:
        data = fh.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise ValueError(f"{what} {path} is larger than {max_bytes} bytes; it is not such a file")
    return data
