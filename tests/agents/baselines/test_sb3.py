"""Tiny-budget smoke runs of SAC, TD3 and PPO through the run of one method and seed that
``mcpilco-compare`` makes (:func:`mcpilco.agents.baselines.compare.run_method`).

300 env steps, an evaluation every 150 steps on 2 episodes; the zoo hyper-parameters are
shrunk (``learning_starts``, ``n_steps``) so that every algorithm also trains.
"""

from __future__ import annotations

import json

import pytest
from stable_baselines3.common.save_util import load_from_pkl

from mcpilco.agents.baselines.compare import run_method

ENV = "mcpilco/CartpoleSwingUp-v0"
DMC_ENV = "mcpilco/DMCCartpoleSwingUp-v0"
TINY = {
    "sac": {"learning_starts": 100, "batch_size": 64, "policy_kwargs": {"net_arch": [32, 32]}},
    "td3": {"learning_starts": 100, "batch_size": 64, "policy_kwargs": {"net_arch": [32, 32]}},
    "ppo": {"n_envs": 2, "n_steps": 75, "batch_size": 50, "n_epochs": 2},  # 150 per update
}


def _opts(algo: str, steps: int) -> dict:
    return {
        "steps": {algo: steps},
        "eval_every": 150,
        "eval_episodes": 2,
        "sb3_hp": {algo: TINY[algo]},
        "threads": 1,
        "progress": False,
        "log": False,
    }


@pytest.mark.parametrize(
    ("algo", "env_id"), [("sac", ENV), ("td3", ENV), ("ppo", ENV), ("sac", DMC_ENV)]
)
def test_smoke_run_records_success_vs_experience(algo, env_id, tmp_path):
    curve = run_method(algo, env_id, 0, tmp_path, _opts(algo, 300))
    assert curve["method"] == algo and curve["env_id"] == env_id and curve["complete"]
    assert curve["budget_steps"] == 300 and curve["steps_done"] >= 300
    pts = curve["points"]
    assert [p["steps"] for p in pts] == [150, 300]
    # experience = env steps x control period 0.05 s
    assert [p["experience_s"] for p in pts] == pytest.approx([7.5, 15.0])
    assert all(p["episodes"] == 2 and p["success_rate"] in (0.0, 0.5, 1.0) for p in pts)
    # a near-random policy never swings the pole up: the env cost stays near 60 per episode
    assert all(50.0 < p["mean_cost"] <= 60.0 for p in pts)
    # seconds within the task's success bounds, at most the 3 s episode
    assert all(0.0 <= p["time_in_goal_s"] <= 3.0 for p in pts)
    ckpt = curve["checkpoint"]
    assert (tmp_path / ckpt["model"]).is_file()
    if algo == "ppo":  # the swing-up zoo preset normalises observations and rewards
        assert (tmp_path / ckpt["vecnormalize"]).is_file()
    else:
        buffer = load_from_pkl(tmp_path / ckpt["replay"])
        assert buffer.size() == ckpt["steps"]  # every transition collected is in the buffer
    assert json.loads((tmp_path / "curve.json").read_text()) == curve


def test_resume_continues_from_the_checkpoint(tmp_path):
    first = run_method("sac", ENV, 1, tmp_path, _opts("sac", 300))
    second = run_method("sac", ENV, 1, tmp_path, _opts("sac", 450))
    assert [p["steps"] for p in second["points"]] == [150, 300, 450]
    assert second["points"][:2] == first["points"]
    assert second["steps_done"] >= 450 and second["cpu_s"] > first["cpu_s"]
    buffer = load_from_pkl(tmp_path / second["checkpoint"]["replay"])
    assert buffer.size() == second["checkpoint"]["steps"]  # old transitions kept
    assert sorted(p.name for p in tmp_path.glob("model_*.zip")) == [second["checkpoint"]["model"]]


def test_a_run_killed_after_its_last_checkpoint_completes_without_training(tmp_path):
    """A run stopped after the checkpoint at its budget (curve not marked complete) resumes
    with no step left: it completes with the same points and no new step."""
    first = run_method("sac", ENV, 2, tmp_path, _opts("sac", 300))
    curve = json.loads((tmp_path / "curve.json").read_text())
    (tmp_path / "curve.json").write_text(json.dumps({**curve, "complete": False}))
    second = run_method("sac", ENV, 2, tmp_path, _opts("sac", 300))
    assert second["complete"] and second["points"] == first["points"]
    assert second["steps_done"] == first["steps_done"]  # 304: the preset trains every 8 steps


def test_resume_refuses_a_changed_evaluation_period(tmp_path):
    run_method("td3", ENV, 0, tmp_path, _opts("td3", 300))
    opts = _opts("td3", 450)
    opts["eval_every"] = 100
    with pytest.raises(ValueError, match="cannot resume: eval_every=100"):
        run_method("td3", ENV, 0, tmp_path, opts)


def test_unknown_method_is_an_error(tmp_path):
    with pytest.raises(ValueError, match="valid methods: mcpilco, pilco, sac, td3, ppo"):
        run_method("a2c", ENV, 0, tmp_path, {})


def test_config_round_trips_through_to_dict_and_from_dict():
    """A saved SB3 config (curve.json's) reads back as it was; an unknown field is named."""
    from mcpilco.agents.baselines.sb3 import SB3Config

    for cfg in (SB3Config("sac"), SB3Config("ppo", steps=5_000, overrides={"n_steps": 64})):
        assert SB3Config.from_dict(cfg.to_dict()) == cfg
        assert SB3Config.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
    with pytest.raises(ValueError, match=r"unknown SB3 config fields \['colour'\]"):
        SB3Config.from_dict({**SB3Config("td3").to_dict(), "colour": "red"})


class _Payload:
    """Unpickling this creates the file ``target``: what a crafted checkpoint would do."""

    def __init__(self, target):
        self.target = str(target)

    def __reduce__(self):
        return (open, (self.target, "w"))


def test_resume_reads_no_pickle_it_did_not_sign(tmp_path):
    """A replay buffer replaced by a crafted pickle (with the old signature kept) and a
    checkpoint entry naming a file outside the run are refused before anything is unpickled:
    the payload's file is never created."""
    import pickle

    run_method("sac", ENV, 3, tmp_path, _opts("sac", 150))
    curve = json.loads((tmp_path / "curve.json").read_text())
    replay = tmp_path / curve["checkpoint"]["replay"]
    marker = tmp_path.parent / f"{tmp_path.name}_pwned"
    replay.write_bytes(pickle.dumps(_Payload(marker)))
    with pytest.raises(ValueError, match="does not match its signature"):
        run_method("sac", ENV, 3, tmp_path, _opts("sac", 300))
    assert not marker.exists()
    outside = dict(curve["checkpoint"], model="../elsewhere/model_150.zip")
    (tmp_path / "curve.json").write_text(json.dumps({**curve, "checkpoint": outside}))
    with pytest.raises(ValueError, match=r"checkpoint\.model = .* is not a checkpoint file"):
        run_method("sac", ENV, 3, tmp_path, _opts("sac", 300))
