"""run_diagnosis, the diagnosis loop on files, its HTML report, and the saved model versions."""

import html

import numpy as np
import pytest

from mcpilco.experiments.diagnosis.hidden_effects import make_case, write_case
from mcpilco.models.diagnosis import run_diagnosis
from tests.models.diagnosis.test_html_report import external_references


@pytest.fixture(scope="module")
def case_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("hidden")
    write_case(make_case("scara", ["viscous:1"], seed=3, duration=8.0), out)
    return out


@pytest.fixture(scope="module")
def run(case_dir, tmp_path_factory):
    """One run of the loop on the case, shared by the tests of its outputs."""
    out = tmp_path_factory.mktemp("run") / "run"
    lines: list[str] = []
    summary = run_diagnosis(
        [case_dir / "train_1.csv", case_dir / "train_2.csv"],
        [case_dir / "test_1.csv"],
        model=case_dir / "robot.xml",
        add=["viscous:1"],
        out=out,
        plots=False,
        rerun=False,
        log=lines.append,
    )
    return out, summary, lines


def test_run_diagnosis_reports_through_log_and_returns_the_summary(run):
    out, summary, lines = run
    assert any("== 3. which effect is missing" in line for line in lines)
    assert (out / "summary.json").is_file()
    assert summary["artefacts"] == {} and len(summary["versions"]) == 2
    rmse = np.array(summary["heldout_rmse"])
    assert rmse[1, 0] < 0.5 * rmse[0, 0]


def test_run_diagnosis_writes_one_self_contained_html_report(run):
    out, summary, _ = run
    path = out / "report.html"
    assert summary["report"] == str(path) and path.is_file()
    text = path.read_text(encoding="utf-8")
    assert text.startswith("<!DOCTYPE html>") and text.rstrip().endswith("</html>")
    assert external_references(text) == []
    assert html.escape(summary["verdict"]) in text
    for version in summary["versions"]:  # the fit table has a row per version
        assert f"<td>{html.escape(version)}</td>" in text
    rmse = np.array(summary["heldout_rmse"])
    assert f'<td class="num">{rmse[1, 0]:.4g}</td>' in text
    for c in summary["diagnoses"]["v0"]["candidates"]:  # the candidate table, every row
        assert f"<td>{html.escape(c['effect'])}</td>" in text
    assert "<td>F_v</td>" in text  # the chosen effect's parameter
    # the viscous term written back as the joint's damping, with its interval and the
    # file's value it replaced
    written = summary["robot_file"]["written"]
    assert [(c["attribute"], c["effect"]) for c in written] == [("damping", "viscous:1")]
    assert f"<td>{html.escape(written[0]['element'])} damping</td>" in text
    assert f'<td class="num">{written[0]["after"]:.4g}</td>' in text


def test_run_diagnosis_needs_a_start_model(case_dir, tmp_path):
    with pytest.raises(ValueError, match="give a start model"):
        run_diagnosis([case_dir / "train_1.csv"], out=tmp_path, log=lambda _: None)
    with pytest.raises(ValueError, match="learned start must be one of"):
        run_diagnosis(
            [case_dir / "train_1.csv"], learned=("nn", "RRPR"), out=tmp_path, log=lambda _: None
        )


def test_saved_versions_are_never_overwritten(case_dir, tmp_path):
    from mcpilco.models.diagnosis import DiagnosisModel, NominalStart, load_trajectories

    train = load_trajectories([case_dir / "train_1.csv"])
    model = DiagnosisModel(NominalStart(case_dir / "robot.xml")).fit(train)
    first, second = model.save(tmp_path), model.save(tmp_path)
    assert first.name == "model_v0.json" and second.name == "model_v0-2.json"
    again = DiagnosisModel.load(first).fit(train)
    np.testing.assert_allclose(again.log_evidence_, model.log_evidence_)
