"""The console scripts' error policy: one line, exit 2, traceback only with --debug."""

from __future__ import annotations

import subprocess
import sys

import pytest

from mcpilco.agents.common.cli import console_main


def _main_raising(err: BaseException):
    @console_main("prog")
    def main(argv=None) -> int:
        raise err

    return main


@pytest.mark.parametrize(
    "err",
    [
        ValueError("bad value\nsecond line"),
        FileNotFoundError(2, "No such file or directory", "data.csv"),
        IsADirectoryError(21, "Is a directory", "robot.xml"),
        EOFError(),
        SystemExit("--frames must be >= 24"),
    ],
)
def test_user_errors_are_one_line_and_exit_2(err, capsys):
    if isinstance(err, SystemExit):
        with pytest.raises(SystemExit) as stop:
            _main_raising(err)([])
        assert stop.value.code == 2
    else:
        assert _main_raising(err)([]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("prog: error: ")
    if isinstance(err, OSError):
        assert err.filename in lines[0]


def test_debug_shows_the_traceback_and_bugs_keep_theirs():
    with pytest.raises(ValueError, match="bad"):
        _main_raising(ValueError("bad"))(["--debug"])
    with pytest.raises(RuntimeError):
        _main_raising(RuntimeError("a bug"))([])


def test_debug_flag_is_removed_before_the_script_parses(capsys):
    seen = []

    @console_main("prog")
    def main(argv=None) -> int:
        seen.append(list(argv))
        return 0

    assert main(["--x", "--debug", "1"]) == 0 and seen == [["--x", "1"]]


def test_installed_script_reports_out_being_a_file_in_one_line(tmp_path):
    out = tmp_path / "a_file"
    out.write_text("x")
    done = subprocess.run(
        [sys.executable, "-m", "mcpilco.scripts.train_mcpilco", "--out", str(out), "--trials", "0"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and str(out) in lines[0] and "Traceback" not in done.stderr


def test_negative_seed_is_an_argument_error(capsys, command):
    code = command("mcpilco-train", ["--seed", "-1"])
    assert code == 2 and "--seed" in capsys.readouterr().err
