"""The demo's library parts (:mod:`mcpilco.experiments.mcpilco.demo`): its preset, when it
compiles the rollout, and how it reports the rollout mode."""

from __future__ import annotations

import dataclasses

import torch

from mcpilco.agents.mc_pilco import DEFAULT_ENV_ID, load_config
from mcpilco.experiments.mcpilco.demo import choose_compile, rollout_mode


def test_demo_preset_is_the_bench_budget_stopped_after_three_policy_trials():
    demo_cfg = load_config(DEFAULT_ENV_ID, preset="demo")
    bench = load_config(DEFAULT_ENV_ID, preset="bench")
    assert demo_cfg.num_trials == 3 and bench.num_trials == 4
    assert dataclasses.replace(demo_cfg, num_trials=4) == bench


def test_demo_compiles_the_rollout_on_the_cpu_only_when_it_can(monkeypatch):
    cpu = torch.device("cpu")
    assert choose_compile(cpu, eager=True) == (False, None)
    assert choose_compile(torch.device("cuda"), eager=False) == (False, None)
    monkeypatch.setenv("CXX", "no-such-c++")
    compiled, note = choose_compile(cpu, eager=False)
    assert not compiled and "no-such-c++ not found" in note and "runs the rollout eagerly" in note
    monkeypatch.setenv("CXX", "sh")  # any program on PATH counts as found
    assert choose_compile(cpu, eager=False) == (True, None)


def test_rollout_mode_reads_the_policy_trials_records():
    explore = {"kind": "exploration"}
    eager = {"kind": "policy", "compiled_step": False}
    native = {"kind": "policy", "compiled_step": True, "compile_backend": "native"}
    assert rollout_mode([explore, eager]) == "eager"
    two = [explore, {**native, "rollout_shards": 2}, {**native, "rollout_shards": 2}, eager]
    assert rollout_mode(two) == "compiled (native backend, 2 shards) in 2 of 3 policy trials"
    one = [explore, {**native, "rollout_shards": 1}]
    assert rollout_mode(one) == "compiled (native backend, 1 shard) in 1 of 1 policy trials"
