"""Run folders: one run per folder, one process per run, every written file listed.

A *run folder* is the ``--out`` folder of a training run. :func:`open_run_folder`

* refuses a folder that holds another run (its ``manifest.json``, or, in a folder without
  a manifest, the known run outputs) unless the caller resumes it or overwrites it;
  ``overwrite`` first deletes the files the other run wrote (those its manifest lists, and
  the known run outputs), never other files;
* takes an exclusive ``fcntl.flock`` on ``run.lock`` so that a second process on the same
  folder fails at once; the kernel releases the lock when the process exits or is killed,
  so a killed run never leaves a stale lock;
* keeps ``manifest.json``, the list of files the run wrote (rewritten atomically by
  :meth:`RunFolder.record`; files deleted since are dropped from it);
* follows no symbolic link: ``run.lock``, the manifest and every temporary file are opened
  with ``O_NOFOLLOW`` (temporary files created with ``O_EXCL``,
  :mod:`mcpilco.models.files`), so a link put into the folder by someone else is refused
  instead of written through; every name a manifest lists must be a plain file name of the
  folder (a path outside it is refused, never deleted).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import time
from pathlib import Path, PurePosixPath
from typing import Any

from mcpilco.envs.numbers import shown
from mcpilco.models.files import open_nofollow, read_bytes, write_atomic

__all__ = [
    "LOCK_NAME",
    "MANIFEST_NAME",
    "RunFolder",
    "RUN_OUTPUTS",
    "RunFolderBusyError",
    "open_run_folder",
]

MANIFEST_NAME = "manifest.json"
# the lock file; held with flock while a process runs in the folder
LOCK_NAME = "run.lock"
# files and glob patterns of an MC-PILCO run's outputs (recognised also without a manifest)
RUN_OUTPUTS = (
    "checkpoint.pt",
    "checkpoint.pt.tmp",
    "records.json",
    "records.json.tmp",
    "run.rrd",
    "optimisation.png",
    "trial_*_particles.png",
    "gp_trial*.pt",
    "gp_trial*.pt.tmp",
)
_FORMAT = "mcpilco.run_folder/1"  # the manifest's format tag
MAX_MANIFEST_BYTES = 1 << 20  # largest manifest read (a run lists a few dozen files)


class RunFolderBusyError(ValueError):
    """Another process holds the run folder's lock."""


class RunFolder:
    """An acquired run folder (see the module docstring); release with :meth:`close`.

    Attributes:
        path: the folder.
        resumed: whether the folder held a run that this one continues.
    """

    def __init__(self, path: Path, lock_fd: int, resumed: bool) -> None:
        self.path = path
        self.resumed = resumed
        self._lock_fd: int | None = lock_fd
        old = run_files(path) if resumed else []
        self._files: set[str] = {f.relative_to(path).as_posix() for f in old}
        self.record(LOCK_NAME)

    def record(self, *paths: str | os.PathLike) -> None:
        """Add the files ``paths`` (inside the folder; relative names may be glob patterns)
        to the manifest and rewrite it atomically.

        Only existing files are listed; files recorded before and deleted since are dropped.
        """
        for p in paths:
            p = Path(p)
            if p.is_absolute():
                self._files.add(p.relative_to(self.path).as_posix())
            else:
                self._files |= {f.relative_to(self.path).as_posix() for f in self.path.glob(str(p))}
        self._files = {
            f for f in self._files if (self.path / f).is_file() and not (self.path / f).is_symlink()
        }
        files = sorted(self._files | {MANIFEST_NAME})
        data = {"format": _FORMAT, "updated": time.time(), "files": files}
        write_atomic(self.path / MANIFEST_NAME, json.dumps(data, indent=1))

    @property
    def files(self) -> list[str]:
        """The files listed in the manifest (relative to the folder)."""
        return sorted(self._files | {MANIFEST_NAME})

    def close(self) -> None:
        """Release the lock (idempotent)."""
        fd = getattr(self, "_lock_fd", None)
        if fd is not None:
            self._lock_fd = None
            os.close(fd)  # closing the descriptor releases the flock

    def __enter__(self) -> RunFolder:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __del__(self) -> None:
        self.close()


def _read_manifest(path: Path) -> dict[str, Any]:
    """The manifest of ``path`` (empty when absent); ValueError naming it when damaged."""
    file = path / MANIFEST_NAME
    if not file.exists() and not file.is_symlink():
        return {}
    try:
        data = json.loads(read_bytes(file, "run manifest", MAX_MANIFEST_BYTES))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as err:
        raise ValueError(
            f"{file} is damaged ({type(err).__name__}); delete it, or pass --overwrite to clear "
            "the run"
        ) from None
    if not isinstance(data, dict) or not isinstance(data.get("files", []), list):
        raise ValueError(f"{file} is not a run manifest; delete it or choose another folder")
    return data


