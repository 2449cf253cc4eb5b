"""The reference implementation's step beside the package's (``--reference-repo``): run on a
small fake "reference" checkout written here, laid out as merlresearch/MC-PILCO is (its
experiment scripts, ``policy_learning.MC_PILCO``, ``model_learning.Model_learning``)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import torch

from mcpilco.experiments.mcpilco.reference import (
    GP_EPOCHS,
    ReferenceStep,
    reference_setting,
    reference_task,
    synthetic_transitions,
)

STEP_SLEEP = 0.02  # seconds the fake reference's step sleeps between zero_grad and step

FAKE_MC_PILCO = f"""
import json, time
import torch

class MC_PILCO(torch.nn.Module):
    def __init__(self, T_sampling, state_dim, input_dim, f_sim, f_model_learning,
                 model_learning_par, f_rand_exploration_policy, rand_exploration_policy_par,
                 f_control_policy, control_policy_par, f_cost_function, cost_function_par,
                 std_meas_noise=None, log_path=None, dtype=torch.float64, device=None):
        super().__init__()
        self.T_sampling, self.dtype, self.log_path = T_sampling, dtype, log_path
        self.model_learning = f_model_learning(**model_learning_par)
        self.control_policy = torch.nn.Linear(state_dim, input_dim).to(dtype)
        self.cost_par = cost_function_par
        self.calls = []

    def reinforce_policy(self, T_control, num_particles, trial_index, particles_initial_state_mean,
                         particles_initial_state_var, flg_particles_init_uniform,
                         particles_init_up_bound, particles_init_low_bound,
                         flg_particles_init_multi_gauss, opt_steps_list, lr_list, f_optimizer,
                         num_step_print=10, policy_reinit_dict=None, p_dropout_list=None,
                         **rest):
        self.calls.append(dict(
            T_control=T_control, num_particles=num_particles,
            opt_steps=opt_steps_list[trial_index], threads=torch.get_num_threads(),
            rest=sorted(rest), targets=len(self.cost_par.get("target_traj", []))))
        with torch.no_grad():  # the initial rollout without gradients, untimed
            self.control_policy(particles_initial_state_mean)
        optimizer = eval(f_optimizer)(p=self.control_policy.parameters(), lr=lr_list[trial_index])
        for _ in range(opt_steps_list[trial_index]):
            optimizer.zero_grad()
            time.sleep({STEP_SLEEP!r})
            cost = self.control_policy(particles_initial_state_mean).square().sum()
            cost.backward()
            optimizer.step()
"""

FAKE_MODEL_LEARNING = """
import torch

class Speed_model:
    def __init__(self, num_gp, vel_indeces, not_vel_indeces, **rest):
        self.rest = rest
        self.adds = 0
        self.gp_inputs = None

    def add_data(self, new_state_samples, new_input_samples):
        assert len(new_state_samples) == len(new_input_samples)
        rows = torch.as_tensor(new_state_samples)[:-1]
        self.gp_inputs = rows if self.gp_inputs is None else torch.cat([self.gp_inputs, rows])
        self.adds += 1

    def reinforce_model(self, optimization_opt_list=None):
        self.epochs = [d["N_epoch"] for d in optimization_opt_list]

    def set_eval_mode(self):
        self.eval_mode = True
"""

FAKE_SCRIPT = """
import argparse
import pickle as pkl
import numpy as np
import torch
{gym}
import model_learning.Model_learning as ML
import policy_learning.MC_PILCO as MC_PILCO

p = argparse.ArgumentParser("test")
p.add_argument("-seed", type=int, default=1)
locals().update(vars(p.parse_known_args()[0]))
torch.manual_seed(seed)
np.random.seed(seed)
torch.set_num_threads(1)
print("---- a print the harness swallows ----")
u_max = {u_max}
model_learning_par = dict(num_gp=2, vel_indeces={vel}, not_vel_indeces={pos},
                          approximation_mode="SOD", approximation_dict={{}})
MC_PILCO_init_dict = dict(T_sampling={dt}, state_dim=4, input_dim={inputs}, f_sim={f_sim},
    f_model_learning=ML.Speed_model, model_learning_par=model_learning_par,
    f_rand_exploration_policy=None, rand_exploration_policy_par={{}}, f_control_policy=None,
    control_policy_par={{}}, f_cost_function=None, cost_function_par={cost},
    log_path="results_tmp/1"{extra})
PL_obj = MC_PILCO.MC_PILCO(**MC_PILCO_init_dict)
model_optimization_opt_list = [dict(f_optimizer="adam", N_epoch=1501, N_epoch_print=500)] * 2
policy_optimization_dict = dict(num_particles=400, opt_steps_list=[2000], lr_list=[0.01],
    f_optimizer="lambda p, lr: torch.optim.Adam(p, lr)", num_step_print=100,
    p_dropout_list=[0.25], min_diff_cost=0.08, policy_reinit_dict={{}})
reinforce_param_dict = dict(initial_state=np.zeros(4), initial_state_var=1e-4 * np.ones(4),
    policy_optimization_dict=policy_optimization_dict)
