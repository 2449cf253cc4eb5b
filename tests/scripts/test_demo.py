"""``make demo``'s script at a tiny budget: it runs MC-PILCO (the rollout compiled on the CPU)
and prints the outcome, how the rollout ran and the paths."""

from __future__ import annotations

import dataclasses

import torch

import mcpilco.scripts.demo as demo
from mcpilco.agents.mc_pilco import DEFAULT_ENV_ID, load_config


def test_demo_prints_per_trial_outcome_and_output_paths(tmp_path, monkeypatch, capsys):
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

    monkeypatch.setattr(demo, "load_config", tiny_config)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        assert demo.main(["--out", str(tmp_path / "demo")]) == 0
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


def test_demo_preset_is_the_bench_budget_stopped_after_three_policy_trials():
    demo_cfg = load_config(DEFAULT_ENV_ID, preset="demo")
    bench = load_config(DEFAULT_ENV_ID, preset="bench")
    assert demo_cfg.num_trials == 3 and bench.num_trials == 4
    assert dataclasses.replace(demo_cfg, num_trials=4) == bench


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


def test_demo_compiles_the_rollout_on_the_cpu_only_when_it_can(monkeypatch):
    cpu = torch.device("cpu")
    assert demo.choose_compile(cpu, eager=True) == (False, None)
    assert demo.choose_compile(torch.device("cuda"), eager=False) == (False, None)
    monkeypatch.setenv("CXX", "no-such-c++")
    compiled, note = demo.choose_compile(cpu, eager=False)
    assert not compiled and "no-such-c++ not found" in note and "runs the rollout eagerly" in note
    monkeypatch.setenv("CXX", "sh")  # any program on PATH counts as found
    assert demo.choose_compile(cpu, eager=False) == (True, None)


def test_rollout_mode_reads_the_policy_trials_records():
    explore = {"kind": "exploration"}
    eager = {"kind": "policy", "compiled_step": False}
    direct = {"kind": "policy", "compiled_step": True, "compile_backend": "direct"}
    assert demo.rollout_mode([explore, eager]) == "eager"
    two = [explore, {**direct, "rollout_shards": 2}, {**direct, "rollout_shards": 2}, eager]
    assert demo.rollout_mode(two) == "compiled (direct backend, 2 shards) in 2 of 3 policy trials"
    one = [explore, {**direct, "rollout_shards": 1}]
    assert demo.rollout_mode(one) == "compiled (direct backend, 1 shard) in 1 of 1 policy trials"
