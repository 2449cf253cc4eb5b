"""MC-PILCO's TorchRL parts: the loss's tensordict keys (``set_keys``), the GP world model as
a ``TensorDictModule`` against the GP's own prediction, the TorchRL env of a task, and the
TorchRL example (examples/torchrl) trained on the toy env of the test suite."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn

from mcpilco.agents.mc_pilco import (
    GPDynamicsModel,
    MCPilcoLoss,
    StateLayout,
    TaskSpec,
    gp_inputs,
    load_config,
    speed_integration,
)
from mcpilco.agents.mc_pilco.torchrl_parts import (
    STATE_KEY,
    ParticleWorldModel,
    TaskStateTransform,
    make_torchrl_env,
)
from tests.agents.mc_pilco import toy_env

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = ROOT / "examples" / "torchrl" / "mc_pilco.py"


class Halve(nn.Module):
    """``u = -x / 2`` (one state, one action)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return -0.5 * x


class AddAction(nn.Module):
    """Stub dynamics ``x+ = x + u`` (the noise is ignored)."""

    def forward(self, x, u, eps):
        return x + u


class Square(nn.Module):
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return (x**2).sum(-1)


def halving_loss(policy_keys=("observation", "action"), horizon: int = 3) -> MCPilcoLoss:
    """The loss of ``x_{t+1} = x_t / 2`` (policy ``-x/2``, dynamics ``x + u``), cost ``x^2``:
    ``J^ = mean_m x_0^2 sum_{t=1}^{H} 4^{-t}`` (analytic)."""
    policy = TensorDictModule(Halve(), in_keys=[policy_keys[0]], out_keys=[policy_keys[1]])
    return MCPilcoLoss(
        policy, AddAction(), Square(), horizon=horizon, num_particles=4, init_mean=[0.0],
        delta_dim=1,
    )  # fmt: skip


def test_set_keys_renames_what_the_loss_reads_and_writes():
    """Default keys as documented; after ``set_keys`` the loss reads ``x_0`` and ``eps`` and
    writes its outputs under the new names, with the analytic ``J^`` of the halving system;
    ``None`` restores a default; an unknown name is refused (TorchRL's rule)."""
    loss = halving_loss()
    keys = loss.tensor_keys
    assert (keys.initial_state, keys.noise, keys.observation, keys.action) == (
        "initial_state",
        "noise",
        "observation",
        "action",
    )
    assert (keys.next_observation, keys.loss_cost) == (("next", "observation"), "loss_cost")
    x0 = torch.tensor([[1.0], [2.0], [-1.0], [3.0]])
    eps = torch.zeros(3, 4, 1)
    truth = float((x0**2).mean()) * sum(4.0**-t for t in (1, 2, 3))
    out = loss(TensorDict({"initial_state": x0, "noise": eps}, []))
    assert float(out["loss_cost"]) == pytest.approx(truth, rel=1e-6)

    loss.set_keys(initial_state=("data", "x0"), noise="eps", loss_cost="loss_mcpilco")
    out = loss(TensorDict({("data", "x0"): x0, "eps": eps}, []))
    assert float(out["loss_mcpilco"]) == pytest.approx(truth, rel=1e-6)
    assert "loss_cost" not in out.keys()
    assert out["candidate_costs"].shape == (1,)
    loss.set_keys(loss_cost=None)  # back to the default
    assert loss.tensor_keys.loss_cost == "loss_cost"
    with pytest.raises(ValueError, match="not an accepted tensordict key"):
        loss.set_keys(bogus="x")


