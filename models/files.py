"""File access of run folders and results: atomic writes, and reads and creations that follow
no symbolic link.

Atomic writes: a reader (a resumed run, a second process) sees the old file or the whole new
one, never a part. The content goes to a temporary file in the destination's folder, is
flushed to disk (``fsync``) and renamed over the destination with ``os.replace``, which is
atomic on POSIX within one file system (and replaces a link at the destination itself, never
its target). A write that fails or is interrupted removes its temporary file; a process
killed mid-write leaves at most the temporary file, never a truncated destination.
:func:`write_atomic` writes text or bytes, :func:`atomic_open` yields the open file (for
``torch.save``), and :func:`atomic_path` hands a temporary path to code
that writes the file itself by name (a recording library) and moves it into place
when that code returns. Every layer above ``models`` (agents, experiments, scripts) writes
its files through these two.

No links: a run folder may sit on a shared machine where someone else can put files into
it. A symbolic link named like a run's file (``run.lock``, ``checkpoint.pt.tmp``) would make
a plain ``open`` write through the link into a file outside the folder. A temporary file is
therefore created with ``O_CREAT | O_EXCL | O_NOFOLLOW`` (:func:`create_new`: a link, or a
file that appeared in between, makes it fail; a symbolic link is refused, not removed, so the
user sees what was put into the folder); :func:`open_nofollow` opens an existing regular
file without following a link; :func:`read_bytes` reads only a regular file of bounded size
(a FIFO or a device would block or never end). Every refusal is a ``ValueError`` naming the
file and what to do.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import stat
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import BinaryIO

__all__ = [
    "LinkError",
    "atomic_open",
    "atomic_path",
    "create_new",
    "open_nofollow",
    "read_bytes",
    "read_signed",
    "sign_file",
    "signing_key",
    "write_atomic",
]


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
        os.close(create_new(tmp_path))  # a link at the fixed name is refused
    try:
        yield tmp_path
        fd = open_nofollow(tmp_path, os.O_RDWR)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp_path, 0o666 & ~umask)
        os.replace(tmp_path, path)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


@contextmanager
def atomic_open(
    path: str | os.PathLike, *, tmp: str | os.PathLike | None = None
) -> Iterator[BinaryIO]:
    """Yield a binary file open for writing at a new temporary file for ``path`` (``tmp``, a
    fixed name created by :func:`create_new`, or a unique one as :func:`atomic_path`); on a
    normal exit flush, fsync and rename it over ``path``; on an exception delete it and
    re-raise. The content is written through the descriptor that created the file, so nothing
    put at the temporary name meanwhile is written through."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if tmp is None:
        fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        tmp_path = Path(name)
    else:
        tmp_path = Path(tmp)
        fd = create_new(tmp_path)
    try:
        with os.fdopen(fd, "wb") as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
            umask = os.umask(0)
            os.umask(umask)
            os.fchmod(fh.fileno(), 0o666 & ~umask)
        os.replace(tmp_path, path)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


def write_atomic(path: str | os.PathLike, content: str | bytes) -> None:
    """Write ``content`` (text as UTF-8, or bytes) to ``path`` atomically
    (:func:`atomic_open`)."""
    with atomic_open(path) as fh:
        fh.write(content if isinstance(content, bytes) else content.encode("utf-8"))


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


SIGNATURE_SUFFIX = ".sig"  # the HMAC of a signed file sits beside it under this suffix
KEY_ENV = "MCPILCO_KEY_FILE"  # environment variable naming the signing key's file
_SIGN_CONTEXT = b"mcpilco-signed-file/1\0"  # prefix of every signed message (domain separation)


def signing_key_path() -> Path:
    """The user's signing key: ``$MCPILCO_KEY_FILE``, else ``~/.config/mcpilco/file_key``."""
    env = os.environ.get(KEY_ENV)
    return Path(env) if env else Path.home() / ".config" / "mcpilco" / "file_key"


def signing_key() -> bytes:
    """The user's 32-byte signing key, created on first use with permissions 0600 in a
    folder of permissions 0700 (only this user can read it, so only this user can sign).

    Raises:
        ValueError: the key file is a link, not a regular file, readable by others, or not
            32 bytes; the message names it and what to do.
    """
    path = signing_key_path()
    if not path.exists() and not path.is_symlink():
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
        except FileExistsError:  # another process created it meanwhile
            pass
        else:
            with os.fdopen(fd, "wb") as fh:
                fh.write(os.urandom(32))
    key = read_bytes(path, "signing key", 64)
    mode = os.stat(path, follow_symlinks=False).st_mode
    if mode & 0o077:
        raise ValueError(
            f"signing key {path} is readable or writable by others (mode {oct(mode & 0o777)}); "
            "run chmod 600 on it"
        )
    if len(key) != 32:
        raise ValueError(f"signing key {path} is not 32 bytes; remove it to make a new one")
    return key


def _signature(name: str, data: bytes) -> str:
    msg = _SIGN_CONTEXT + name.encode() + b"\0" + data
    return hmac.new(signing_key(), msg, hashlib.sha256).hexdigest()


def sign_file(path: str | os.PathLike) -> None:
    """Write ``<path>.sig``: the HMAC-SHA256, under the user's :func:`signing_key`, of the
    file's name and bytes. A file another library writes in a format that can run code when
    read (a pickle) is signed after it is written and read back only through
    :func:`read_signed`."""
    path = Path(path)
    data = read_bytes(path, "file to sign", 1 << 34)
    write_atomic(path.with_name(path.name + SIGNATURE_SUFFIX), _signature(path.name, data))


def read_signed(path: str | os.PathLike, what: str, max_bytes: int = 1 << 34) -> bytes:
    """The bytes of ``path`` when ``<path>.sig`` holds their HMAC under the user's key
    (:func:`sign_file`): a file this user's runs wrote, not one put into the folder by
    someone else. The bytes are read once, so what is checked is what the caller gets.

    Raises:
        ValueError: no signature, a wrong one, a link or an oversized file; the message
            names ``what`` and the file.
    """
    path = Path(path)
    data = read_bytes(path, what, max_bytes)
    sig_path = path.with_name(path.name + SIGNATURE_SUFFIX)
    try:
        sig = read_bytes(sig_path, f"signature of {what}", 256).decode("ascii", "replace")
    except FileNotFoundError:
        raise ValueError(
            f"{what} {path} has no signature ({sig_path.name}): it was not written by your "
            "runs, so it is not read (it could run code); start the run again without resuming"
        ) from None
    if not hmac.compare_digest(sig.strip(), _signature(path.name, data)):
        raise ValueError(
            f"{what} {path} does not match its signature: changed after your run wrote it, or "
            "written by someone else; it is not read (it could run code); start the run again"
        )
    return data
