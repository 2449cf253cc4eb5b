"""The robustness benchmark's parts: outcome of a command, a refused command, fuzzed inputs,
the tables."""

from __future__ import annotations

import sys

import pytest

from mcpilco.experiments.infra.robustness import (
    OUTCOMES,
    TRAIN_ARGS,
    classify_exit,
    command_line,
    fuzz_counts,
    markdown,
    outcome_lines,
    run_case,
)


@pytest.mark.parametrize(
    ("code", "stderr", "outcome", "message"),
    [
        (2, "usage: x\nprog: error: bad --seed\n", "clear error", "prog: error: bad --seed"),
        (2, "Traceback (most recent call last):\nValueError: x", "crash", "exit 2: ValueError: x"),
        (2, "", "crash", "exit 2: "),
        (0, "", "silent wrong", "exit 0"),
        (1, "boom\n", "crash", "exit 1: boom"),
    ],
)
def test_exit_status_and_stderr_give_the_outcome(code, stderr, outcome, message):
    assert classify_exit(code, stderr) == (outcome, message)


def test_a_command_runs_by_its_console_name_with_this_interpreter():
    assert command_line("mcpilco-train")[:2] == [sys.executable, "-m"]
    with pytest.raises(LookupError, match="no console script 'mcpilco-nope'"):
        command_line("mcpilco-nope")


def test_a_refused_argument_is_a_clear_error(tmp_path):
    outcome, message = run_case("mcpilco-train", ["--seed", "-1", *TRAIN_ARGS])
    assert outcome == "clear error" and "--seed" in message


def test_fuzzed_inputs_are_counted_by_kind_and_outcome():
    rows = fuzz_counts(seed=0, n=6)
    assert [r["kind"] for r in rows] == ["GP core", "loader", "file bytes"]
    for r in rows:
        counts = {k: v for k, v in r.items() if k not in ("kind", "inputs")}
        assert set(counts) <= set(OUTCOMES) and r["inputs"] == sum(counts.values()) == 6
        assert counts.get("crash", 0) == 0 and counts.get("silent wrong", 0) == 0
    assert rows == fuzz_counts(seed=0, n=6)  # the seed fixes the inputs


def test_tables_count_cases_per_tool_and_kind():
    result = {
        "cases": [
            {"tool": "train", "kind": "argument", "input": "--seed -1", "outcome": "clear error"}
            | {"message": "mcpilco-train: error: a|b"},
            {"tool": "train", "kind": "argument", "input": "--trials -2", "outcome": "crash"}
            | {"message": "exit 1"},
        ],
        "fuzz": [{"kind": "loader", "inputs": 3, "clear error": 2, "result": 1}],
        "kills": [
            {
                "kill_after_s": 3.0,
                "trials_finished_before_kill": 1,
                "trials_kept": 1,
                "finished_trials_lost": 0,
                "continued_with": "--resume",
                "continued_exit": 0,
                "run_completed": True,
            }
        ],
    }
    md = markdown(result)
    assert "| train | argument | 2 | 0 | 1 | 1 | 0 |" in md
    assert "| fuzz | loader | 3 | 1 | 2 | 0 | 0 |" in md
    assert "| train: --seed -1 | clear error | mcpilco-train: error: a\\|b |" in md
    assert "| 3 s | 1 | 1 | 0 | --resume | yes |" in md
    assert "train\targument\tclear error\t1" in outcome_lines(result)