def test_policy_keys_must_match_the_loss_keys():
    """A policy reading ``"state"`` is refused until the loss's keys are set to it (the
    message names the call); then the loss runs, and its trajectory TensorDict carries the
    keys set (``x_{t+1}`` of step ``t`` is ``x_t`` of step ``t+1``)."""
    loss = halving_loss(("state", "u"))
    with pytest.raises(ValueError, match=r"set_keys\(observation='state', action='u'\)"):
        loss(TensorDict({}, []))
    loss.set_keys(observation="state", action="u", next_observation=("next", "state"))
    assert torch.isfinite(loss(TensorDict({}, []))["loss_cost"])
    td = loss.rollout_tensordict(initial_state=torch.ones(4, 1), noise=torch.zeros(3, 4, 1))
    assert td.batch_size == (4, 3)
    assert torch.allclose(td["state"][:, 1:], td["next", "state"][:, :-1])
    assert torch.allclose(td["u"][:, 0], -0.5 * torch.ones(4, 1))
    assert torch.allclose(td["next", "cost"][:, -1, 0], torch.full((4,), 0.5**6))


def tasks() -> list[TaskSpec]:
    """The toy's 4-state task and a 3-state one: an angle paired with its speed and an
    unpaired coordinate, two actions."""
    three = {
        "env_id": "any",
        "state_names": ["th", "thd", "z"],
        "angles": ["th"],
        "pairs": [["th", "thd"]],
        "action_low": [-1.0, -1.0],
        "action_high": [1.0, 1.0],
        "dt": 0.05,
        "horizon": 5,
        "init_mean": [0.0, 0.0, 0.0],
        "cost": {"terms": [{"state": "th", "target": math.pi, "length_scale": 1.0}]},
        "success": {"bounds": {"th": {"target": math.pi, "tol": 0.1}}},
    }
    return [TaskSpec.from_dict(toy_env.TASK), TaskSpec.from_dict(three)]


@pytest.mark.parametrize("task", tasks(), ids=["toy4", "angle3"])
def test_world_model_agrees_with_the_gps_own_prediction(task):
    """The world model's mean ``x_{t+1}`` is eq. (5.9) of the GP's posterior mean as
    ``GPRegressor.predict`` computes it (its plain cached posterior; the world model steps
    the fused one), and its sample that of ``E[Delta] + sqrt(var[Delta]) eps``, for any state
    size and leading batch shape; the loss over the world model equals the loss over the
    plain dynamics."""
    rng = np.random.default_rng(0)
    n, a = task.state_dim, task.action_dim
    s = rng.normal(size=(40, n))
    u = rng.uniform(-1, 1, size=(40, a))
    s1 = s + 0.05 * np.tanh(s @ rng.normal(size=(n, n)) + u @ rng.normal(size=(a, n)))
    model = GPDynamicsModel(
        task, adam_iters=20, lbfgs_iters=0, max_points=None, delta_clip_factor=None
    ).fit(s, u, s1)
    world = ParticleWorldModel.from_model(model, torch.float64)
    layout = StateLayout.from_task(task)
    x = torch.as_tensor(rng.normal(size=(2, 5, n)))
    act = torch.as_tensor(rng.uniform(-1, 1, size=(2, 5, a)))
    eps = torch.as_tensor(rng.normal(size=(2, 5, layout.output_dim)))
    td = world(TensorDict({"observation": x, "action": act, "noise": eps}, batch_size=[2, 5]))
    assert td["next", "observation"].shape == (2, 5, n)
    mean, var = model.gp_.predict(gp_inputs(x, act, layout).reshape(10, -1))
    mean, var = mean.reshape(2, 5, -1), var.reshape(2, 5, -1)
    want_mean = speed_integration(x, mean, task.dt, layout)
    want_sample = speed_integration(x, mean + var.sqrt() * eps, task.dt, layout)
    assert torch.allclose(td["next", "observation_mean"], want_mean, atol=1e-8)
    assert torch.allclose(td["next", "observation"], want_sample, atol=1e-8)
    drawn = world(TensorDict({"observation": x, "action": act}, batch_size=[2, 5]))
    assert not torch.allclose(drawn["next", "observation"], want_sample)  # eps drawn
    with pytest.raises(ValueError, match=f"the task's {n} states"):
        world(TensorDict({"observation": x[..., :-1], "action": act}, batch_size=[2, 5]))

    def loss_over(dynamics):
        policy = TensorDictModule(nn.Linear(n, a).double(), ["observation"], ["action"])
        torch.manual_seed(1)
        policy.module.reset_parameters()
        return MCPilcoLoss(
            policy, dynamics, Square(), horizon=4, num_particles=6, init_mean=[0.1] * n
        ).double()

    x0 = torch.as_tensor(rng.normal(size=(6, n)))
    noise = torch.as_tensor(rng.normal(size=(4, 6, layout.output_dim)))
    inputs = TensorDict({"initial_state": x0, "noise": noise}, [])
    J_world = loss_over(world)(inputs.clone())["loss_cost"]
    J_plain = loss_over(model.particle_dynamics(torch.float64))(inputs.clone())["loss_cost"]
    assert torch.allclose(J_world, J_plain, rtol=1e-10)
    renamed = ParticleWorldModel.from_model(
        model, in_keys=("s", "action", "noise"), out_keys=(("next", "s"), ("next", "s_mean"))
    )
    with pytest.raises(ValueError, match=r"set_keys\(observation='s', action='action'"):
        loss_over(renamed)(inputs.clone())


