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


def test_a_signed_file_reads_back_and_any_change_or_swap_is_refused(tmp_path):
    """``read_signed`` returns exactly the bytes ``sign_file`` signed; changed bytes, a file
    without its signature, and a signed file renamed over another (its name is signed too)
    are refused with one line naming the file."""
    from mcpilco.models.files import read_signed, sign_file

    a, b = tmp_path / "replay_1.pkl", tmp_path / "replay_2.pkl"
    a.write_bytes(b"first payload")
    b.write_bytes(b"second payload")
    sign_file(a)
    sign_file(b)
    assert read_signed(a, "buffer") == b"first payload"
    a.write_bytes(b"first payloaD")
    with pytest.raises(ValueError, match=r"buffer .*replay_1\.pkl does not match its signature"):
        read_signed(a, "buffer")
    (tmp_path / "replay_1.pkl.sig").unlink()
    with pytest.raises(ValueError, match="has no signature"):
        read_signed(a, "buffer")
    b.replace(a)  # a validly signed file under another name, with that name's old signature
    (tmp_path / "replay_2.pkl.sig").replace(tmp_path / "replay_1.pkl.sig")
    with pytest.raises(ValueError, match="does not match its signature"):
        read_signed(a, "buffer")


def test_the_signing_key_is_private_to_its_user(tmp_path, monkeypatch):
    """The key is made with mode 0600; a key others can read is refused."""
    import os
    import stat

    from mcpilco.models.files import signing_key

    key = tmp_path / "keys" / "file_key"
    monkeypatch.setenv("MCPILCO_KEY_FILE", str(key))
    assert len(signing_key()) == 32 and stat.S_IMODE(os.stat(key).st_mode) == 0o600
    assert signing_key() == signing_key()  # made once, then read
    os.chmod(key, 0o644)
    with pytest.raises(ValueError, match="readable or writable by others"):
        signing_key()
