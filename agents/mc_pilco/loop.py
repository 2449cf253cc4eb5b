"""Outer loop of MC-PILCO (thesis Algorithm 1): explore, fit GP, optimise policy, apply, repeat.

Glossary
--------
trial ``k = 0``
    random exploration for ``H`` steps (3 s): actions ``u ~ U(-1, 1)`` i.i.d., each held for
    ``explore_hold`` control steps (default 2: one draw per 0.1 s, the thesis's sampling time).
trial ``k >= 1``
    fit the velocity-change GPs on all transitions ``D`` by marginal likelihood (fresh
    hyperparameters each trial; subset of data beyond ``max_points``), optimise the policy on the
    particle estimate ``J^`` (5.8) with the monitoring rule, apply the policy (no dropout)
    to the env for ``H`` steps, append the transitions to ``D``.
experience
    ``3 (k + 1)`` seconds after trial ``k`` (3, 6, 9, 12, 15 s ...).
record of a trial
    env cost ``sum_t c(x_t)`` on the true state, ``success`` (env ``info``: upright over the
    last 1 s with ``|x| < 0.5``), time upright, mean ``|x|``, wall-clock of the GP fit, of
    the optimisation and of the trial, optimisation steps and seconds per step, the one-step
    GP error on the trial's data (model fitted before the trial), and the particle
    predictions of the final policy.

After every trial the run is checkpointed atomically (:mod:`.checkpoint`): data, policy,
GP state, optimiser and RNG states, records. ``resume=True`` continues from it.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mcpilco.agents.common.run_folder import RUN_OUTPUTS, open_run_folder
from mcpilco.agents.mc_pilco.checkpoint import (
    CHECKPOINT_VERSION,
    atomic_torch_save,
    load_checkpoint,
    rng_state,
    set_rng_state,
)
from mcpilco.agents.mc_pilco.cost import SwingUpCost
from mcpilco.agents.mc_pilco.dynamics import KERNEL_CHOICES, GPDynamicsModel
from mcpilco.agents.mc_pilco.loss import MCPilcoLoss
from mcpilco.agents.mc_pilco.native_rollout import cpp_compiler, cpp_compiler_names
from mcpilco.agents.mc_pilco.optimize import OptimizationResult, PolicyOptConfig, optimize_policy
from mcpilco.agents.mc_pilco.policy import (
    PolicyPopulation,
    SquashedRBFPolicy,
    make_policy_module,
)
from mcpilco.agents.mc_pilco.viz import (
    plot_optimisation,
    plot_trial_particles,
    write_rerun_recording,
)
from mcpilco.models.device import check_device_name, resolve_device

DEFAULT_ENV_ID = "mcpilco/CartpoleSwingUp-v0"
CHECKPOINT_NAME = "checkpoint.pt"
# config fields that must not change when a run is resumed
_RESUME_FIXED = (
    "env_id",
    "seed",
    "kernel",
    "horizon",
    "num_particles",
    "num_basis",
    "num_candidates",
    "explore_hold",
)
ROLLOUT_DTYPES = ("float32", "float64")
"""Choices of :attr:`MCPilcoConfig.rollout_dtype`."""
DEFAULT_EXPLORE_HOLD = 2
"""Exploration hold of an env without an entry in :data:`EXPLORE_HOLD_BY_ENV` (0.1 s at the
cartpoles' 0.05 s control period: the thesis's sampling time, 5.5.1)."""
EXPLORE_HOLD_BY_ENV: dict[str, int] = {"mcpilco/DMCCartpoleSwingUp-v0": 1}
"""Measured exceptions to :data:`DEFAULT_EXPLORE_HOLD`. dm-control's cartpole: on seeds 0-11
(bench preset) i.i.d. exploration swung up at 12 s on 7 / 12 seeds, held exploration on
3 / 12 (15 s: 8 / 12 against 5 / 12); held pushes drove the cart into the rail's end stop
(``|x|`` 1.85-1.90 m, the rail ends at 1.8 m) on 8 seeds (``results/mcpilco_cartpole.md``)."""
LEGACY_FIELD_VALUES: dict[str, Any] = {"explore_hold": 1}
"""Value of each config field added after results were saved, for configs that lack it."""
CANDIDATE_SEED_STRIDE = 7919
"""Candidate ``k`` of run ``seed`` is initialised with seed ``seed + 7919 k``."""


def default_explore_hold(env_id: str) -> int:
    """Control steps each random exploration action is held on ``env_id`` when the config
    does not say: :data:`EXPLORE_HOLD_BY_ENV` or else :data:`DEFAULT_EXPLORE_HOLD`."""
    return EXPLORE_HOLD_BY_ENV.get(env_id, DEFAULT_EXPLORE_HOLD)


@dataclass
class MCPilcoConfig:
    """One MC-PILCO experiment (defaults: the MC-PILCO cartpole setup, thesis 5.5.1).

    Attributes:
        env_id: registered Gymnasium id (``import mcpilco.envs`` registers ``mcpilco/...``).
        num_trials: policy trials after the exploration trial.
        horizon: ``H``, steps per trial and of the particle rollout (must equal the env's
            episode length).
        num_particles: ``M``.
        kernel: ``"rbf+mpk"`` or ``"rbf"``.
        max_points: GP subset-of-data size.
        gp_adam_iters, gp_lbfgs_iters: marginal-likelihood budget per fit.
        num_basis: policy basis functions.
        policy_weight_scale: initial policy weights ``w ~ U(-s, s)``. Small, so that the
            initial policy is close to ``u = 0``: with ``s = 0.5`` the sum over 200 basis
            functions gives a biased action that drives the cart metres away in 3 s, where
            the cost is flat (1) and its gradient vanishes (seed 1 never left ``J^ = 56``).
        l_x, l_theta: length scales of the cost optimised on the particles. Default: the
            values of Amadio et al. 2022 (sec. V-A, cart-pole: ``l_theta = 3``,
            ``l_x = 1``), wider than the env's evaluation cost (thesis 5.5.1: ``l_theta = 1``,
            ``l_x = 1.5``): with ``l_theta = 1`` the cost is flat (``1 - 5e-5``) while the pole
            hangs, its gradient vanishes and, in our first runs, the policy collapsed to
            "do nothing" on trial 2. Success and the reported cost always come from the env.
        cost_wrap_angle: wrap theta in the optimised cost (False: MC-PILCO's ``|theta|``,
            which does not reward spinning the pole; see :mod:`.cost`).
        num_candidates: ``K`` candidate policies optimised side by side (``M`` particles
            each; :class:`~mcpilco.agents.mc_pilco.policy.PolicyPopulation`); the one with
            the lowest ``J^`` (fresh particles, no dropout) is applied. 1: plain MC-PILCO.
        candidate_weight_scales: initial weight scale ``s_k`` of each candidate ``k``
            (length ``K``); None: ``policy_weight_scale`` for all. Candidates that all start
            near ``u = 0`` tend to follow the same gradient path into the same optimum;
            a larger ``s_k`` starts candidate ``k`` from a different random policy.
        explore_hold: control steps each random action of the exploration trial is held
            (``u ~ U(-1, 1)`` drawn once per ``explore_hold`` steps). None (default): the
            env's value, :func:`default_explore_hold`, filled in at construction (and again
            when :meth:`with_overrides` changes ``env_id`` and this field still holds the old
            env's value). 2 on ``mcpilco/CartpoleSwingUp-v0``: one draw per 0.1 s, the sampling
            time of the thesis's cartpole (5.5.1), whose exploration this reproduces; 1: i.i.d.
            per 0.05 s step (the setting of the runs before this field existed;
            :meth:`from_dict` reads a config without it as 1). At 0.05 s the i.i.d. force
            averages out and the pole swings less (median largest angle over the exploration
            trials of seeds 0-19: 1.24 rad i.i.d., 2.04 rad held for 2 steps). 1 on the
            dm-control adapter, where it is better (seeds 0-11 at 12 s: 7/12 against 3/12): there
            held pushes drive the cart into the rail's end stop (x = 1.8 m).
        init_std: ``sigma_0`` of the initial particles.
        sim_obs_noise_std: measurement noise simulated on the policy input in rollouts.
        opt: policy optimisation schedule (:class:`PolicyOptConfig`).
        opt_steps_first: optimisation steps of the first policy trial, when smaller than
            ``opt.max_steps`` (thesis 5.5.1: fewer steps while the model is poor); None = same.
        log_particles: particles kept per trial for the PNG / Rerun plots.
        seed: seeds torch, numpy and the env resets.
        torch_threads: ``torch.set_num_threads`` (None: leave as is).
        compile_rollout: compile the rollout's time step with its backward
            (:meth:`MCPilcoLoss.compile_step`, default backend: ``native`` on the CPU, the
            whole rollout in the package's C++ loop (built once, 2-3 s; then 0.04-0.21 s
            per trial to pack the GP and check); ``direct`` where that does not apply, the
            parts' backward passes chained by hand and compiled by inductor; ``torch.compile``
            elsewhere). Each trial recompiles for its new GP (``direct``: 17-24 s at a new
            size N, about 1 s from inductor's on-disk cache; 2-6 s
            for ``torch.compile`` with inductor's on-disk cache warm, about 20 s cold). The
            speed-ups are measured by ``mcpilco-bench-mcpilco --parts timing
            --compile-rollout`` (``results/mcpilco_cartpole.md``); off by default (needs a C++
            compiler). Each trial checks the compiled step against the eager one (``J^`` and
            its gradient) and runs eagerly if they disagree (the trial record's
            ``compiled_step``, ``compile_backend``, ``rollout_shards`` and
            ``compile_check``).
        rollout_dtype: dtype of the GP posterior evaluated in the particle rollout,
            ``"float32"`` (default; a step at M = 400 is 1.4x / 1.8x faster at N = 100 / 250,
            1 thread) or ``"float64"``; the particles, the policy and the GP fit are the
            same in both (float32, float32, float64). The benchmark compares the two
            (``mcpilco-bench-mcpilco --rollout-dtype``).
        device: where the policy optimisation runs (policy, particles, GP posterior):
            ``"cpu"`` (default) or ``"cuda"`` / ``"cuda:<index>"``. The GP fit (float64,
            ``N <= max_points``) and the env stay on the CPU; the policy acts on the env from
            the device. Checked at :func:`run_mcpilco` (a config saved on a GPU machine loads
            anywhere).
    """

    env_id: str = DEFAULT_ENV_ID
    num_trials: int = 5
    horizon: int = 60
    num_particles: int = 400
    kernel: str = "rbf+mpk"
    max_points: int | None = 300
    gp_adam_iters: int = 200
    gp_lbfgs_iters: int = 100
    num_basis: int = 200
    policy_weight_scale: float = 0.01
    l_x: float = 1.0
    l_theta: float = 3.0
    cost_wrap_angle: bool = False
    num_candidates: int = 1
    candidate_weight_scales: list[float] | None = None
    explore_hold: int | None = None
    init_std: float = 0.01
    sim_obs_noise_std: float = 0.01
    opt: PolicyOptConfig = field(default_factory=PolicyOptConfig)
    opt_steps_first: int | None = None
    log_particles: int = 100
    seed: int = 0
    torch_threads: int | None = None
    compile_rollout: bool = False
    rollout_dtype: str = "float32"
    device: str = "cpu"

    def __post_init__(self) -> None:
        if isinstance(self.opt, dict):
            self.opt = PolicyOptConfig(**self.opt)
        if int(self.num_particles) != self.num_particles or self.num_particles < 1:
            raise ValueError(
                f"num_particles must be a positive integer, got {self.num_particles!r} "
                "(MC-PILCO uses 400)"
            )
        if int(self.num_trials) != self.num_trials or self.num_trials < 0:
            raise ValueError(f"num_trials must be an integer >= 0, got {self.num_trials!r}")
        if int(self.horizon) != self.horizon or self.horizon < 1:
            raise ValueError(f"horizon must be a positive integer, got {self.horizon!r}")
        if int(self.num_candidates) != self.num_candidates or self.num_candidates < 1:
            raise ValueError(
                f"num_candidates must be a positive integer, got {self.num_candidates!r}"
            )
        if self.candidate_weight_scales is not None:
            scales = [float(v) for v in self.candidate_weight_scales]
            if len(scales) != self.num_candidates or not all(v > 0 for v in scales):
                raise ValueError(
                    f"candidate_weight_scales must hold num_candidates={self.num_candidates} "
                    f"positive values, got {self.candidate_weight_scales!r}"
                )
            self.candidate_weight_scales = scales
        if self.explore_hold is None:
            self.explore_hold = default_explore_hold(self.env_id)
        if int(self.explore_hold) != self.explore_hold or self.explore_hold < 1:
            raise ValueError(f"explore_hold must be an integer >= 1, got {self.explore_hold!r}")
        if self.rollout_dtype not in ROLLOUT_DTYPES:
            raise ValueError(
                f"rollout_dtype must be one of {ROLLOUT_DTYPES}, got {self.rollout_dtype!r}"
            )
        if self.kernel not in KERNEL_CHOICES:
            raise ValueError(f"kernel must be one of {KERNEL_CHOICES}, got {self.kernel!r}")
        self.device = str(check_device_name(self.device))
        if self.max_points is not None and self.max_points < 10:
            raise ValueError(f"max_points must be >= 10 or None, got {self.max_points}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def with_overrides(self, opt_steps: int | None = None, **fields: Any) -> MCPilcoConfig:
        """A validated copy with ``fields`` replaced; ``None`` values leave a field as is.

        ``opt_steps`` sets ``opt.max_steps`` and caps ``opt_steps_first`` at it (the
        command-line ``--opt-steps`` of the scripts). A new ``env_id`` without an
        ``explore_hold`` takes the new env's default hold if this config has the old env's.
        """
        over = {k: v for k, v in fields.items() if v is not None}
        if (
            "env_id" in over
            and "explore_hold" not in over
            and self.explore_hold == default_explore_hold(self.env_id)
        ):
            over["explore_hold"] = default_explore_hold(over["env_id"])
        if opt_steps is not None:
            over["opt"] = dataclasses.replace(self.opt, max_steps=opt_steps)
            if self.opt_steps_first is not None:
                over["opt_steps_first"] = min(self.opt_steps_first, opt_steps)
        return dataclasses.replace(self, **over)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> MCPilcoConfig:
        """Inverse of :meth:`to_dict`; fields added later take the value that reproduces the
        runs saved before them (:data:`LEGACY_FIELD_VALUES`), not their new default."""
        return cls(**{**LEGACY_FIELD_VALUES, **d})


SMALL_CONFIG = MCPilcoConfig(
    num_trials=4,
    num_particles=100,
    num_candidates=2,
    max_points=200,
    opt=PolicyOptConfig(max_steps=500, monitor_patience=100),
    opt_steps_first=300,
    log_particles=100,
)
"""Small budget: 100 particles, 2 candidate policies, at most 500 optimisation steps per
trial (``make demo``'s budget, preset ``demo``, until 2026-11-26; now preset ``small``). With
held exploration, 12 seeds: 58 % / 92 % success at 12 / 15 s of experience; with i.i.d.
exploration (``explore_hold=1``) 58 % / 83 %; one policy, 6 seeds: 50 % / 67 %
(``results/mcpilco_cartpole.md``, sections demo_hold2, K2 and the one-candidate run)."""

BENCH_CONFIG = MCPilcoConfig(
    num_trials=4,
    num_particles=400,
    max_points=250,
    opt=PolicyOptConfig(max_steps=1000, monitor_patience=100),
    opt_steps_first=500,
)
"""Budget of ``mcpilco-bench-mcpilco`` per seed (exploration + 4 policy trials = 15 s). With
the default held exploration, seeds 0-19 all swing up at 12 s and at 15 s of experience
(section "hold2" of ``results/mcpilco_cartpole.md``; i.i.d. exploration: 60 % / 95 %)."""

DEMO_CONFIG = dataclasses.replace(BENCH_CONFIG, num_trials=3)
"""``make demo``'s budget: the bench budget, stopped after 3 policy trials (12 s of
experience), where the bench swung up on 20 of 20 seeds (held exploration; 19 of 20 with the
time step compiled). ``make demo`` (:mod:`mcpilco.scripts.demo`) also compiles the time step
on the CPU when a C++ compiler is found. Seed 0, 2 threads, on the slower 2-core machine of
2026-11-27: success at 9 and 12 s of experience, 5.9 min compiled, 14.0 min eager (eager on
the faster machine of 2026-11-26: 7.6 min; seed 1 5.9 min)."""

PRESETS: dict[str, MCPilcoConfig] = {
    "default": MCPilcoConfig(),
    "small": SMALL_CONFIG,
    "demo": DEMO_CONFIG,
    "bench": BENCH_CONFIG,
}
"""The named configs of the scripts' ``--preset`` option."""


@dataclass
class RunSummary:
    """What :func:`run_mcpilco` returns: per-trial records and the output files."""

    config: dict[str, Any]
    records: list[dict[str, Any]]
    out_dir: Path
    checkpoint: Path
    rrd: Path | None
    pngs: list[Path]
    seconds: float
    resumed_from_trial: int | None = None

    @property
    def success(self) -> bool:
        """Success of the last policy trial."""
        return bool(self.records and self.records[-1].get("success"))

    @property
    def first_success_trial(self) -> int | None:
        for r in self.records:
            if r["kind"] == "policy" and r["success"]:
                return int(r["index"])
        return None


# ----------------------------------------------------------------------------------- env
def registered_ids(prefix: str = "mcpilco/") -> list[str]:
    import gymnasium as gym

    import mcpilco.envs  # noqa: F401  (registers the ids)

    return sorted(k for k in gym.registry if k.startswith(prefix))


def make_env(env_id: str, horizon: int):
    """``gym.make(env_id)`` with clear errors for an unknown id or a horizon mismatch."""
    import gymnasium as gym

    ids = registered_ids()
    if env_id not in gym.registry:
        raise ValueError(f"unknown env id {env_id!r}; registered mcpilco ids: {', '.join(ids)}")
    env = gym.make(env_id)
    steps = env.spec.max_episode_steps if env.spec is not None else None
    if steps is not None and steps != horizon:
        env.close()
        raise ValueError(
            f"horizon mismatch: the config's horizon is {horizon} steps but {env_id} episodes "
            f"last {steps} steps; set horizon={steps}"
        )
    return env


def env_dt(env) -> float:
    return float(getattr(env.unwrapped, "dt", 0.05))


def run_episode(
    env, act: Callable[[np.ndarray], np.ndarray], seed: int, horizon: int
) -> dict[str, Any]:
    """One episode of ``horizon`` steps; returns observations, true states, actions, metrics."""
    obs, info = env.reset(seed=seed)
    observations = [np.asarray(obs, dtype=np.float64)]
    states = [np.asarray(info.get("state", obs), dtype=np.float64)]
    actions, costs, upright = [], [], []
    success = False
    for _ in range(horizon):
        a = np.asarray(act(observations[-1]), dtype=np.float64).reshape(-1)
        obs, _, terminated, truncated, info = env.step(a.astype(np.float32))
        observations.append(np.asarray(obs, dtype=np.float64))
        states.append(np.asarray(info.get("state", obs), dtype=np.float64))
        actions.append(a)
        costs.append(float(info["cost"]))
        upright.append(bool(info["upright"]))
        if "success" in info:
            success = bool(info["success"])
        if terminated or truncated:
            break
    states_arr = np.stack(states)
    dt = env_dt(env)
    return {
        "obs": np.stack(observations),
        "states": states_arr,
        "actions": np.stack(actions),
        "costs": np.asarray(costs),
        "success": success,
        "cost": float(np.sum(costs)),
        "time_upright": float(np.sum(upright) * dt),
        "mean_abs_x": float(np.mean(np.abs(states_arr[1:, 0]))),
    }


# ------------------------------------------------------------------------------- helpers
def _policy_act(policy: SquashedRBFPolicy) -> Callable[[np.ndarray], np.ndarray]:
    policy.eval()
    device = policy.weights.device

    @torch.no_grad()
    def act(obs: np.ndarray) -> np.ndarray:
        x = torch.as_tensor(obs, dtype=torch.float32, device=device)[None]
        return policy(x)[0].cpu().numpy()

    return act


@torch.no_grad()
def choose_candidate(
    loss: MCPilcoLoss, population: PolicyPopulation, policy: SquashedRBFPolicy, repeats: int = 4
) -> torch.Tensor:
    """``J^_k`` of every candidate (mean of ``repeats`` rollouts with fresh particles, no
    dropout); copies the best candidate into ``policy`` and returns the ``J^_k`` (K,)."""
    population.eval()
    costs = torch.stack([loss()["candidate_costs"] for _ in range(repeats)]).mean(0)
    population.copy_to(int(costs.argmin()), policy)
    return costs


def transitions(episodes: list[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(s_t, a_t, s_{t+1})`` of all episodes, stacked."""
    s = np.concatenate([e["obs"][:-1] for e in episodes])
    a = np.concatenate([e["actions"] for e in episodes])
    s1 = np.concatenate([e["obs"][1:] for e in episodes])
    return s, a, s1


def trial_seed(seed: int, k: int) -> int:
    """Env reset seed of trial ``k`` of run ``seed`` (shared by MC-PILCO and its baselines)."""
    return int(seed) * 10_007 + int(k)


def exploration_actions(rng: np.random.Generator, horizon: int, hold: int = 1) -> np.ndarray:
    """``(horizon, 1)`` random actions: ``ceil(horizon / hold)`` draws ``u ~ U(-1, 1)`` from
    ``rng``, each repeated for ``hold`` steps (``hold = 1``: i.i.d. per step)."""
    if int(hold) != hold or hold < 1:
        raise ValueError(f"hold must be an integer >= 1, got {hold!r}")
    draws = rng.uniform(-1.0, 1.0, size=(-(-horizon // hold), 1))
    return np.repeat(draws, hold, axis=0)[:horizon]


def exploration_episode(
    env, rng: np.random.Generator, seed: int, horizon: int, hold: int = 1
) -> dict[str, Any]:
    """Trial 0: the actions of :func:`exploration_actions` for ``horizon`` steps."""
    it = iter(exploration_actions(rng, horizon, hold))
    return run_episode(env, lambda _o: next(it), trial_seed(seed, 0), horizon)


def check_resume(saved: dict[str, Any], config: Any, keys: tuple[str, ...]) -> None:
    """Raise ``ValueError`` naming the first of ``keys`` whose value in ``config`` differs
    from the checkpoint's ``saved`` config (a run resumes only what it started)."""
    for key in keys:
        was = saved.get(key, LEGACY_FIELD_VALUES.get(key))
        if was != getattr(config, key):
            raise ValueError(
                f"cannot resume: {key}={getattr(config, key)!r} differs from the "
                f"checkpoint's {was!r}; use the same value or a new output folder"
            )


def record_line(r: dict[str, Any]) -> str:
    """One line per trial: cost, success, time upright, mean |x|, wall time (and the
    optimisation figures of a policy trial)."""
    line = (
        f"trial {r['index']} ({r['kind']}, {r['experience_s']:.0f} s of experience): "
        f"cost {r['cost']:.2f}, success {r['success']}, upright {r['time_upright']:.2f} s, "
        f"mean |x| {r['mean_abs_x']:.2f} m, time {r['wall_s']:.1f} s"
    )
    if r["kind"] == "policy":
        line += (
            f" (GP fit {r['gp_fit_s']:.1f} s on N={r['gp_points']}, {r['opt_steps']} opt steps "
            f"x {r['s_per_opt_step']:.3f} s (CPU {r['cpu_s_per_opt_step']:.3f} s), "
            f"J^ {r['opt_final_cost']:.2f})"
        )
        if r.get("compile_error"):
            line += f"; compiling the step failed ({r['compile_error']}): ran eagerly"
        elif r.get("compiled_step") is False:
            line += "; the compiled step failed its check against the eager step: ran eagerly"
    return line


def episode_outcome(ep: dict[str, Any], t0: float) -> dict[str, Any]:
    """The real-system part of a trial record: env cost, ``success``, time upright, mean
    ``|x|`` of episode ``ep``, and the wall-clock since ``t0`` (``time.perf_counter``)."""
    return {
        "cost": ep["cost"],
        "success": ep["success"],
        "time_upright": ep["time_upright"],
        "mean_abs_x": ep["mean_abs_x"],
        "wall_s": time.perf_counter() - t0,
    }


def write_records(out: Path, config: Any, records: list[dict[str, Any]]) -> None:
    """Write ``out/records.json`` (the config and one record per trial) atomically."""
    tmp = out / "records.json.tmp"
    tmp.write_text(json.dumps({"config": config.to_dict(), "records": records}, indent=1))
    tmp.replace(out / "records.json")


# ---------------------------------------------------------------------------------- main
def check_compile_toolchain(device: torch.device) -> None:
    """Raise ValueError when ``compile_rollout`` cannot work here: the native rollout and
    inductor's CPU backend build C++ (``$CXX``, else ``g++`` or ``clang++`` on ``PATH``).
    Checked before any trial runs, so that a missing compiler does not stop the run inside
    its first policy trial."""
    if device.type != "cpu":
        return
    if cpp_compiler() is None:
        names = cpp_compiler_names()
        raise ValueError(
            f"compile_rollout on the CPU needs a C++ compiler ({' or '.join(names)} not found "
            "on PATH): install one (e.g. apt install g++), set CXX, or run without "
            "--compile-rollout"
        )


def run_mcpilco(
    config: MCPilcoConfig,
    out_dir: str | Path,
    resume: bool = False,
    progress: bool = True,
    log: Callable[[str], None] | None = print,
    write_rrd: bool = True,
    overwrite: bool = False,
) -> RunSummary:
    """Run (or resume) MC-PILCO; writes checkpoint, PNGs, ``run.rrd`` and ``records.json``.

    Args:
        config: the experiment.
        out_dir: output folder (created).
        resume: continue from ``out_dir/checkpoint.pt``; finished trials are kept and not
            re-run; ``config.num_trials`` may be larger than in the first call.
        progress: tqdm bars on trials and optimisation steps.
        log: called with one line per trial (None: silent).
        write_rrd: write the Rerun recording.
        overwrite: delete another run found in ``out_dir`` first (else it is refused; the
            folder is locked and its files listed in ``manifest.json``: :mod:`.run_folder`).
    """
    t_start = time.perf_counter()
    out = Path(out_dir)
    run = open_run_folder(out, resume=resume, overwrite=overwrite)
    ckpt_path = out / CHECKPOINT_NAME
    device = resolve_device(config.device)
    if config.compile_rollout:
        check_compile_toolchain(device)
    if config.torch_threads is not None:
        torch.set_num_threads(int(config.torch_threads))
    env = make_env(config.env_id, config.horizon)
    dt = env_dt(env)

    torch.manual_seed(config.seed)
    np_rng = np.random.default_rng(config.seed)
    scales = config.candidate_weight_scales or [config.policy_weight_scale] * config.num_candidates
    candidates = [
        SquashedRBFPolicy(
            num_basis=config.num_basis,
            weight_scale=scale,
            seed=config.seed + CANDIDATE_SEED_STRIDE * k,
        )
        for k, scale in enumerate(scales)
    ]
    policy = candidates[0].to(device)  # the policy applied to the system (the chosen one)
    population = PolicyPopulation(candidates).to(device)
    policy_module = make_policy_module(population)
    model = GPDynamicsModel(
        kernel=config.kernel,
        dt=dt,
        max_points=config.max_points,
        adam_iters=config.gp_adam_iters,
        lbfgs_iters=config.gp_lbfgs_iters,
    )
    episodes: list[dict[str, Any]] = []
    records: list[dict[str, Any]] = []
    arrays: list[dict[str, Any]] = []
    opt_state = None
    start_trial = 0
    resumed_from = None
    if resume:
        ckpt = load_checkpoint(ckpt_path)
        check_resume(ckpt["config"], config, _RESUME_FIXED)
        episodes = ckpt["episodes"]
        records = ckpt["records"]
        arrays = ckpt["arrays"]
        policy.load_state_dict(ckpt["policy"])
        population.load_state_dict(ckpt["population"])
        opt_state = ckpt["optimizer"]
        if ckpt["gp_file"] is not None:
            model.load(out / ckpt["gp_file"])
        set_rng_state(ckpt["rng"], np_rng)
        start_trial = int(ckpt["next_trial"])
        resumed_from = start_trial
        if log:
            log(f"resumed {ckpt_path}: trials 0..{start_trial - 1} done")

    cost_fn = SwingUpCost(l_x=config.l_x, l_theta=config.l_theta, wrap=config.cost_wrap_angle)
    total = config.num_trials + 1
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=total, initial=min(start_trial, total), desc="trials", unit="trial")
    pngs: list[Path] = []
    try:
        for k in range(start_trial, total):
            t0 = time.perf_counter()
            rec: dict[str, Any] = {"index": k, "experience_s": (k + 1) * config.horizon * dt}
            arr: dict[str, Any] = {"index": k, "particles": None, "opt_costs": None}
            if k == 0:
                rec["kind"] = "exploration"
                ep = exploration_episode(
                    env, np_rng, config.seed, config.horizon, config.explore_hold
                )
            else:
                rec["kind"] = "policy"
                # 1. model learning
                t_fit = time.perf_counter()
                model.fit(*transitions(episodes))
                rec["gp_fit_s"] = time.perf_counter() - t_fit
                rec["gp_points"] = int(model.gp_.train_x_.shape[0])
                rec["n_data"] = int(sum(len(e["actions"]) for e in episodes))
                dynamics = model.particle_dynamics(getattr(torch, config.rollout_dtype))

                def make_loss(module, dynamics=dynamics) -> MCPilcoLoss:
                    return MCPilcoLoss(
                        module,
                        dynamics,
                        cost_fn,
                        horizon=config.horizon,
                        num_particles=config.num_particles,
                        init_std=config.init_std,
                        obs_noise_std=config.sim_obs_noise_std,
                    ).to(device)  # with the policy module and the dynamics in it

                loss = make_loss(policy_module)
                if config.compile_rollout:  # compiled, then checked against the eager step
                    rec["compiled_step"] = loss.compile_step(dynamic=False)
                    rec["compile_check"] = loss.compile_check
                    rec["compile_error"] = loss.compile_error
                    rec["compile_backend"] = loss.compile_backend
                    rec["rollout_shards"] = loss.rollout_shards
                # 2. policy update
                opt_cfg = config.opt
                if k == 1 and config.opt_steps_first is not None:
                    opt_cfg = dataclasses.replace(
                        opt_cfg, max_steps=min(opt_cfg.max_steps, config.opt_steps_first)
                    )
                obar = None
                if progress:
                    from tqdm.auto import tqdm

                    obar = tqdm(total=opt_cfg.max_steps, desc=f"trial {k} policy opt", leave=False)

                def on_step(i, c, s, lr, obar=obar):
                    if obar is not None:
                        obar.update(1)
                        if i % 10 == 0:
                            J = c / config.num_candidates
                            obar.set_postfix(J=f"{J:.2f}", std=f"{s:.2f}", lr=f"{lr:.4f}")

                res: OptimizationResult = optimize_policy(
                    loss, population, opt_cfg, on_step=on_step
                )
                if obar is not None:
                    obar.close()
                cand_costs = choose_candidate(loss, population, policy)
                rec.update(
                    opt_steps=res.num_steps,
                    opt_s=res.seconds,
                    s_per_opt_step=res.seconds_per_step,
                    cpu_s_per_opt_step=res.cpu_seconds_per_step,
                    opt_stop=res.stop_reason,
                    opt_lr_reductions=res.num_lr_reductions,
                    opt_reinits=res.num_reinits,
                    opt_final_cost=res.costs[-1] / config.num_candidates if res.costs else math.nan,
                    candidate_costs=cand_costs.tolist(),
                    chosen_candidate=int(cand_costs.argmin()),
                    chosen_cost=float(cand_costs.min()),
                )
                # mean J^_k over candidates per step (J^ itself for one candidate)
                arr["opt_costs"] = np.asarray(res.costs, dtype=np.float32) / config.num_candidates
                # particle predictions of the applied policy (for the plots)
                policy.eval()
                log_loss = make_loss(make_policy_module(policy))
                with torch.no_grad():
                    n_log = min(config.log_particles, config.num_particles)
                    ro = log_loss.rollout(num_particles=n_log)
                arr["particles"] = ro.states.cpu().numpy()
                # 3. apply the policy
                ep = run_episode(
                    env, _policy_act(policy), trial_seed(config.seed, k), config.horizon
                )
                rec["gp_rmse"] = model.one_step_rmse(*transitions([ep])).tolist()
                arr["gp_rmse"] = rec["gp_rmse"]
                opt_state = None  # Adam restarts at each trial (MC-PILCO)
            episodes.append({"obs": ep["obs"], "actions": ep["actions"]})
            rec.update(episode_outcome(ep, t0))
            arr.update(real=ep["states"], **{key: rec[key] for key in ("cost", "success")})
            arr.update(time_upright=rec["time_upright"], mean_abs_x=rec["mean_abs_x"])
            records.append(rec)
            arrays.append(arr)
            # outputs and checkpoint (checkpoint last: it is the commit point of the trial)
            if arr["particles"] is not None:
                pngs.append(
                    plot_trial_particles(
                        out / f"trial_{k:02d}_particles.png",
                        arr["particles"],
                        ep["states"],
                        dt,
                        title=f"trial {k}: particles (model) vs real, success={ep['success']}",
                    )
                )
            _write_outputs(out, config, records, arrays, dt, write_rrd)
            gp_file = None
            if model.gp_ is not None:
                gp_file = f"gp_trial{k:02d}.pt"
                model.save(out / gp_file)
            atomic_torch_save(
                {
                    "version": CHECKPOINT_VERSION,
                    "config": config.to_dict(),
                    "next_trial": k + 1,
                    "episodes": episodes,
                    "records": records,
                    "arrays": arrays,
                    "policy": policy.state_dict(),
                    "population": population.state_dict(),
                    "optimizer": opt_state,
                    "gp_file": gp_file,
                    "rng": rng_state(np_rng),
                },
                ckpt_path,
            )
            for old_gp in out.glob("gp_trial*.pt"):
                if old_gp.name != gp_file:
                    old_gp.unlink(missing_ok=True)
            run.record(*RUN_OUTPUTS)  # the manifest lists every file written so far
            if log:
                log(record_line(rec))
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
        env.close()
        run.close()
    if not pngs:
        pngs = sorted(out.glob("trial_*_particles.png"))
    opt_png = out / "optimisation.png"
    return RunSummary(
        config=config.to_dict(),
        records=records,
        out_dir=out,
        checkpoint=ckpt_path,
        rrd=(out / "run.rrd") if write_rrd else None,
        pngs=pngs + ([opt_png] if opt_png.exists() else []),
        seconds=time.perf_counter() - t_start,
        resumed_from_trial=resumed_from,
    )


def _write_outputs(
    out: Path,
    config: MCPilcoConfig,
    records: list[dict[str, Any]],
    arrays: list[dict[str, Any]],
    dt: float,
    write_rrd: bool,
) -> None:
    curves = [(a["opt_costs"], f"trial {a['index']}") for a in arrays if a["opt_costs"] is not None]
    if curves:
        plot_optimisation(out / "optimisation.png", [c for c, _ in curves], [n for _, n in curves])
    if write_rrd:
        write_rerun_recording(out / "run.rrd", arrays, dt)
    write_records(out, config, records)
