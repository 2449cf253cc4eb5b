"""``make demo``'s script at a tiny budget: it runs MC-PILCO and prints the outcome and paths."""

from __future__ import annotations

import dataclasses

import torch

import mcpilco.scripts.demo as demo
from mcpilco.agents.mc_pilco import DEMO_CONFIG


def test_demo_prints_per_trial_outcome_and_output_paths(tmp_path, monkeypatch, capsys):
    tiny = dataclasses.replace(
        DEMO_CONFIG,
        num_trials=1,
        num_particles=8,
        opt=dataclasses.replace(DEMO_CONFIG.opt, max_steps=3),
        opt_steps_first=3,
        gp_adam_iters=5,
        gp_lbfgs_iters=0,
        log_particles=4,
    )
    monkeypatch.setattr(demo, "DEMO_CONFIG", tiny)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        assert demo.main(["--out", str(tmp_path / "demo")]) == 0
    finally:
        torch.set_num_threads(threads)
    out = capsys.readouterr().out
    assert "trial 0 (exploration): success" in out and "trial 1 (policy     ): success" in out
    assert "success (last trial):" in out and "wall time" in out
    assert f"checkpoint        : {tmp_path / 'demo'}" in out
    assert "run.rrd" in out and ".png" in out
    assert (tmp_path / "demo" / "checkpoint.pt").is_file()


def test_demo_refuses_a_gpu_it_cannot_see(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    try:
        demo.main(["--out", str(tmp_path / "demo"), "--device", "cuda"])
    except SystemExit as exc:
        assert exc.code == 2
    else:
        raise AssertionError("the demo started without a CUDA device")
    assert "sees no CUDA device" in capsys.readouterr().err
    assert not (tmp_path / "demo").exists()