pkl.dump(reinforce_param_dict, open("results_tmp/1/config_log.pkl", "wb"))
PL_obj.reinforce(**reinforce_param_dict)
raise SystemExit("the harness never runs this far")
"""


def fake_reference_repo(root: Path) -> Path:
    """A fake checkout of the reference at ``root``: the cart-pole script (an ODE simulator,
    a function) and the UR5 script (a ``gym`` registration, a tracking cost, the MuJoCo
    subclass's ``sim_timestep``), 4 states each, the reference's module layout."""
    (root / "policy_learning").mkdir(parents=True)
    (root / "model_learning").mkdir()
    (root / "policy_learning" / "MC_PILCO.py").write_text(FAKE_MC_PILCO)
    (root / "model_learning" / "Model_learning.py").write_text(FAKE_MODEL_LEARNING)
    cart = FAKE_SCRIPT.format(
        gym="", u_max=10.0, vel=[1, 3], pos=[0, 2], dt=0.05, inputs=1, f_sim="np.cos",
        cost="{}", extra="",
    )  # fmt: skip
    ur5 = FAKE_SCRIPT.format(
        gym="from gym.envs.registration import register\nregister(id='UR5_Env-v0')",
        u_max=[1.0, 1.0], vel=[2, 3], pos=[0, 1], dt=0.02, inputs=2, f_sim="'UR5_Env-v0'",
        cost="dict(target_traj=torch.zeros(200, 4))", extra=", sim_timestep=0.001",
    )  # fmt: skip
    (root / "test_mcpilco_cartpole.py").write_text(cart)
    (root / "test_mcpilco_ur5_mujoco.py").write_text(ur5)
    return root


def test_the_reference_step_is_its_own_reinforce_policy_step_timed_by_its_optimiser(tmp_path):
    """The harness runs the reference's script up to its learning (its setting, without
    making its learning object or writing its log), builds the reference's ``MC_PILCO`` with
    exact GP inference and no log, gives its model N transitions and times one optimiser
    step of its own ``reinforce_policy``: the clock covers the step (the fake's sleep), not the
    untimed setup; the caller's threads, working directory and random states are kept."""
    repo = fake_reference_repo(tmp_path / "ref")
    torch.set_num_threads(2)
    cwd, state = os.getcwd(), np.random.get_state()  # noqa: NPY002
    torch.manual_seed(5)
    before = torch.rand(1)
    torch.manual_seed(5)
    step = ReferenceStep(repo, "cartpole", n_points=7, num_particles=5, horizon=3)
    assert torch.rand(1) == before  # the scripts' seeding did not touch the caller's stream
    assert torch.get_num_threads() == 2 and os.getcwd() == cwd
    assert np.array_equal(np.random.get_state()[1], state[1])  # noqa: NPY002
    assert not (repo / "results_tmp").exists()  # its config log was not written
    ml = step.agent.model_learning
    assert step.n_points == 7 and ml.gp_inputs.shape == (7, 4) and ml.adds == 1
    assert "approximation_mode" not in ml.rest and step.agent.log_path is None
    assert ml.epochs == [GP_EPOCHS] * 2  # its own optimiser, fewer epochs than its 1501
    walls = [step() for _ in range(2)]
    assert all(wall >= STEP_SLEEP and cpu >= 0 for wall, cpu in walls)
    (call, _) = step.agent.calls
    assert call["opt_steps"] == 1 and call["num_particles"] == 5 and call["threads"] == 2
    assert call["T_control"] == pytest.approx(3 * 0.05)
    assert call["rest"] == ["min_diff_cost"]  # its other options passed on


def test_the_reference_ur5_without_gym_and_given_transitions(tmp_path):
    """The UR5 script registers a gym env: without gym its registration is a stub, removed
    after; the tracking cost follows the first H steps of its trajectory; transitions given
    go to its model one by one (no false pair between two episodes)."""
    repo = fake_reference_repo(tmp_path / "ref")
    s = np.random.default_rng(0).normal(size=(9, 4))
    a, s1 = np.ones((9, 2)), s + 0.1
    step = ReferenceStep(repo, "ur5", 6, 4, horizon=10, transitions=(s, a, s1))
    assert step.agent.model_learning.adds == 6 and step.n_points == 6
    step()
    assert step.agent.calls[0]["targets"] == 10  # of its 200 target steps
    try:
        import gym  # noqa: F401
    except ImportError:
        import sys

        assert "gym" not in sys.modules


def test_reference_setting_and_synthetic_data_and_task_names(tmp_path):
    """A folder without the reference's scripts is a clear error; the synthetic transitions
    are one trajectory of damped springs (positions integrate velocities) within the input
    bounds; the arm specs are timed beside the UR5, the cart-pole beside the cart-pole."""
    with pytest.raises(ValueError, match="no test_mcpilco_ur5_mujoco.py there"):
        reference_setting(tmp_path, "ur5")
    with pytest.raises(ValueError, match="task must be one of"):
        reference_setting(tmp_path, "pendulum")
    ns = reference_setting(fake_reference_repo(tmp_path / "ref"), "cartpole")
    states, inputs = synthetic_transitions(ns, 50, seed=0)
    assert states.shape == (51, 4) and inputs.shape == (51, 1)
    assert np.abs(inputs).max() <= 10.0
    dt = 0.05  # x+ = x + dt v on each position
    np.testing.assert_allclose(states[1:, [0, 2]], states[:-1, [0, 2]] + dt * states[:-1, [1, 3]])
    assert np.abs(states).max() < 10.0  # the springs keep it bounded
    assert reference_task("mcpilco/CartpoleSwingUp-v0") == "cartpole"
    assert reference_task("mcpilco/UR10-v0") == reference_task("mcpilco/UR10-v0:joints") == "ur5"
    json.dumps({k: v for k, v in ns.items() if isinstance(v, (int, float, str))})
