"""The reference implementation's policy optimisation step, timed beside the package's: the
``--reference-repo`` option of the ``timing`` part of ``mcpilco-bench-mcpilco``.

The reference is merlresearch/MC-PILCO (release 1.0.0, commit 82013d6), given as a checkout
on disk (nothing is downloaded, nothing of it is copied into the package). Its experiment
scripts build their whole setting (GP model class and kernels, policy, cost, optimiser
options) as module-level code before the line that starts the learning
(``PL_obj.reinforce(...)``); :func:`reference_setting` runs that part of the script of a
task (:data:`REFERENCE_SCRIPTS`) from the checkout, less the statements that make the
learning object and write its configuration file, so the setting is the reference's own.

:class:`ReferenceStep` then builds the reference's ``MC_PILCO`` object from that setting,
gives its GP model ``N`` transitions of random data of the task's shape
(:func:`synthetic_transitions`; exact GP inference, every point kept; its hyperparameters
trained for a few epochs of its own optimiser: the step's cost does not depend on their
values) and times one step of its own
``MC_PILCO.reinforce_policy`` loop: the rollout of ``M`` particles through its GP for ``H``
steps, the cost, the backward pass and the Adam step. The clock runs from the optimiser's
``zero_grad`` to the end of its ``step`` (an ``Adam`` whose two calls read the clock, named in
the reference module's namespace, where ``reinforce_policy`` evaluates its optimiser string).

The UR5 task's script builds a MuJoCo simulator through ``gym`` (its ``MC_PILCO_Mujoco``
subclass only adds that simulator); where ``gym`` is not installed, a stub of its
registration functions lets the script's setting run, and the learning object is the base
``MC_PILCO`` class, whose ``reinforce_policy`` is the one the subclass runs: the step never
touches the simulator.
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
import time
import types
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "REFERENCE_MODULE",
    "REFERENCE_SCRIPTS",
    "ReferenceStep",
    "reference_checkout",
    "reference_setting",
    "reference_task",
    "synthetic_transitions",
]

REFERENCE_SCRIPTS = {
    "cartpole": "test_mcpilco_cartpole.py",
    "ur5": "test_mcpilco_ur5_mujoco.py",
}
"""The reference's experiment script of each of its tasks (paths in its repository)."""

REFERENCE_MODULE = "policy_learning.MC_PILCO"  # the reference module of the MC_PILCO class
START_LINE = "PL_obj.reinforce("  # the script line that starts the learning: run up to it
SKIPPED_LINES = ("PL_obj = ", "pkl.dump(")  # one-line statements left out: object, log file
TIMED_OPTIMIZER = "_mcpilco_timed_adam"  # the name the timed optimiser gets in that module
GP_EPOCHS = 200  # epochs of the reference's own GP hyperparameter optimiser before timing
STUB_GYM = ("gym", "gym.envs", "gym.envs.registration", "gym.wrappers")  # stubbed without gym


def reference_checkout(path: str) -> Path:
    """The type of ``--reference-repo``: ``path`` if it holds a checkout of the reference (its
    ``policy_learning`` folder), else an ``argparse.ArgumentTypeError`` saying what it is not."""
    import argparse

    if not (Path(path) / "policy_learning").is_dir():
        raise argparse.ArgumentTypeError(
            f"{path}: not a checkout of merlresearch/MC-PILCO (no policy_learning folder)"
        )
    return Path(path)


def reference_task(env_id: str) -> str:
    """The reference's task timed beside a package spec: its cart-pole beside the package's
    cart-pole, its UR5 arm beside the arm specs (the UR10 tracking task and its joints-only
    spec)."""
    return "cartpole" if "Cartpole" in env_id else "ur5"


@contextlib.contextmanager
def _in_checkout(repo: Path) -> Iterator[None]:
    """The reference's imports and relative paths resolve in ``repo`` (``sys.path`` first,
    the working directory), its prints are swallowed and the command line it parses is
    empty; the caller's random states, thread count, working directory, ``sys.argv`` and
    ``sys.path`` are restored after. Without ``gym``, its registration functions are stubs
    (module docstring)."""
    import torch

    before = (os.getcwd(), list(sys.argv), list(sys.path), torch.get_num_threads())
    np_state = np.random.get_state()  # noqa: NPY002 (the scripts seed the legacy global)
    stubs = []
    try:
        import gym  # noqa: F401
    except ImportError:
        for name in STUB_GYM:
            if name not in sys.modules:
                sys.modules[name] = types.ModuleType(name)
                stubs.append(name)
        sys.modules["gym.envs.registration"].register = lambda *a, **k: None
        sys.modules["gym"].wrappers = sys.modules["gym.wrappers"]
    try:
        with torch.random.fork_rng(devices=[]), contextlib.redirect_stdout(io.StringIO()):
            os.chdir(repo)
            sys.argv = [sys.argv[0]]
            sys.path.insert(0, str(repo))
            yield
    finally:
        cwd, argv, path, threads = before
        os.chdir(cwd)
        sys.argv[:] = argv
        sys.path[:] = path
        torch.set_num_threads(threads)
        np.random.set_state(np_state)  # noqa: NPY002
        for name in stubs:
            sys.modules.pop(name, None)


