"""mcpilco-diagnose end to end on a tiny generated case, and its bad-input errors."""

import base64
import json
import re

import numpy as np
import pandas as pd
import pytest

from mcpilco.experiments.diagnosis.hidden_effects import make_case, write_case


@pytest.fixture(scope="module")
def case_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("hidden")
    write_case(make_case("scara", ["viscous:1"], seed=3, duration=8.0), out)
    return out


def test_cli_loop_writes_versions_plots_and_recording(case_dir, tmp_path, capsys, command):
    out = tmp_path / "run"
    argv = [
        "--model",
        str(case_dir / "robot.xml"),
        "--train",
        str(case_dir / "train_1.csv"),
        str(case_dir / "train_2.csv"),
        "--test",
        str(case_dir / "test_1.csv"),
        "--add",
        "viscous:1",
        "--out",
        str(out),
    ]
    assert command("mcpilco-diagnose", argv) == 0
    text = capsys.readouterr().out
    assert "SIGNIFICANT" in text and "viscous:1" in text
    for name in (
        "compare_v0.png",
        "compare_v1.png",
        "residuals_v0.png",
        "waterfall.png",
        "diagnosis.rrd",
        "models/model_v0.json",
        "models/model_v1.json",
        "corrected.xml",
        "corrected_effects.json",
        "refined.xml",
    ):
        assert (out / name).exists(), name
    summary = json.loads((out / "summary.json").read_text())
    rmse = np.array(summary["heldout_rmse"])
    assert rmse[1, 0] < 0.5 * rmse[0, 0]
    # the report carries every figure of the run inside itself, byte for byte
    report = (out / "report.html").read_text(encoding="utf-8")
    embedded = {
        base64.b64decode(b) for b in re.findall(r'src="data:image/png;base64,([^"]*)"', report)
    }
    assert {p.read_bytes() for p in out.glob("*.png")} == embedded


def _bad(case_dir, tmp_path, edit):
    df = pd.read_csv(case_dir / "train_1.csv")
    df = edit(df)
    path = tmp_path / "bad.csv"
    df.to_csv(path, index=False)
    return path


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda df: df.drop(columns=["tau2"]), "missing column 'tau2'"),
        (lambda df: df.rename(columns={"q3": "pos3"}), "missing column 'q3'"),
        (lambda df: df.assign(qd1=df["qd1"].where(df.index != 17)), "row 17"),
        (lambda df: df.assign(t=df["t"].where(df.index != 40, 0.0)), "not strictly increasing"),
        (lambda df: df.drop(columns=["q4", "qd4", "qdd4", "tau4"]), "joint count mismatch"),
    ],
)
def test_bad_input_gives_clear_error(case_dir, tmp_path, capsys, command, edit, message):
    bad = _bad(case_dir, tmp_path, edit)
    argv = ["--model", str(case_dir / "robot.xml"), "--train", str(bad), "--out", str(tmp_path)]
    assert command("mcpilco-diagnose", argv) == 2
    err = capsys.readouterr().err
    assert message in err, err


def test_joint_count_of_model_file_is_named(case_dir, tmp_path, capsys, command):
    from mcpilco.envs.arm_builder import arm_to_xml
    from mcpilco.envs.arms import ur10

    xml = tmp_path / "ur10.xml"
    xml.write_text(arm_to_xml(ur10(), friction=False))
    argv = ["--model", str(xml), "--train", str(case_dir / "train_1.csv"), "--out", str(tmp_path)]
    assert command("mcpilco-diagnose", argv) == 2
    err = capsys.readouterr().err
    assert "4 joints" in err and "6" in err, err


def test_shipped_example_finds_its_hidden_effect(tmp_path, command):
    """The README walk-through: the shipped SCARA example's hidden effect (truth.json) is
    added by --auto, and the held-out error of its joint falls to the noise level."""
    from importlib.resources import files

    ex = files("mcpilco.models.diagnosis") / "examples" / "scara_coulomb2"
    truth = json.loads((ex / "truth.json").read_text())
    out = tmp_path / "run"
    argv = ["--model", str(ex / "robot.xml"), "--train"]
    argv += [str(ex / "train_1.parquet"), str(ex / "train_2.parquet")]
    argv += ["--test", str(ex / "test_1.parquet"), "--auto", "2", "--out", str(out)]
    assert command("mcpilco-diagnose", [*argv, "--no-plots", "--no-rerun"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    (label,) = truth["labels"]
    assert len(summary["versions"]) == 2 and label in summary["versions"][1]
    j = truth["effects"][0]["joint"] - 1
    rmse = np.array(summary["heldout_rmse"])
    assert rmse[-1, j] <= 1.5 * truth["noise_std"][j] < rmse[0, j]