def test_torchrl_env_observes_the_tasks_state():
    """``Pendulum-v1`` observes ``[cos th, sin th, thd]`` (Gymnasium's definition); the
    TorchRL env of its task file writes the state ``[th, thd]`` at reset and at every step.
    A derived state read from ``info`` is refused, naming the field."""
    task = load_config("Pendulum-v1").task_spec()
    env = make_torchrl_env(task, seed=3)
    td = env.rollout(4)
    for t in (td, td["next"]):
        obs, state = t["observation"].double(), t[STATE_KEY].double()
        assert torch.allclose(state[:, 0], torch.atan2(obs[:, 1], obs[:, 0]), atol=1e-5)
        assert torch.allclose(state[:, 1], obs[:, 2], atol=1e-5)
    env.close()
    reads_info = TaskSpec.from_dict(
        {**toy_env.TASK, "state_from": {n: {"index": 0, "info": "physics"} for n in
                                        toy_env.TASK["state_names"]}}
    )  # fmt: skip
    with pytest.raises(ValueError, match=r"state_from\.px\.info"):
        TaskStateTransform(reads_info)


def load_example():
    spec = importlib.util.spec_from_file_location("mcpilco_torchrl_example", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_example_config_reads_with_overrides():
    """The shipped config.yaml parses; ``--set`` values (dotted keys) override it."""
    ex = load_example()
    cfg = ex.read_config(ex.CONFIG, ["config.num_trials=2", "env_id=Pendulum-v1"])
    assert cfg["env_id"] == "Pendulum-v1" and cfg["config"]["num_trials"] == 2
    assert cfg["config"]["compile_rollout"] is False


def test_example_trains_the_toy_env_through_torchrl():
    """The TorchRL example on the toy point mass (GymEnv, Collector, ReplayBuffer, world
    model module, loss): after 3 s of random exploration, one policy trial brings the mass
    from (-1, 0.5) to the origin. Judged by the env's own reward ``-(px^2 + py^2)`` per step
    against the analytic cost of staying at the start, ``30 * 1.25 = 37.5`` (the
    random exploration's is larger still), and by the final distance to the origin (under
    a fifth of the start's, 1.12)."""
    ex = load_example()
    cfg = {
        "env_id": toy_env.ENV_ID,
        "config": {
            "task": toy_env.TASK,
            "seed": 0,
            "num_trials": 1,
            "num_particles": 50,
            "max_points": 100,
            "gp_adam_iters": 60,
            "gp_lbfgs_iters": 20,
            "num_basis": 50,
            "sim_obs_noise_std": 0.0,
            "torch_threads": 1,
            "opt": {"max_steps": 150, "min_steps": 50, "monitor_patience": 50},
        },
    }
    explore, trial = ex.train(cfg, log=None)
    stay = toy_env.TASK["horizon"] * (1.0**2 + 0.5**2)
    assert -explore["env_return"] > stay
    assert -trial["env_return"] < 0.4 * stay, trial
    assert np.hypot(*np.asarray(trial["final_state"])[[0, 2]]) < 0.2, trial  # from 1.12
    assert trial["experience_s"] == pytest.approx(6.0)
