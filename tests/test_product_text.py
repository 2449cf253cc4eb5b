"""The tracked text speaks of the software, not of how it was made.

Every text file that git tracks (code, configs, docs, results) is scanned line by line for
phrases that belong to a development log: a numbered work period, an issue number, a
temporary path, a one-off script, or an absolute path of one machine or user. A hit is
reported as ``file:line`` with the phrase.

This file holds the patterns themselves and examples of bad lines, so it is not scanned; its
bad examples are written with a ``|`` inside the phrase (removed by :func:`_bad`), so that no
other search over the repository finds them either.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# suffixes of the text files scanned, and file names scanned whatever their suffix
TEXT_SUFFIXES = frozenset(
    {".py", ".md", ".yaml", ".yml", ".toml", ".txt", ".cpp", ".h", ".json", ".cfg"}
)
TEXT_NAMES = frozenset({"Makefile"})

# (what the phrase is, its pattern); each pattern is anchored on word boundaries so that
# ordinary words ("a session of training", "issues a warning", "tmp_path") pass, and none
# spans a line break
PATTERNS: tuple[tuple[str, re.Pattern[str]], ...] = (
    # a numbered work period: the word session (or sessions) followed by a number or #number
    ("numbered work period", re.compile(r"\bsessions?[ \t]+#?\d+", re.IGNORECASE)),
    # an issue number: the word issue (or issues) followed by a number or #number
    ("issue number", re.compile(r"\bissues?[ \t]*#?\d+", re.IGNORECASE)),
    # a temporary path of one machine: "/tmp/x", "/var/tmp/x" (not "tmp_path", "run/tmp/")
    ("temporary path", re.compile(r"(?<![\w.-])(?:/var)?/tmp/")),
    # a script or file written to be thrown away (the word, with or without a hyphen)
    ("one-off script", re.compile(r"\bthrow-?away\b", re.IGNORECASE)),
    # an absolute path of this machine's work tree
    ("machine path", re.compile(r"(?<![\w.~-])/work/")),
    # a user's home: "/home/alice", "/Users/bob", "/root/", "C:\\Users\\carol"
    (
        "home path",
        re.compile(r"(?<![\w.~-])(?:/home/[A-Za-z_]|/Users/|/root/)|\b[A-Za-z]:[\\/]+Users\b"),
    ),
)


def _bad(example: str) -> str:
    """A bad example line as written in this file, with its ``|`` removed."""
    return example.replace("|", "")


def scan_text(text: str) -> list[tuple[int, str, str]]:
    """``(line number, kind, phrase)`` of every match in ``text`` (lines numbered from 1),
    in line order."""
    hits = [
        (text.count("\n", 0, match.start()) + 1, kind, match.group(0))
        for kind, pattern in PATTERNS
        for match in pattern.finditer(text)
    ]
    return sorted(hits, key=lambda hit: hit[0])


def scan_line(line: str) -> list[tuple[str, str]]:
    """``(kind, phrase)`` of every match in one line."""
    return [(kind, phrase) for _, kind, phrase in scan_text(line)]


def is_text_file(path: str) -> bool:
    """Whether a tracked path is one of the scanned text files."""
    name = Path(path)
    return name.suffix in TEXT_SUFFIXES or name.name in TEXT_NAMES


def tracked_files(root: Path) -> list[str]:
    """The files git tracks under ``root`` (relative paths); skips outside a git checkout."""
    git = shutil.which("git")
    if git is None:
        pytest.skip("git is not installed")
    try:
        done = subprocess.run(
            [git, "ls-files", "-z"], cwd=root, capture_output=True, check=False, timeout=60
        )
    except (OSError, subprocess.TimeoutExpired) as err:
        pytest.skip(f"git ls-files failed: {err}")
    if done.returncode != 0 or not done.stdout:
        pytest.skip(f"{root} is not a git checkout")
    return [p for p in done.stdout.decode("utf-8", "replace").split("\0") if p]


def test_tracked_text_has_no_development_history():
    own = Path(__file__).resolve().relative_to(ROOT).as_posix()
    report = []
    for path in tracked_files(ROOT):
        if path == own or not is_text_file(path):
            continue
        file = ROOT / path
        if not file.is_file():  # deleted in the work tree, not yet in the index
            continue
        text = file.read_text(encoding="utf-8", errors="replace")
        report += [f"{path}:{n}: {kind} {phrase!r}" for n, kind, phrase in scan_text(text)]
    assert not report, f"{len(report)} development-history phrases:\n" + "\n".join(report)


@pytest.mark.parametrize(
    ("line", "kind"),
    [
        ("# tuned in sess|ion 12", "numbered work period"),
        ("Sess|ion 3 measured this", "numbered work period"),
        ("see iss|ue 4 for the plan", "issue number"),
        ("closes Iss|ue #12", "issue number"),
        ("written to /tmp/run1 first", "temporary path"),
        ('out = "/var/tmp/x.json"', "temporary path"),
        ("a throw|away script made it", "one-off script"),
        ("cd /work/wt-x && make", "machine path"),
        ("data in /home/alice/runs", "home path"),
        ("open('/Users/bob/data.csv')", "home path"),
        ("see /root/.cache", "home path"),
        (r"C:\Users\carol\robot.csv", "home path"),
    ],
)
def test_scanner_catches_history(line, kind):
    assert kind in [k for k, _ in scan_line(_bad(line))]


@pytest.mark.parametrize(
    "line",
    [
        '@pytest.fixture(scope="session")',
        "a session of training on the cart-pole",
        "the call issues a warning and goes on",
        "issues are raised as ValueError",
        "def test_save(tmp_path): ...",
        "out = tmp_path / 'tmp' / 'run'",
        "written to runs/tmp/records.json",
        "the worker's homework/ and network/work/ folders",
        "https://github.com/DLR-RM/rl-baselines3-zoo",
        "~/.cache/torch_extensions",
        "the thesis (2021), eq. 5.8, seed 0",
    ],
)
def test_scanner_passes_ordinary_text(line):
    assert scan_line(line) == []


def test_scan_text_numbers_lines_and_no_match_spans_two():
    text = _bad("first line\nsee iss|ue 7\nthe session\n12 steps, /tmp/a\n")
    assert scan_text(text) == [
        (2, "issue number", _bad("iss|ue 7")),
        (4, "temporary path", "/tmp/"),
    ]