def _listed_file(path: Path, name: Any) -> Path:
    """The file ``name`` of a manifest of ``path``: a plain file name in the folder (no
    folder part, no ``..``, not absolute); ValueError naming the manifest otherwise, so that
    a crafted manifest can never make ``--overwrite`` delete a file outside the folder."""
    ok = isinstance(name, str) and name not in ("", ".", "..") and "\0" not in name
    if ok:
        pure = PurePosixPath(name)
        ok = not pure.is_absolute() and len(pure.parts) == 1 and "\\" not in name
    if ok:
        file = path / name
        ok = file.parent.resolve() == path.resolve()
    if not ok:
        raise ValueError(
            f"{path / MANIFEST_NAME} lists {shown(name)}, which is not a file of the run "
            "folder; it was not written by a run: delete the manifest (and check the folder) "
            "before reusing the folder"
        )
    return file


def run_files(path: Path) -> list[Path]:
    """Files of an earlier run in ``path``: those its manifest lists and the known run
    outputs (:data:`RUN_OUTPUTS`), the lock file excluded; sorted."""
    found: set[Path] = set()
    listed: list[Any] = []
    with contextlib.suppress(ValueError):  # a damaged manifest is itself a run file
        listed = _read_manifest(path).get("files", [])
    found |= {_listed_file(path, f) for f in listed}  # a path outside the folder: refused
    for pattern in (*RUN_OUTPUTS, MANIFEST_NAME, MANIFEST_NAME + ".tmp"):
        found |= set(path.glob(pattern))
    return sorted(f for f in found if f.name != LOCK_NAME and (f.is_file() or f.is_symlink()))


def _lists_outputs(path: Path) -> bool:
    """Whether the manifest of ``path`` lists files besides itself and the lock (True when
    it cannot be read: a damaged manifest counts as a run's)."""
    try:
        listed = _read_manifest(path).get("files", [])
    except ValueError:
        return True
    return any(f not in (MANIFEST_NAME, LOCK_NAME) for f in listed)


def _lock(path: Path) -> int:
    """Open and ``flock`` the folder's lock file; RunFolderBusyError when held elsewhere."""
    lock_file = path / LOCK_NAME
    fd = open_nofollow(lock_file, os.O_RDWR | os.O_CREAT)  # a link there is refused
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "another process"
        os.close(fd)
        raise RunFolderBusyError(
            f"{path} is in use by {holder} (lock {lock_file}); wait for that run to end or "
            "choose another output folder"
        ) from None
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"process {os.getpid()}".encode(), 0)
    return fd


def open_run_folder(
    path: str | os.PathLike, *, resume: bool = False, overwrite: bool = False
) -> RunFolder:
    """Create or reopen the run folder ``path``, lock it and start its manifest.

    Args:
        path: the folder (created with its parents).
        resume: continue the run in ``path`` (its manifest is kept and extended).
        overwrite: delete the files of the run in ``path`` first (see :func:`run_files`).

    Raises:
        ValueError: ``path`` is a file, both ``resume`` and ``overwrite``, or ``path`` holds
            another run and neither is given (the message says which flag to pass).
        RunFolderBusyError: another process runs in ``path``.
    """
    path = Path(path)
    if resume and overwrite:
        raise ValueError("--resume and --overwrite exclude each other: pass one of them")
    if path.exists() and not path.is_dir():
        raise ValueError(f"output folder {path} is a file; choose a folder")
    path.mkdir(parents=True, exist_ok=True)
    fd = _lock(path)
    try:
        old = run_files(path)
        links = [f for f in old if f.is_symlink()]
        if links:  # someone else's link among a run's files: refused, not deleted nor followed
            raise ValueError(
                f"{links[0]} is a symbolic link; a run folder holds no links (one could "
                "redirect a write or a read outside the folder): remove it, or choose another "
                "folder"
            )
        if not [f for f in old if f.name != MANIFEST_NAME] and not _lists_outputs(path):
            old = []  # a manifest of a run that wrote nothing (it failed before its first file)
        if old and not resume:
            if not overwrite:
                names = ", ".join(f.name for f in old[:3]) + (", ..." if len(old) > 3 else "")
                raise ValueError(
                    f"{path} holds another run ({names}); pass --resume to continue it, "
                    "--overwrite to delete it first, or choose another output folder"
                )
            for f in old:
                f.unlink(missing_ok=True)
        return RunFolder(path, fd, resumed=bool(old) and resume)
    except BaseException:
        os.close(fd)
        raise
