"""A tiny run of the inverse-dynamics benchmark writes its JSON, PNGs and Markdown."""

from __future__ import annotations

import json

import numpy as np
import torch

from mcpilco.experiments.identification.inverse_dynamics import ESTIMATORS
from mcpilco.experiments.results import read_result


def test_tiny_benchmark_writes_outputs(tmp_path, command) -> None:
    threads = torch.get_num_threads()
    argv = [
        "--parts", "scara,efficiency,ur10,timing",
        "--runs", "2", "--n-train", "200", "--n-test", "100", "--n-sinusoids", "20",
        "--adam-iters", "3", "--lbfgs-iters", "0", "--hyper-points", "60",
        "--nn-hidden", "16", "--nn-epochs", "3", "--ur10-nn-hidden", "16",
        "--sizes", "30,60", "--efficiency-estimators", "GIP,PP",
        "--ur10-train", "300", "--ur10-subset", "100", "--ur10-test-exploration", "100",
        "--no-ur10-circle", "--ur10-estimators", "FE,GIP,NN",
        "--timing-n", "60", "--timing-adam-iters", "1", "--timing-lbfgs-iters", "0",
        "--out-dir", str(tmp_path), "--runs-dir", str(tmp_path / "runs"), "--no-progress",
    ]  # fmt: skip
    try:
        assert command("mcpilco-bench-inverse-dynamics", argv) == 0
    finally:
        torch.set_num_threads(threads)
    res = read_result(tmp_path / "inverse_dynamics.json").payload()
    scara = res["scara"]
    assert set(scara["nmse"]) == set(ESTIMATORS)
    assert np.asarray(scara["nmse"]["GIP"]).shape == (2, 4)
    assert np.all(np.isfinite(np.asarray(scara["nmse"]["FE"])))
    # one result file per Monte Carlo run, holding what the table shows
    run1 = json.loads((tmp_path / "runs" / "scara" / "run1.json").read_text())["result"]
    assert run1["nmse"]["GIP"] == scara["nmse"]["GIP"][1]
    assert res["efficiency"]["sizes"] == [30, 60]
    assert len(res["efficiency"]["gmse"]["GIP"]) == 2
    assert len(res["ur10"]["noise_floor"]) == 6 and res["ur10"]["n_gp"] == 100
    assert res["timing"]["n"] == 60 and res["timing"]["cholesky_seconds"] > 0
    assert res["timing"]["gram_forward_backward_seconds"]["ratio"] > 0
    for name in ("scara_nmse", "efficiency", "ur10_nmse"):
        assert (tmp_path / f"inverse_dynamics_{name}.png").stat().st_size > 1000
    md = (tmp_path / "inverse_dynamics.md").read_text()
    assert "| GIP |" in md and "Cholesky" in md
