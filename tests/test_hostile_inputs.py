"""Hostile inputs of every entry point, by threat class: each must be refused in one line that
names the field or file, with exit status 2, within its time limit, and with no file outside
the run folder touched (:mod:`mcpilco.experiments.infra.hostile_inputs`).

The cases that refuse before any env, model or run is built run in the default suite; those
that build one first (crafted checkpoints, detector estimators, degree checks) are slow.
"""

from __future__ import annotations

import ast
import collections
import time
from pathlib import Path

import pytest

from mcpilco.experiments.infra.hostile_inputs import (
    EXAMPLE,
    OUTCOMES,
    THREATS,
    HostileCase,
    hostile_cases,
    run_case,
)

CASES = hostile_cases()
FAST_LIMIT_S = 30.0  # seconds a default-suite case may take before it counts as a hang
ENTRIES = (
    "mcpilco-train",
    "mcpilco-diagnose",
    "mcpilco-detect-collisions",
    "mcpilco-bench-collision",
    "mcpilco-compare",
)  # the console scripts that read files or values from a user


def _param(case: HostileCase):
    marks = [pytest.mark.slow] if case.slow else []
    return pytest.param(case, id=f"{case.threat}: {case.id}", marks=marks)


@pytest.mark.parametrize("case", [_param(c) for c in CASES])
def test_hostile_input_is_refused_in_one_line(case, tmp_path):
    result = run_case(case, tmp_path, limit_s=FAST_LIMIT_S if not case.slow else 300.0)
    assert result["outcome"] == "refused", result
    assert result["message"].count("error:") == 1 and len(result["message"]) < 700, result


def test_the_cases_cover_every_class_and_entry_point():
    by_threat = collections.Counter(c.threat for c in CASES)
    assert set(by_threat) == set(THREATS) and min(by_threat.values()) >= 5, by_threat
    assert {c.entry for c in CASES} == set(ENTRIES)
    assert len(CASES) >= 150 and len({c.id for c in CASES}) == len(CASES)
    assert sum(not c.slow for c in CASES) >= 100


def test_the_classifier_sees_a_hole_a_hang_and_a_silent_answer(tmp_path):
    """The outcomes are not all "refused" by construction: a command that writes outside its
    folder, one that runs past its limit and one that accepts are classified as such."""

    def write_outside(w: Path, o: Path) -> list[str]:
        (o / "victim.txt").write_text("changed")
        return ["--help"]

    cases = {
        "hole": HostileCase("writes outside the folder", "mcpilco-compare", "x", write_outside),
        "silent wrong answer": HostileCase(
            "silent wrong answer", "mcpilco-compare", "y", lambda w, o: ["--help"]
        ),
    }
    for k, (want, case) in enumerate(cases.items()):
        assert run_case(case, tmp_path / str(k))["outcome"] == want
    assert OUTCOMES[0] == "refused"
    slow = HostileCase("hang", "mcpilco-train", "z", lambda w, o: [])
    result = run_case(slow, tmp_path / "hang", limit_s=0.5, main=lambda argv: time.sleep(5))
    assert result["outcome"] == "hang" and result["seconds"] < 2.0


def test_a_relative_include_next_to_the_model_is_read(tmp_path):
    from mcpilco.models.diagnosis import NominalStart

    source = (EXAMPLE / "robot.xml").read_text()
    start, end = source.index("<worldbody>"), source.index("</worldbody>") + len("</worldbody>")
    (tmp_path / "body.xml").write_text("<mujoco>" + source[start:end] + "</mujoco>")
    main = tmp_path / "main.xml"
    main.write_text(source[:start] + '<include file="body.xml"/>' + source[end:])
    with_include = NominalStart(main)
    plain = NominalStart(EXAMPLE / "robot.xml")
    assert with_include.joint_types == plain.joint_types
    assert "<include" not in with_include.robot.text


def test_an_include_root_allows_a_folder_above_the_model(tmp_path):
    from mcpilco.models.robot_files import read_robot_file

    (tmp_path / "shared.xml").write_text('<mujoco><option timestep="0.004"/></mujoco>')
    (tmp_path / "robot").mkdir()
    model = tmp_path / "robot" / "robot.xml"
    model.write_text('<mujoco><include file="../shared.xml"/><worldbody/></mujoco>')
    with pytest.raises(ValueError, match="--include-root"):
        read_robot_file(model)
    assert 'timestep="0.004"' in read_robot_file(model, include_root=tmp_path)


def test_no_module_of_the_package_unpickles():
    """Only ``torch.load(weights_only=True)`` reads pickled data: no ``pickle.load(s)``, no
    ``torch.load`` without ``weights_only=True`` anywhere in the package."""
    root = Path(__file__).resolve().parents[1]
    found = []
    for folder in ("agents", "envs", "experiments", "models", "scripts"):
        for path in (root / folder).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                if not isinstance(node, ast.Call) or not isinstance(node.func, ast.Attribute):
                    continue
                owner = getattr(node.func.value, "id", "")
                name = node.func.attr
                if owner in ("pickle", "cPickle", "dill", "joblib") and name in ("load", "loads"):
                    found.append(f"{path.name}:{node.lineno}")
                if owner == "torch" and name == "load":
                    safe = any(
                        k.arg == "weights_only" and getattr(k.value, "value", None) is True
                        for k in node.keywords
                    )
                    if not safe:
                        found.append(f"{path.name}:{node.lineno}")
    assert not found, found