def reference_setting(repo: Path, task: str) -> dict[str, Any]:
    """The namespace of the reference's script for ``task`` (:data:`REFERENCE_SCRIPTS`) run
    from the checkout ``repo`` up to the line that starts its learning, less the one-line
    statements of :data:`SKIPPED_LINES`: its ``MC_PILCO_init_dict``,
    ``policy_optimization_dict``, ``reinforce_param_dict``, ``model_optimization_opt_list``
    and the rest of its setting."""
    repo = Path(repo)
    if task not in REFERENCE_SCRIPTS:
        raise ValueError(f"task must be one of {sorted(REFERENCE_SCRIPTS)}, got {task!r}")
    script = repo / REFERENCE_SCRIPTS[task]
    if not script.is_file():
        raise ValueError(
            f"--reference-repo {repo}: no {REFERENCE_SCRIPTS[task]} there; give a checkout "
            "of merlresearch/MC-PILCO"
        )
    lines = script.read_text().splitlines(keepends=True)
    cut = next((i for i, ln in enumerate(lines) if ln.startswith(START_LINE)), None)
    if cut is None:
        raise ValueError(f"{script}: no line starting with {START_LINE!r}")
    kept = []
    for ln in lines[:cut]:
        if ln.startswith(SKIPPED_LINES):
            if ln.count("(") != ln.count(")"):
                raise ValueError(f"{script}: the statement {ln.strip()!r} spans several lines")
            continue
        kept.append(ln)
    namespace: dict[str, Any] = {"__name__": "reference_setting", "__file__": str(script)}
    with _in_checkout(repo):
        exec(compile("".join(kept), str(script), "exec"), namespace)  # noqa: S102
    return namespace


SYNTHETIC_DAMPING = 0.9  # velocity kept per step by the synthetic data's dynamics
SYNTHETIC_STIFFNESS = 10.0  # 1/s^2: the synthetic data's spring pulling each position back


def synthetic_transitions(setting: dict[str, Any], n_points: int, seed: int):
    """``n_points`` transitions of random data of the shape of the reference's task
    (``setting``: :func:`reference_setting`): one trajectory of ``n_points + 1`` states from
    its initial state of damped springs: each velocity coordinate (its GP model's
    ``vel_indeces``) driven by a uniform random input within ``+-u_max``, pulled back by its
    position (:data:`SYNTHETIC_STIFFNESS`) and damped (:data:`SYNTHETIC_DAMPING`), each
    position integrating its velocity over ``T_sampling``; ``(states, inputs)`` with one
    input per state, as its ``add_data`` takes them (the last input unused). A stable linear
    system keeps the particles of its rollout where the data are (elsewhere its float64
    posterior variance can come out negative, and its sampler rejects the NaN); the step's
    cost does not depend on the values."""
    rng = np.random.default_rng(seed)
    init, par = setting["MC_PILCO_init_dict"], setting["model_learning_par"]
    dt, input_dim = float(init["T_sampling"]), int(init["input_dim"])
    vel, pos = list(par["vel_indeces"]), list(par["not_vel_indeces"])
    u_max = np.broadcast_to(np.asarray(setting.get("u_max", 1.0), dtype=float), (input_dim,))
    x = np.asarray(setting["reinforce_param_dict"]["initial_state"], dtype=float).copy()
    x0 = x[pos].copy()
    inputs = rng.uniform(-1.0, 1.0, (n_points + 1, input_dim)) * u_max
    states = np.empty((n_points + 1, x.size))
    for t in range(n_points + 1):
        states[t] = x
        drive = inputs[t, np.arange(len(vel)) % input_dim] - SYNTHETIC_STIFFNESS * (x[pos] - x0)
        x[pos] += dt * x[vel]
        x[vel] = SYNTHETIC_DAMPING * x[vel] + dt * drive
    return states, inputs


class _TimedAdam:
    """An ``Adam`` factory for the reference's optimiser string whose optimisers record the
    wall and CPU seconds from each ``zero_grad`` to the end of the following ``step``."""

    def __init__(self) -> None:
        self.steps: list[tuple[float, float]] = []

    def __call__(self, p: Any, lr: float) -> Any:
        import torch

        record = self.steps

        class Timed(torch.optim.Adam):
            def zero_grad(self, set_to_none: bool = True) -> None:
                self._t0 = (time.perf_counter(), time.process_time())
                super().zero_grad(set_to_none=set_to_none)

            def step(self, closure: Any = None) -> Any:
                grads = [p.grad for group in self.param_groups for p in group["params"]]
                if not all(bool(g.isfinite().all()) for g in grads if g is not None):
                    # its loop would re-initialise the policy and start again, for ever here
                    raise RuntimeError(
                        "the reference's rollout gave a NaN cost on these data (its sampler "
                        "or its variance failed); its step is not timed"
                    )
                out = super().step(closure)
                wall, cpu = self._t0
                record.append((time.perf_counter() - wall, time.process_time() - cpu))
                return out

        return Timed(p, lr)


