"""run_diagnosis, the diagnosis loop on files, and the saved model versions."""

import numpy as np
import pytest

from mcpilco.experiments.hidden_effects import make_case, write_case
from mcpilco.models.diagnosis import run_diagnosis


@pytest.fixture(scope="module")
def case_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("hidden")
    write_case(make_case("scara", ["viscous:1"], seed=3, duration=8.0), out)
    return out


def test_run_diagnosis_reports_through_log_and_returns_the_summary(case_dir, tmp_path):
    lines: list[str] = []
    summary = run_diagnosis(
        [case_dir / "train_1.csv", case_dir / "train_2.csv"],
        [case_dir / "test_1.csv"],
        model=case_dir / "robot.xml",
        add=["viscous:1"],
        out=tmp_path / "run",
        plots=False,
        rerun=False,
        log=lines.append,
    )
    assert any("== 3. which effect is missing" in line for line in lines)
    assert (tmp_path / "run" / "summary.json").is_file()
    assert summary["artefacts"] == {} and len(summary["versions"]) == 2
    rmse = np.array(summary["heldout_rmse"])
    assert rmse[1, 0] < 0.5 * rmse[0, 0]


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
