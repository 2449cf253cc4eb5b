"""``mcpilco-demo`` (``make demo``) at a tiny budget: it runs MC-PILCO (the rollout compiled on
the CPU) and prints the outcome, how the rollout ran and the paths."""

from __future__ import annotations

import dataclasses

import torch

import mcpilco.experiments.mcpilco.demo as cartpole_demo
from mcpilco.agents.mc_pilco import DEFAULT_ENV_ID, load_config


def test_demo_prints_per_trial_outcome_and_output_paths(command, tmp_path, monkeypatch, capsys):
    asked = []

    def tiny_config(env_id, *args, **kwargs):  # the demo preset at a tiny budget
        asked.append((env_id, kwargs.get("preset")))
        cfg = load_config(env_id, *args, **kwargs)
        return dataclasses.replace(
            cfg,
            num_trials=1,
            num_particles=8,
            opt=dataclasses.replace(cfg.opt, max_steps=3),
            opt_steps_first=3,
            gp_adam_iters=5,
            gp_lbfgs_iters=0,
            log_particles=4,
        )

    monkeypatch.setattr(cartpole_demo, "load_config", tiny_config)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        assert command("mcpilco-demo", ["--out", str(tmp_path / "demo")]) == 0
    finally:
        torch.set_num_threads(threads)
    out = capsys.readouterr().out
    assert "trial 0 (exploration): success" in out and "trial 1 (policy     ): success" in out
    # the default on the CPU: the time step compiled (here 1 thread, so 1 shard) and checked
    assert "rollout           : compiled (native backend, 1 shard) in 1 of 1 policy trials" in out
    assert "success (last trial):" in out and "wall time" in out
    assert f"checkpoint        : {tmp_path / 'demo'}" in out
    assert "run.rrd" in out and ".png" in out
    assert (tmp_path / "demo" / "checkpoint.pt").is_file()
    assert asked == [(DEFAULT_ENV_ID, "demo")]


def test_demo_refuses_a_gpu_it_cannot_see(command, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert command("mcpilco-demo", ["--out", str(tmp_path / "demo"), "--device", "cuda"]) == 2
    assert "sees no CUDA device" in capsys.readouterr().err
    assert not (tmp_path / "demo").exists()
