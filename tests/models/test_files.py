"""Atomic writes (:mod:`mcpilco.models.files`): the destination is the old file or the whole
new one, and no temporary file is left behind."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from mcpilco.models.files import atomic_path, write_atomic


def test_write_atomic_text_and_bytes(tmp_path: Path) -> None:
    target = tmp_path / "sub" / "a.json"
    write_atomic(target, "héllo")
    assert target.read_text(encoding="utf-8") == "héllo"
    write_atomic(target, b"\x00\x01")
    assert target.read_bytes() == b"\x00\x01"
    assert sorted(p.name for p in target.parent.iterdir()) == ["a.json"]


def test_failed_write_keeps_the_old_file(tmp_path: Path) -> None:
    target = tmp_path / "a.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("killed")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["a.txt"]


def test_fixed_temporary_name_and_umask(tmp_path: Path) -> None:
    target = tmp_path / "c.pt"
    fixed = tmp_path / "c.pt.tmp"
    old = os.umask(0o027)
    try:
        with atomic_path(target, tmp=fixed) as tmp:
            assert tmp == fixed
            tmp.write_bytes(b"x")
    finally:
        os.umask(old)
    assert not fixed.exists() and target.read_bytes() == b"x"
    assert target.stat().st_mode & 0o777 == 0o640
