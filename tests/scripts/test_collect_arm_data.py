"""``mcpilco-collect-arm-data``: a tiny run writes a readable file with the documented columns."""

from __future__ import annotations

import numpy as np
import pandas as pd

from mcpilco.models.robot_data import column_names, load_dataset


def test_tiny_scara_run_writes_the_documented_columns(command, tmp_path) -> None:
    out = tmp_path / "scara.csv"
    argv = ["--robot", "scara", "--program", "exploration", "--duration", "0.4", "--seed", "1"]
    assert command("mcpilco-collect-arm-data", [*argv, "--out", str(out)]) == 0
    raw = pd.read_csv(out)
    assert list(raw.columns[: len(column_names(4))]) == column_names(4)
    ds = load_dataset(out, n_joints=4)
    assert ds.n_samples == 51 and ds.metadata["robot"] == "scara"
    np.testing.assert_allclose(np.diff(ds.t), 0.008, atol=1e-9)
    assert ds.metadata["joint_types"] == "RRPR"


def test_tiny_ur10_run_to_parquet(command, tmp_path) -> None:
    out = tmp_path / "ur10.parquet"
    argv = ["--program", "sinusoids", "--duration", "0.2", "--out", str(out)]
    assert command("mcpilco-collect-arm-data", argv) == 0
    ds = load_dataset(out, n_joints=6)
    assert ds.n_samples == 26 and ds.i is not None and ds.i_cmd is not None