class ReferenceStep:
    """One policy optimisation step of the reference implementation on its own ``task``
    (``"ur5"``, ``"cartpole"``) with ``n_points`` GP points, ``num_particles`` particles and
    ``horizon`` steps (module docstring); call it to run one step and get its ``(wall, CPU)``
    seconds. Built from the checkout ``repo``; its GP model's data: ``transitions``
    (``states, actions, next_states`` arrays in the reference task's state layout, the first
    ``n_points`` of them), else :func:`synthetic_transitions` drawn with ``seed``. A tracking
    cost follows the first ``horizon`` steps of its trajectory."""

    def __init__(
        self,
        repo: Path,
        task: str,
        n_points: int,
        num_particles: int,
        horizon: int,
        seed: int = 0,
        transitions: tuple[Any, Any, Any] | None = None,
    ) -> None:
        import torch

        self.repo, self.task = Path(repo), task
        ns = reference_setting(self.repo, task)
        self.setting = ns
        init = dict(ns["MC_PILCO_init_dict"])
        init.pop("sim_timestep", None)  # the MuJoCo subclass's own argument
        init["log_path"] = None
        par = {
            k: v
            for k, v in ns["model_learning_par"].items()
            if k not in ("approximation_mode", "approximation_dict")  # exact: all N points
        }
        init["model_learning_par"] = par
        cost_par = dict(init["cost_function_par"])
        if "target_traj" in cost_par:  # a tracking cost: its trajectory's first H steps
            cost_par["target_traj"] = cost_par["target_traj"][: int(horizon)]
        init["cost_function_par"] = cost_par
        self.dt = float(init["T_sampling"])
        self.horizon = int(horizon)
        self.num_particles = int(num_particles)
        self.clock = _TimedAdam()
        with _in_checkout(self.repo):
            import importlib

            module = importlib.import_module(REFERENCE_MODULE)
            setattr(module, TIMED_OPTIMIZER, self.clock)
            self.agent = module.MC_PILCO(**init)
            ml = self.agent.model_learning
            if transitions is not None:  # one add_data per transition: no false pairs
                arrays = [np.asarray(t, dtype=float)[:n_points] for t in transitions]
                for x, u, x1 in zip(*arrays, strict=True):
                    ml.add_data(np.stack([x, x1]), np.stack([u, u]))
            else:
                ml.add_data(*synthetic_transitions(ns, n_points, seed))
            opt = [
                {**d, "N_epoch": GP_EPOCHS, "N_epoch_print": GP_EPOCHS + 1}
                for d in ns["model_optimization_opt_list"]
            ]
            ml.reinforce_model(optimization_opt_list=opt)
            ml.set_eval_mode()
        self.n_points = int(ml.gp_inputs.shape[0])
        dtype = getattr(self.agent, "dtype", torch.float64)
        rp = ns["reinforce_param_dict"]
        self.mean = torch.as_tensor(np.asarray(rp["initial_state"], dtype=float), dtype=dtype)
        self.var = torch.as_tensor(np.asarray(rp["initial_state_var"], dtype=float), dtype=dtype)
        opts = dict(ns["policy_optimization_dict"])
        for key in ("num_particles", "opt_steps_list", "lr_list", "f_optimizer", "num_step_print"):
            opts.pop(key, None)
        self.options = opts
        self.lr = float(ns["policy_optimization_dict"]["lr_list"][0])

    def __call__(self) -> tuple[float, float]:
        """Run ``reinforce_policy`` for one optimisation step (its untimed initial rollout
        without gradients first) and return that step's ``(wall, CPU)`` seconds."""
        before = len(self.clock.steps)
        with _in_checkout(self.repo):
            self.agent.reinforce_policy(
                T_control=self.horizon * self.dt,
                num_particles=self.num_particles,
                trial_index=0,
                particles_initial_state_mean=self.mean,
                particles_initial_state_var=self.var,
                flg_particles_init_uniform=False,
                particles_init_up_bound=None,
                particles_init_low_bound=None,
                flg_particles_init_multi_gauss=False,
                opt_steps_list=[1],
                lr_list=[self.lr],
                f_optimizer=TIMED_OPTIMIZER,
                num_step_print=10**9,
                **self.options,
            )
        if len(self.clock.steps) != before + 1:
            raise RuntimeError(
                f"the reference's reinforce_policy ran {len(self.clock.steps) - before} "
                "optimiser steps, not 1"
            )
        return self.clock.steps[-1]
