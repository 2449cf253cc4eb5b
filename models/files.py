"""Atomic file writes: a reader (a resumed run, a second process) sees the old file or the
whole new one, never a part.

The content goes to a temporary file in the destination's folder, is flushed to disk
(``fsync``) and renamed over the destination with ``os.replace``, which is atomic on POSIX
within one file system. A write that fails or is interrupted removes its temporary file; a
process killed mid-write leaves at most the temporary file, never a truncated destination.

:func:`write_atomic` writes text or bytes; :func:`atomic_path` hands a temporary path to
code that writes the file itself (``torch.save``, a recording library) and moves it into
place when that code returns. Every layer above ``models`` (agents, experiments, scripts)
writes its files through these two.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_path", "write_atomic"]


@contextmanager
def atomic_path(
    path: str | os.PathLike, *, tmp: str | os.PathLike | None = None, suffix: str = ".tmp"
) -> Iterator[Path]:
    """Yield a temporary path for ``path``; on a normal exit, fsync it and rename it over
    ``path``; on an exception, delete it and re-raise.

    ``tmp``: a fixed temporary name (for callers whose readers look for a known partial file,
    e.g. ``checkpoint.pt.tmp``); by default a unique ``.<name>.<random><suffix>`` in the same
    folder, so that concurrent writers of one destination never share a temporary file. The
    folder is created when missing; the file gets the permissions of the process's umask, as
    with :func:`open`.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if tmp is None:
        fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
        os.close(fd)
        tmp_path = Path(name)
    else:
        tmp_path = Path(tmp)
    try:
        yield tmp_path
        with open(tmp_path, "rb+") as fh:
            os.fsync(fh.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp_path, 0o666 & ~umask)
        os.replace(tmp_path, path)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


def write_atomic(path: str | os.PathLike, content: str | bytes) -> None:
    """Write ``content`` (text as UTF-8, or bytes) to ``path`` atomically
    (:func:`atomic_path`)."""
    with atomic_path(path) as tmp:
        if isinstance(content, bytes):
            tmp.write_bytes(content)
        else:
            tmp.write_text(content, encoding="utf-8")
