"""Outer loop of MC-PILCO (thesis Algorithm 1): explore, fit GP, optimise policy, apply, repeat.

Glossary
--------
The task (state layout, cost, success test, action bounds) comes from a
:class:`~mcpilco.agents.mc_pilco.task.TaskSpec`, the hyperparameters from an
:class:`MCPilcoConfig` (per-env YAML files, :func:`load_config`).

trial ``k = 0``
    random exploration for ``H`` steps: actions ``u ~ U(low, high)``, each drawn once per
    ``explore_hold`` control steps.
trial ``k >= 1``
    fit the velocity-change GPs on all transitions ``D`` by marginal likelihood (fresh
    hyperparameters each trial; subset of data beyond ``max_points``), optimise the policy on the
    particle estimate ``J^`` (5.8) with the monitoring rule, apply the policy (no dropout)
    to the env for ``H`` steps, append the transitions to ``D``.
experience
    ``H T_s (k + 1)`` seconds after trial ``k`` (3, 6, 9, 12, 15 s ... on the cart-pole).
record of a trial
    the task's evaluation cost ``sum_t c(x_t)`` on the true state, ``success`` (the task's
    test), the time spent within the task's goal bounds, wall-clock of the GP fit, of
    the optimisation and of the trial, optimisation steps and seconds per step, the one-step
    GP error on the trial's data (model fitted before the trial), and the particle
    predictions of the final policy.

After every trial the run is checkpointed atomically (:mod:`.checkpoint`): data, policy,
GP state, optimiser and RNG states, records. ``resume=True`` continues from it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mcpilco.agents.common.run_folder import RUN_OUTPUTS, open_run_folder
from mcpilco.agents.mc_pilco.backends import BACKENDS, use_fast_rollout
from mcpilco.agents.mc_pilco.checkpoint import (
    CHECKPOINT_VERSION,
    atomic_torch_save,
    load_checkpoint,
    restore_state,
    rng_state,
    set_rng_state,
)
from mcpilco.agents.mc_pilco.cost import SaturatingCost
from mcpilco.agents.mc_pilco.dynamics import KERNEL_CHOICES, GPDynamicsModel, check_mpk_degree
from mcpilco.agents.mc_pilco.features import StateLayout
from mcpilco.agents.mc_pilco.filters import CollisionFilter, contact_steps
from mcpilco.agents.mc_pilco.loss import MCPilcoLoss
from mcpilco.agents.mc_pilco.native_rollout import cpp_compiler, cpp_compiler_names
from mcpilco.agents.mc_pilco.optimize import OptimizationResult, PolicyOptConfig, optimize_policy
from mcpilco.agents.mc_pilco.policy import (
    PolicyPopulation,
    SquashedRBFPolicy,
    data_init,
    make_policy_module,
)
from mcpilco.agents.mc_pilco.task import ANGLE_MODES, TaskSpec
from mcpilco.agents.mc_pilco.viz import (
    plot_optimisation,
    plot_trial_particles,
    write_rerun_recording,
)
from mcpilco.models.device import check_device_name, resolve_device
from mcpilco.models.safe_io import atomic_write

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
    "explore_steps",
    "env_kwargs",
    "policy_init",
    "push_filter",
)
ROLLOUT_DTYPES = ("float32", "float64")
"""Choices of :attr:`MCPilcoConfig.rollout_dtype`."""
CONF_DIR = Path(__file__).resolve().parent / "conf"
"""The shipped per-env config files (one YAML file per env id)."""
LEGACY_FIELD_VALUES: dict[str, Any] = {"explore_hold": 1, "policy_init": "box", "push_filter": None}
"""Value of each config field added after results were saved, for configs that lack it."""
CANDIDATE_SEED_STRIDE = 7919
"""Candidate ``k`` of run ``seed`` is initialised with seed ``seed + 7919 k``."""


POLICY_INITS = ("box", "data")  # MCPilcoConfig.policy_init
# range of each number of MCPilcoConfig (mcpilco.envs.numbers.check_number keywords): what a
# run on one machine can hold (particles x horizon x candidates tensors, GP subsets)
CONFIG_NUMBER_RANGES: dict[str, dict[str, Any]] = {
    "num_trials": {"lo": 0, "hi": 10_000, "integer": True},
    "horizon": {"lo": 1, "hi": 10_000_000, "integer": True},
    "num_particles": {"lo": 1, "hi": 100_000, "integer": True},
    "max_points": {"lo": 10, "hi": 100_000, "integer": True},
    "gp_adam_iters": {"lo": 0, "hi": 1_000_000, "integer": True},
    "gp_lbfgs_iters": {"lo": 0, "hi": 1_000_000, "integer": True},
    "gp_noise_min": {"lo": 0.0, "hi": 1.0},
    "gp_min_lengthscale": {"lo": 1e-9, "hi": 1e9},
    "num_basis": {"lo": 1, "hi": 100_000, "integer": True},
    "policy_weight_scale": {"lo": 0.0, "hi": 1e6},
    "policy_centers_box": {"lo": 0.0, "hi": 1e6, "lo_open": True},
    "push_filter_margin": {"lo": 0, "hi": 100_000, "integer": True},
    "num_candidates": {"lo": 1, "hi": 1_000, "integer": True},
    "explore_hold": {"lo": 1, "hi": 10_000_000, "integer": True},
    "explore_steps": {"lo": 1, "hi": 10_000_000, "integer": True},
    "init_std": {"lo": 0.0, "hi": 1e6},
    "sim_obs_noise_std": {"lo": 0.0, "hi": 1e6},
    "opt_steps_first": {"lo": 1, "hi": 10_000_000, "integer": True},
    "log_particles": {"lo": 0, "hi": 100_000, "integer": True},
    "seed": {"lo": 0, "hi": 2**32 - 1, "integer": True},
    "torch_threads": {"lo": 1, "hi": 4096, "integer": True},
}


@dataclass
class MCPilcoConfig:
    """One MC-PILCO experiment: the agent's hyperparameters (the task is a
    :class:`~mcpilco.agents.mc_pilco.task.TaskSpec`). Per-env values live in YAML files
    (:func:`load_config`); the defaults here are MC-PILCO's (thesis 5.5.1).

    Attributes:
        env_id: registered Gymnasium id (``import mcpilco.envs`` registers ``mcpilco/...``).
        task: the task as plain data (a task file's content) for an env without a shipped
            task; None: the task that ships for ``env_id``.
        num_trials: policy trials after the exploration trial.
        horizon: ``H``, steps per trial and of the particle rollout (None: the task's).
        num_particles: ``M``.
        kernel: ``"rbf+mpk"``, ``"rbf"`` or ``"rigid_body"`` (an arm task's structured
            kernel on ``[q, qd, tau, w]``; :mod:`.dynamics`). The chained rollouts (native,
            torch) have no backward for the rigid-body posterior: with it,
            ``rollout_backend="auto"`` runs the eager rollout (one line says so) and
            ``"native"`` / ``"torch"`` are refused here.
        max_points: GP subset-of-data size.
        gp_adam_iters, gp_lbfgs_iters: marginal-likelihood budget per fit.
        gp_noise_min: lower bound of each dynamics GP's noise variance, as a fraction of its
            output's variance.
        gp_min_lengthscale: lower bound of the RBF lengthscales on standardised inputs (None:
            none); keeps noise-free simulated data from shrinking one to a delta kernel,
            which overflows a float32 rollout (:func:`~.dynamics.make_kernel_factory`).
        mpk_degree: degree of the MPK of ``kernel="rbf+mpk"``: 2 (quadratic features of the
            GP inputs, the thesis's cart-pole) or 1 (affine, the MC-PILCO reference's arm
            task; far fewer features on many inputs). The native rollout takes 1 and 2.
        num_basis: policy basis functions.
        policy_weight_scale: initial policy weights ``w ~ U(-s, s) u_half``. Small, so that the
            initial policy is close to the middle of the action range.
        policy_centers_box: half width of the box the centres of the plain state coordinates
            are drawn in.
        push_filter: path of a collision-detector file (``CollisionDetector.save``): the
            transitions in which it alarms are kept out of the dynamics data, with
            ``push_filter_margin`` transitions before and after (:mod:`.filters`; an arm
            task whose env reports motor currents). None: every transition is data.
        policy_init: ``"box"`` (centres in the box, the thesis's initialisation) or
            ``"data"``: before the first policy optimisation, centres and lengthscales are
            re-drawn from the spread of the exploration trial's states
            (:func:`~mcpilco.agents.mc_pilco.policy.data_init`), which a state of many
            coordinates needs.
        cost_length_scales: length scales of the optimised cost by state name (None: the
            task's evaluation cost's). Success and the reported cost always come from the
            task's evaluation cost.
        cost_angle_mode: ``"wrap"`` or ``"abs"`` for the angle terms of the optimised cost
            (None: the task's); see :mod:`.cost`.
        cost_limit_widths: width ``s_k`` of the barrier the optimised cost puts at the task's
            declared limits of state ``k``, by state name (:mod:`.cost`); None: no barrier.
        num_candidates: ``K`` candidate policies optimised side by side (``M`` particles
            each; :class:`~mcpilco.agents.mc_pilco.policy.PolicyPopulation`); the one with
            the lowest ``J^`` (fresh particles, no dropout) is applied. 1: plain MC-PILCO.
        candidate_weight_scales: initial weight scale ``s_k`` of each candidate ``k``
            (length ``K``); None: ``policy_weight_scale`` for all.
        explore_hold: control steps each random action of the exploration trial is held
            (``u ~ U(low, high)`` drawn once per ``explore_hold`` steps; 1: i.i.d.).
        explore_steps: steps of the exploration trial (None: the horizon). A task whose
            policy trials need a longer horizon than the data a first model needs can start
            with a shorter random trial.
        env_kwargs: keyword arguments of ``gym.make`` besides the episode length (for
            example an env's own episode-length argument when the horizon changes).
        init_std: ``sigma_0`` of the initial particles (None: the task's).
        sim_obs_noise_std: measurement noise simulated on the policy input in rollouts.
        opt: policy optimisation schedule (:class:`PolicyOptConfig`).
        opt_steps_first: optimisation steps of the first policy trial, when smaller than
            ``opt.max_steps`` (thesis 5.5.1: fewer steps while the model is poor); None = same.
        log_particles: particles kept per trial for the PNG / Rerun plots.
        seed: seeds torch, numpy and the env resets.
        torch_threads: ``torch.set_num_threads`` (None: leave as is).
        compile_rollout: use a fast rollout with its backward
            (:func:`~mcpilco.agents.mc_pilco.backends.use_fast_rollout`, backend
            ``rollout_backend``); each trial checks it against the eager rollout (``J^`` and
            its gradient) and runs eagerly if they disagree (the trial record's
            ``compiled_step``, ``compile_backend``, ``rollout_shards`` and ``compile_check``).
            The native and dynamo backends need a C++ compiler on the CPU.
        rollout_backend: ``"auto"`` (default: the native C++ rollout where it applies, else
            ``torch.compile`` of the time step), ``"native"``, ``"torch"`` (the same chained
            maths in plain PyTorch ops) or ``"dynamo"``.
        rollout_dtype: dtype of the GP posterior evaluated in the particle rollout,
            ``"float32"`` (default) or ``"float64"``; the particles, the policy and the GP
            fit are the same in both (float32, float32, float64).
        device: where the policy optimisation runs (policy, particles, GP posterior):
            ``"cpu"`` (default) or ``"cuda"`` / ``"cuda:<index>"``. The GP fit (float64,
            ``N <= max_points``) and the env stay on the CPU.
    """

    env_id: str = DEFAULT_ENV_ID
    task: dict[str, Any] | None = None
    num_trials: int = 5
    horizon: int | None = None
    num_particles: int = 400
    kernel: str = "rbf+mpk"
    max_points: int | None = 300
    gp_adam_iters: int = 200
    gp_lbfgs_iters: int = 100
    gp_noise_min: float = 1e-8
    gp_min_lengthscale: float | None = None
    mpk_degree: int = 2
    num_basis: int = 200
    policy_weight_scale: float = 0.01
    policy_centers_box: float = math.pi
    policy_init: str = "box"
    push_filter: str | None = None
    push_filter_margin: int = 1
    cost_length_scales: dict[str, float] | None = None
    cost_angle_mode: str | None = None
    cost_limit_widths: dict[str, float] | None = None
    num_candidates: int = 1
    candidate_weight_scales: list[float] | None = None
    explore_hold: int = 1
    explore_steps: int | None = None
    env_kwargs: dict[str, Any] | None = None
    init_std: float | None = None
    sim_obs_noise_std: float = 0.01
    opt: PolicyOptConfig = field(default_factory=PolicyOptConfig)
    opt_steps_first: int | None = None
    log_particles: int = 100
    seed: int = 0
    torch_threads: int | None = None
    compile_rollout: bool = False
    rollout_backend: str = "auto"
    rollout_dtype: str = "float32"
    device: str = "cpu"

    def __post_init__(self) -> None:
        from mcpilco.envs.numbers import check_number

        for name, rule in CONFIG_NUMBER_RANGES.items():
            if getattr(self, name) is not None:
                setattr(self, name, check_number(getattr(self, name), name, **rule))
        for name in ("cost_length_scales", "cost_limit_widths"):
            for key, v in (
                (getattr(self, name) or {}).items() if isinstance(getattr(self, name), dict) else ()
            ):
                check_number(v, f"{name}.{key}", lo=1e-9, hi=1e9)
        if not isinstance(self.compile_rollout, bool):
            raise ValueError(f"compile_rollout must be true or false, got {self.compile_rollout!r}")
        if isinstance(self.opt, dict):
            unknown = sorted(set(self.opt) - {f.name for f in dataclasses.fields(PolicyOptConfig)})
            if unknown:
                raise ValueError(f"unknown opt fields {unknown}")
            self.opt = PolicyOptConfig(**self.opt)
        for name in ("num_particles", "num_candidates", "explore_hold", "num_basis"):
            v = getattr(self, name)
            if isinstance(v, bool) or int(v) != v or v < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        if int(self.num_trials) != self.num_trials or self.num_trials < 0:
            raise ValueError(f"num_trials must be an integer >= 0, got {self.num_trials!r}")
        for name in ("horizon", "explore_steps"):
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or int(v) != v or v < 1):
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        if self.env_kwargs is not None and not isinstance(self.env_kwargs, dict):
            raise ValueError(f"env_kwargs must be a mapping, got {self.env_kwargs!r}")
        if self.candidate_weight_scales is not None:
            scales = [float(v) for v in self.candidate_weight_scales]
            if len(scales) != self.num_candidates or not all(v > 0 for v in scales):
                raise ValueError(
                    f"candidate_weight_scales must hold num_candidates={self.num_candidates} "
                    f"positive values, got {self.candidate_weight_scales!r}"
                )
            self.candidate_weight_scales = scales
        if self.rollout_dtype not in ROLLOUT_DTYPES:
            raise ValueError(
                f"rollout_dtype must be one of {ROLLOUT_DTYPES}, got {self.rollout_dtype!r}"
            )
        if self.policy_init not in POLICY_INITS:
            raise ValueError(f"policy_init must be one of {POLICY_INITS}, got {self.policy_init!r}")
        if self.kernel not in KERNEL_CHOICES:
            raise ValueError(f"kernel must be one of {KERNEL_CHOICES}, got {self.kernel!r}")
        if self.rollout_backend not in BACKENDS:
            raise ValueError(
                f"rollout_backend must be one of {BACKENDS}, got {self.rollout_backend!r}"
            )
        if self.kernel == "rigid_body" and self.rollout_backend in ("native", "torch"):
            raise ValueError(
                f"rollout_backend={self.rollout_backend!r} cannot run kernel='rigid_body' (no "
                "chained backward for its posterior); use 'auto' (eager rollout) or 'dynamo'"
            )
        if self.cost_angle_mode is not None and self.cost_angle_mode not in ANGLE_MODES:
            raise ValueError(
                f"cost_angle_mode must be one of {ANGLE_MODES} or None, got "
                f"{self.cost_angle_mode!r}"
            )
        if self.cost_length_scales is not None:
            if not isinstance(self.cost_length_scales, dict) or not all(
                float(v) > 0 for v in self.cost_length_scales.values()
            ):
                raise ValueError(
                    "cost_length_scales must map state names to positive length scales, got "
                    f"{self.cost_length_scales!r}"
                )
            self.cost_length_scales = {str(k): float(v) for k, v in self.cost_length_scales.items()}
        if self.cost_limit_widths is not None:
            widths = self.cost_limit_widths
            if not isinstance(widths, dict) or not all(
                _is_positive_number(v) for v in widths.values()
            ):
                raise ValueError(
                    f"cost_limit_widths must map state names to positive widths, got {widths!r}"
                )
            self.cost_limit_widths = {str(k): float(v) for k, v in widths.items()}
        self.device = str(check_device_name(self.device))
        if not (math.isfinite(self.gp_noise_min) and self.gp_noise_min >= 0):
            raise ValueError(f"gp_noise_min must be a finite value >= 0, got {self.gp_noise_min}")
        if self.gp_min_lengthscale is not None and not (
            _is_positive_number(self.gp_min_lengthscale) and math.isfinite(self.gp_min_lengthscale)
        ):
            raise ValueError(
                f"gp_min_lengthscale must be a finite value > 0 or None, got "
                f"{self.gp_min_lengthscale!r}"
            )
        check_mpk_degree(self.mpk_degree)
        if self.max_points is not None and self.max_points < 10:
            raise ValueError(f"max_points must be >= 10 or None, got {self.max_points}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def with_overrides(self, opt_steps: int | None = None, **fields: Any) -> MCPilcoConfig:
        """A validated copy with ``fields`` replaced; ``None`` values leave a field as is.

        ``opt_steps`` sets ``opt.max_steps`` and caps ``opt_steps_first`` at it (the
        command-line ``--opt-steps`` of the scripts).
        """
        over = {k: v for k, v in fields.items() if v is not None}
        if opt_steps is not None:
            over["opt"] = dataclasses.replace(self.opt, max_steps=opt_steps)
            if self.opt_steps_first is not None:
                over["opt_steps_first"] = min(self.opt_steps_first, opt_steps)
        return dataclasses.replace(self, **over)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> MCPilcoConfig:
        """Inverse of :meth:`to_dict`; unknown fields are an error that names them. Configs
        saved with the cart-pole's cost fields ``l_x``, ``l_theta``, ``cost_wrap_angle`` read
        as the same cost (``cost_length_scales``, ``cost_angle_mode``)."""
        d = dict(d)
        if {"l_x", "l_theta", "cost_wrap_angle"} & set(d):
            d.setdefault(
                "cost_length_scales", {"x": d.pop("l_x", 1.0), "theta": d.pop("l_theta", 3.0)}
            )
            d.setdefault("cost_angle_mode", "wrap" if d.pop("cost_wrap_angle", False) else "abs")
            d.pop("l_x", None), d.pop("l_theta", None), d.pop("cost_wrap_angle", None)
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"unknown MC-PILCO config fields {unknown} (fields: {sorted(known)})")
        return cls(**{**LEGACY_FIELD_VALUES, **d})

    def task_spec(self) -> TaskSpec:
        """The task: ``task`` when given, else the one that ships for ``env_id``; the
        config's ``horizon`` replaces the task's."""
        spec = TaskSpec.from_dict(self.task) if self.task else TaskSpec.for_env(self.env_id)
        if spec.env_id != self.env_id:
            raise ValueError(f"the task is for {spec.env_id!r}, the config for {self.env_id!r}")
        if self.horizon is not None and self.horizon != spec.horizon:
            spec = spec.replace(horizon=int(self.horizon))
        return spec


def _is_positive_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) and v > 0


def parse_set(items: list[str] | None) -> dict[str, Any]:
    """``["a=1", "opt.max_steps=500", "cost_length_scales={x: 1}"]`` -> a nested dict of
    overrides (:func:`~mcpilco.envs.yaml_files.parse_overrides`: each value parsed by the
    package's one YAML loader, bounded, YAML 1.2 numbers)."""
    from mcpilco.envs.yaml_files import parse_overrides

    return parse_overrides(items, "--set")


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def config_files(conf_dir: str | Path = CONF_DIR) -> dict[str, Path]:
    """Env id -> per-env config file (``*.yaml`` in ``conf_dir`` with an ``env_id`` key)."""
    from mcpilco.envs.yaml_files import read_yaml

    out = {}
    for path in sorted(Path(conf_dir).glob("*.yaml")):
        data = read_yaml(path, "MC-PILCO config file")
        if "env_id" in data:
            out[str(data["env_id"])] = path
    return out


def load_config(
    env_id: str,
    conf_dir: str | Path | None = CONF_DIR,
    preset: str | None = None,
    overrides: dict[str, Any] | None = None,
) -> MCPilcoConfig:
    """The config of ``env_id``: :class:`MCPilcoConfig`'s defaults, then the env's file in
    ``conf_dir`` (default: the shipped :data:`CONF_DIR`; None: no file): its ``config``
    mapping, then the named ``preset`` of its ``presets``; then ``overrides`` (nested dicts,
    e.g. from :func:`parse_set`).

    A config file (one per env, like the SB3 zoo's ``hyperparams/*.yml``)::

        env_id: mcpilco/CartpoleSwingUp-v0
        config:                 # each value with a comment saying where it comes from
          num_particles: 400
        presets:
          demo: {num_trials: 3}
    """
    from mcpilco.envs.yaml_files import read_yaml

    data: dict[str, Any] = {}
    path = config_files(conf_dir).get(env_id) if conf_dir is not None else None
    if path is not None:
        data = read_yaml(path, "MC-PILCO config file")
    merged: dict[str, Any] = {"env_id": env_id}
    merged = _merge(merged, data.get("config") or {})
    presets = data.get("presets") or {}
    if preset is not None and preset != "default":
        if preset not in presets:
            where = f"{path.name}" if path else f"no config file for {env_id}"
            raise ValueError(
                f"unknown preset {preset!r} for {env_id} ({where}; presets: "
                f"{sorted(presets) or 'none'})"
            )
        merged = _merge(merged, presets[preset])
    merged = _merge(merged, overrides or {})
    if merged.get("env_id") != env_id:
        raise ValueError(f"the config names env {merged.get('env_id')!r}, not {env_id!r}")
    return MCPilcoConfig.from_dict(merged)


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


def make_env(
    env_id: str,
    horizon: int,
    task: TaskSpec | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
):
    """``gym.make(env_id, **env_kwargs)`` with episodes of ``horizon`` control steps
    (``horizon`` times the task's ``action_repeat`` env steps), clear errors for an unknown
    id, for spaces that do not fit ``task`` (:meth:`TaskSpec.check_env`), and for a horizon
    that differs from the env's own episode length when the task's success is the env's
    ``info`` flag (defined at the env's own last step), and for ``render_mode="human"``
    where no window can open (:func:`mcpilco.envs.display.check_render_mode`)."""
    import gymnasium as gym

    import mcpilco.envs  # noqa: F401  (registers the ids)
    from mcpilco.envs.display import check_render_mode

    if env_id not in gym.registry:
        raise ValueError(
            f"unknown env id {env_id!r}; registered mcpilco ids: {', '.join(registered_ids())}"
        )
    steps = gym.spec(env_id).max_episode_steps
    horizon = int(horizon) * (task.action_repeat if task is not None else 1)
    if steps is not None and steps != horizon and task is not None and task.success.info_key:
        raise ValueError(
            f"horizon mismatch: the config's horizon is {horizon} steps but {env_id} episodes "
            f"last {steps} steps (its success flag is set at its last step); set horizon={steps}"
        )
    kwargs = dict(env_kwargs or {})
    # "human" needs a window: refused with one line where none can open (a GLFW or pygame
    # window on a machine without a display aborts or raises deep inside the env)
    check_render_mode(kwargs.get("render_mode"), ("rgb_array", "depth_array"))
    env = gym.make(env_id, max_episode_steps=int(horizon), **kwargs)
    if task is not None:
        try:
            task.check_env(env)
        except ValueError:
            env.close()
            raise
    return env


def env_dt(env, task: TaskSpec | None = None) -> float:
    """The control period: the task's, else the env's ``dt``."""
    if task is not None:
        return float(task.dt)
    return float(env.unwrapped.dt)


def run_episode(
    env,
    act: Callable[[np.ndarray], np.ndarray],
    seed: int,
    horizon: int,
    task: TaskSpec,
    record_info: bool = False,
) -> dict[str, Any]:
    """One episode of at most ``horizon`` control steps under ``act(state)``, each action held
    for the task's ``action_repeat`` env steps (the observation after the last is the next
    state). ``record_info``: also return ``infos``, per control step the ``info`` dicts of
    its env steps (what a push filter reads, :mod:`.filters`).

    Returns the observed states ``obs`` (T+1, n) (read from the observations by the task),
    the true states ``states`` (T+1, n), ``actions`` (T, A), per-step evaluation ``costs``,
    their sum ``cost``, ``success`` (the task's test), ``time_in_goal`` [s] (steps within
    the task's success bounds times ``T_s``), ``final_info`` (the numeric scalars of the last
    step's ``info``, e.g. the marker camera's pose errors) and, for a task whose cost tracks states,
    ``tracking_rms`` (:meth:`TaskSpec.tracking_rms`).

    Raises:
        RuntimeError: the env truncated the episode before ``horizon`` steps (a time limit of
            its own, shorter than the horizon; a termination ends the episode normally).
    """
    obs, info = env.reset(seed=seed, options=task.reset_options())
    observed = [task.state_from_obs(obs)]
    states = [task.true_state(obs, info)]
    actions = []
    infos: list[list[dict[str, Any]]] = []
    low, high = np.asarray(task.action_low), np.asarray(task.action_high)
    for _ in range(horizon):
        a = np.clip(np.asarray(act(observed[-1]), dtype=np.float64).reshape(-1), low, high)
        step_infos = []
        for _ in range(task.action_repeat):
            obs, _, terminated, truncated, info = env.step(a.astype(np.float32))
            if record_info:
                step_infos.append(info)
            if terminated or truncated:
                break
        if record_info:
            infos.append(step_infos)
        observed.append(task.state_from_obs(obs))
        states.append(task.true_state(obs, info))
        actions.append(a)
        if terminated or truncated:
            break
    if truncated and not terminated and len(actions) < horizon:
        name = env.spec.id if env.spec is not None else type(env.unwrapped).__name__
        raise RuntimeError(
            f"{name} truncated the episode after {len(actions)} of the horizon's {horizon} "
            "control steps (its own episode length is shorter than the horizon): pass the "
            "env's episode-length argument in the config's env_kwargs"
        )
    states_arr = np.stack(states)
    costs = task.cost(states_arr[1:])
    steps = len(actions)
    extra: dict[str, Any] = {"infos": infos} if record_info else {}
    if task.tracked_states():
        extra["tracking_rms"] = task.tracking_rms(states_arr)
    return {
        **extra,
        "obs": np.stack(observed),
        "states": states_arr,
        "actions": np.stack(actions) if actions else np.zeros((0, task.action_dim)),
        "costs": np.asarray(costs),
        "success": task.is_success(states_arr[1:], info, steps),
        "cost": float(np.sum(costs)),
        "time_in_goal": float(np.sum(task.in_goal(states_arr[1:])) * task.dt),
        "steps": steps,
        "final_info": {
            k: float(v)
            for k, v in info.items()
            if isinstance(v, int | float | np.number) and not isinstance(v, bool | np.bool_)
        },
    }


# ------------------------------------------------------------------------------- helpers
def _policy_act(policy: SquashedRBFPolicy) -> Callable[[np.ndarray], np.ndarray]:
    policy.eval()
    device = policy.weights.device

    @torch.no_grad()
    def act(state: np.ndarray) -> np.ndarray:
        x = torch.as_tensor(state, dtype=torch.float32, device=device)[None]
        return policy(x)[0].cpu().numpy()

    return act


@torch.no_grad()
def choose_policy(
    loss: MCPilcoLoss,
    population: PolicyPopulation,
    policy: SquashedRBFPolicy,
    snapshots: Sequence[tuple[int, Sequence[torch.Tensor]]] = (),
    repeats: int = 4,
) -> tuple[torch.Tensor, int]:
    """The policy to apply: the candidate and parameter snapshot with the lowest ``J^``.

    ``J^`` of every candidate in every snapshot (``(steps, parameter copies)`` as in
    :attr:`~.optimize.OptimizationResult.snapshots`; none: the population's current
    parameters) is the mean of ``repeats`` rollouts without dropout. With several snapshots,
    each is evaluated on the same random numbers (particles, noise), so that their
    difference is the policies' and not the draws'. The population is left at the chosen
    snapshot and the chosen candidate is copied into ``policy``.

    Returns:
        ``J^`` per snapshot and candidate ``(S, K)`` and the chosen snapshot's index.
    """
    params = [p for p in population.parameters() if p.requires_grad]
    values = [list(v) for _, v in snapshots] or [[p.detach().clone() for p in params]]
    population.eval()
    device = params[0].device
    seed = int(torch.randint(2**62, ())) if len(values) > 1 else None
    costs = []
    for vals in values:
        for p, v in zip(params, vals, strict=True):
            p.copy_(v)
        same_draws = (
            contextlib.nullcontext()
            if seed is None
            else torch.random.fork_rng(devices=[device] if device.type == "cuda" else [])
        )
        with same_draws:
            if seed is not None:
                torch.manual_seed(seed)
            costs.append(torch.stack([loss()["candidate_costs"] for _ in range(repeats)]).mean(0))
    table = torch.stack(costs)
    s, k = divmod(int(table.argmin()), table.shape[1])
    for p, v in zip(params, values[s], strict=True):
        p.copy_(v)
    population.copy_to(k, policy)
    return table, s


def transitions(
    episodes: list[dict[str, Any]], task: TaskSpec | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(s_t, a_t, s_{t+1})`` of all episodes (observed states), stacked. With ``task``, the
    transitions that touch one of its declared limits are left out
    (:meth:`~.task.TaskSpec.touches_limit`), and so are those an episode's ``filtered`` mask
    marks (a push filter's, :mod:`.filters`): the dynamics data of the free motion."""
    s = np.concatenate([e["obs"][:-1] for e in episodes])
    a = np.concatenate([e["actions"] for e in episodes])
    s1 = np.concatenate([e["obs"][1:] for e in episodes])
    free = np.ones(len(a), dtype=bool)
    if task is not None and task.limits:
        free &= ~task.touches_limit(s, s1)
    if any(e.get("filtered") is not None for e in episodes):  # a push filter's marks
        free &= ~np.concatenate(
            [
                np.zeros(len(e["actions"]), bool) if e.get("filtered") is None else e["filtered"]
                for e in episodes
            ]
        )
    return s[free], a[free], s1[free]


def trial_seed(seed: int, k: int) -> int:
    """Env reset seed of trial ``k`` of run ``seed`` (shared by MC-PILCO and its baselines)."""
    return int(seed) * 10_007 + int(k)


def exploration_actions(
    rng: np.random.Generator, horizon: int, hold: int = 1, low=(-1.0,), high=(1.0,)
) -> np.ndarray:
    """``(horizon, A)`` random actions: ``ceil(horizon / hold)`` draws ``u ~ U(low, high)``
    from ``rng``, each repeated for ``hold`` steps (``hold = 1``: i.i.d. per step)."""
    if int(hold) != hold or hold < 1:
        raise ValueError(f"hold must be an integer >= 1, got {hold!r}")
    low, high = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
    draws = rng.uniform(low, high, size=(-(-horizon // hold), low.size))
    return np.repeat(draws, hold, axis=0)[:horizon]


def exploration_episodes(
    env,
    rng: np.random.Generator,
    seed: int,
    horizon: int,
    task: TaskSpec,
    hold: int = 1,
    min_steps: int | None = None,
    record_info: bool = False,
) -> list[dict[str, Any]]:
    """Trial 0: episodes under the random actions of :func:`exploration_actions`.

    The first episode runs ``horizon`` steps from the reset seed ``trial_seed(seed, 0)``
    (fewer when the env terminates it). With ``min_steps``, further episodes follow, each
    reset from the env's own generator (seeded by the first reset) and at most ``horizon``
    steps long, the last one cut so that exactly ``min_steps`` steps are taken in all: a
    random rollout of ``min_steps`` steps that resets whenever an episode ends, as in
    TorchRL's PILCO example (``initial_rollout_length``). Returns the episodes in order
    (:func:`run_episode`'s dicts).
    """
    if min_steps is not None and (int(min_steps) != min_steps or min_steps < 1):
        raise ValueError(f"min_steps must be a positive integer, got {min_steps!r}")
    episodes: list[dict[str, Any]] = []
    taken, reset_seed = 0, trial_seed(seed, 0)
    while not episodes or (min_steps is not None and taken < min_steps):
        n = horizon if not episodes else min(horizon, int(min_steps) - taken)
        it = iter(exploration_actions(rng, n, hold, task.action_low, task.action_high))
        ep = run_episode(env, lambda _o, it=it: next(it), reset_seed, n, task, record_info)
        episodes.append(ep)
        taken += ep["steps"]
        reset_seed = None
    return episodes


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
    """One line per trial: cost, success, time in the goal region, wall time (and the
    optimisation figures of a policy trial)."""
    line = (
        f"trial {r['index']} ({r['kind']}, {r['experience_s']:.0f} s of experience): "
        f"cost {r['cost']:.2f}, success {r['success']}, in goal {r['time_in_goal']:.2f} s, "
        f"time {r['wall_s']:.1f} s"
    )
    if r.get("tracking_rms"):
        line += ", tracking RMS " + " / ".join(f"{v:.4f}" for v in r["tracking_rms"].values())
    if r["kind"] == "policy":
        line += (
            f" (GP fit {r['gp_fit_s']:.1f} s on N={r['gp_points']}, {r['opt_steps']} opt steps "
            f"x {r['s_per_opt_step']:.3f} s (CPU {r['cpu_s_per_opt_step']:.3f} s), "
            f"J^ {r['opt_final_cost']:.2f})"
        )
        if r.get("n_filtered") is not None:
            line += f"; {r['n_filtered']} transitions filtered as pushes"
            if r.get("n_contact") is not None:
                line += f" ({r.get('n_filtered_contact', 0)} of the {r['n_contact']} pushed)"
        if r.get("n_at_limits"):
            line += f"; {r['n_at_limits']} transitions at the task's limits left out of the GP data"
        if r.get("compile_error"):
            line += f"; compiling the step failed ({r['compile_error']}): ran eagerly"
        elif r.get("compiled_step") is False:
            line += "; the compiled step failed its check against the eager step: ran eagerly"
    return line


def episode_outcome(ep: dict[str, Any], t0: float) -> dict[str, Any]:
    """The real-system part of a trial record: evaluation cost, ``success``, time in the goal
    region of episode ``ep``, its ``tracking_rms`` where it has one, and the wall-clock since
    ``t0`` (``time.perf_counter``)."""
    out = {
        "cost": ep["cost"],
        "success": ep["success"],
        "time_in_goal": ep["time_in_goal"],
        "steps": ep["steps"],
        "wall_s": time.perf_counter() - t0,
    }
    if "tracking_rms" in ep:
        out["tracking_rms"] = ep["tracking_rms"]
    return out


def write_records(out: Path, config: Any, records: list[dict[str, Any]]) -> None:
    """Write ``out/records.json`` (the config and one record per trial) atomically."""
    text = json.dumps({"config": config.to_dict(), "records": records}, indent=1)
    atomic_write(out / "records.json", text)  # a link at records.json.tmp is refused


# ---------------------------------------------------------------------------------- main
def check_compile_toolchain(device: torch.device, backend: str = "auto") -> None:
    """Raise ValueError when ``compile_rollout`` with ``backend`` cannot work here: the
    native rollout and inductor's CPU backend build C++ (``$CXX``, else ``g++`` or
    ``clang++`` on ``PATH``); the torch backend needs none. Checked before any trial runs,
    so that a missing compiler does not stop the run inside its first policy trial."""
    if device.type != "cpu" or backend == "torch":
        return
    if cpp_compiler() is None:
        names = cpp_compiler_names()
        raise ValueError(
            f"compile_rollout on the CPU needs a C++ compiler ({' or '.join(names)} not found "
            "on PATH): install one (e.g. apt install g++), set CXX, use the torch backend "
            "(--set rollout_backend=torch), or run without --compile-rollout"
        )


def check_dynamics_task(task: TaskSpec) -> None:
    """Raise ``ValueError`` for a task on which MC-PILCO learns kinematics, not dynamics
    (``TaskSpec.model``): the agent of this module cannot run it."""
    if task.model != "dynamics":
        raise ValueError(
            f"{task.env_id}: MC-PILCO learns the {task.model} on this task, not GP dynamics; "
            "run it with mcpilco-bench-kinematics --reaching-seeds (mcpilco.agents.mc_pilco."
            "reaching), and compare with mcpilco-compare --mcpilco-json "
            "results/kinematics_reaching.json"
        )


def run_mcpilco(
    config: MCPilcoConfig,
    out_dir: str | Path,
    resume: bool = False,
    progress: bool = True,
    log: Callable[[str], None] | None = print,
    write_rrd: bool = True,
    task: TaskSpec | None = None,
    overwrite: bool = False,
) -> RunSummary:
    """Run (or resume) MC-PILCO; writes checkpoint, PNGs, ``run.rrd`` and ``records.json``.

    Args:
        config: the experiment.
        task: the task (None: :meth:`MCPilcoConfig.task_spec`); pass one to use a Python
            cost function (``TaskSpec.cost_fn``).
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
    check_dynamics_task(task if task is not None else config.task_spec())
    out = Path(out_dir)
    run = open_run_folder(out, resume=resume, overwrite=overwrite)
    env = None
    try:  # the setup; the folder is released if it fails
        ckpt_path = out / CHECKPOINT_NAME
        device = resolve_device(config.device)
        if config.compile_rollout:
            check_compile_toolchain(device, config.rollout_backend)
        if config.torch_threads is not None:
            torch.set_num_threads(int(config.torch_threads))
        if task is None:
            task = config.task_spec()
        elif config.horizon is not None and config.horizon != task.horizon:
            task = task.replace(horizon=int(config.horizon))
        horizon = task.horizon
        if config.explore_steps is not None and config.explore_steps > horizon:
            raise ValueError(
                f"explore_steps ({config.explore_steps}) exceeds the horizon ({horizon} steps)"
            )
        env = make_env(config.env_id, horizon, task, config.env_kwargs)
        dt = task.dt
        layout = StateLayout.from_task(task)
        push_filter = None
        if config.push_filter is not None:
            if not task.joints:
                raise ValueError("push_filter needs an arm task (task.joints)")
            push_filter = CollisionFilter(
                config.push_filter,
                len(task.joints),
                task.dt / task.action_repeat,
                config.push_filter_margin,
            )

        torch.manual_seed(config.seed)
        np_rng = np.random.default_rng(config.seed)
        scales = (
            config.candidate_weight_scales or [config.policy_weight_scale] * config.num_candidates
        )
        candidates = [
            SquashedRBFPolicy(
                layout,
                task.action_low,
                task.action_high,
                num_basis=config.num_basis,
                centers_box=config.policy_centers_box,
                weight_scale=scale,
                seed=config.seed + CANDIDATE_SEED_STRIDE * k,
            )
            for k, scale in enumerate(scales)
        ]
        policy = candidates[0].to(device)  # the policy applied to the system (the chosen one)
        population = PolicyPopulation(candidates).to(device)
        policy_module = make_policy_module(population)
        model = GPDynamicsModel(
            task,
            kernel=config.kernel,
            max_points=config.max_points,
            adam_iters=config.gp_adam_iters,
            lbfgs_iters=config.gp_lbfgs_iters,
            noise_min=config.gp_noise_min,
            min_lengthscale=config.gp_min_lengthscale,
            mpk_degree=config.mpk_degree,
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
            restore_state(policy, ckpt["policy"], "policy", ckpt_path)
            restore_state(population, ckpt["population"], "policy population", ckpt_path)
            opt_state = ckpt["optimizer"]
            if ckpt["gp_file"] is not None:
                model.load(out / ckpt["gp_file"])
            set_rng_state(ckpt["rng"], np_rng)
            start_trial = int(ckpt["next_trial"])
            resumed_from = start_trial
            if log:
                log(f"resumed {ckpt_path}: trials 0..{start_trial - 1} done")

        if task.cost_fn is not None:
            if config.cost_limit_widths:
                raise ValueError(
                    "cost_limit_widths adds barriers to the task's cost terms; the task has a "
                    "cost function instead (put the barrier in it)"
                )
            cost_fn = task.cost_fn if isinstance(task.cost_fn, torch.nn.Module) else _CostFn(task)
        else:
            cost_fn = SaturatingCost.from_task(
                task, config.cost_length_scales, config.cost_angle_mode, config.cost_limit_widths
            )
        init_std = np.broadcast_to(
            np.asarray(task.init_std if config.init_std is None else config.init_std, float),
            (task.state_dim,),
        ).copy()
        init_std[list(layout.oscillator_idx)] = 0.0  # a known reference starts on it
    except BaseException:
        if env is not None:
            env.close()
        run.close()
        raise
    total = config.num_trials + 1
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=total, initial=min(start_trial, total), desc="trials", unit="trial")
    pngs: list[Path] = []
    try:
        for k in range(start_trial, total):
            t0 = time.perf_counter()
            rec: dict[str, Any] = {"index": k}
            arr: dict[str, Any] = {"index": k, "particles": None, "opt_costs": None}
            if k == 0:
                rec["kind"] = "exploration"
                (ep,) = exploration_episodes(
                    env,
                    np_rng,
                    config.seed,
                    config.explore_steps or horizon,
                    task,
                    config.explore_hold,
                    record_info=True,
                )
            else:
                rec["kind"] = "policy"
                if config.policy_init == "data" and policy.center_mean is None:
                    # from the exploration trial: the same settings on a resumed run
                    init = data_init(task.features(task.state_from_obs(episodes[0]["obs"])))
                    population.use_data_init(init)
                    policy.use_data_init(init)
                    if k == 1:  # the first policy starts there
                        population.reset_parameters(config.seed)
                        population.copy_to(0, policy)
                # 1. model learning
                t_fit = time.perf_counter()
                data = transitions(episodes, task)
                model.fit(*data)
                rec["gp_fit_s"] = time.perf_counter() - t_fit
                rec["gp_points"] = int(model.gp_.train_x_.shape[0])
                rec["n_data"] = int(len(data[1]))
                # transitions left out of the model's data: they touch a declared limit (or
                # a push filter marked them)
                n_filtered = sum(
                    int(np.sum(e["filtered"])) for e in episodes if e.get("filtered") is not None
                )
                rec["n_at_limits"] = (
                    int(sum(len(e["actions"]) for e in episodes)) - rec["n_data"] - n_filtered
                )
                dynamics = model.particle_dynamics(getattr(torch, config.rollout_dtype))

                def make_loss(module, dynamics=dynamics) -> MCPilcoLoss:
                    return MCPilcoLoss(
                        module,
                        dynamics,
                        cost_fn,
                        horizon=horizon,
                        num_particles=config.num_particles,
                        init_mean=task.init_mean,
                        init_std=init_std,
                        obs_noise_std=config.sim_obs_noise_std,
                    ).to(device)  # with the policy module and the dynamics in it

                loss = make_loss(policy_module)
                if config.compile_rollout:  # built, then checked against the eager rollout
                    fast = use_fast_rollout(loss, config.rollout_backend, dynamic=False)
                    rec["compiled_step"] = fast.in_use
                    rec["compile_check"] = fast.check
                    rec["compile_error"] = fast.error
                    rec["compile_backend"] = fast.backend
                    rec["rollout_shards"] = fast.shards
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
                snap_costs, snap = choose_policy(loss, population, policy, res.snapshots)
                cand_costs = snap_costs[snap]
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
                    snapshot_steps=[step for step, _ in res.snapshots],
                    snapshot_costs=snap_costs.min(1).values.tolist(),
                    chosen_step=res.snapshots[snap][0],
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
                    env, _policy_act(policy), trial_seed(config.seed, k), horizon, task, True
                )
                free = transitions([ep], task)
                rec["gp_rmse"] = (
                    model.one_step_rmse(*free).tolist()
                    if len(free[1])
                    else [math.nan] * layout.output_dim
                )
                arr["gp_rmse"] = rec["gp_rmse"]
                opt_state = None  # Adam restarts at each trial (MC-PILCO)
            filtered = None if push_filter is None else push_filter.excluded(ep["infos"])
            contact = contact_steps(ep.pop("infos"))
            if contact is not None:  # the env says when it was pushed (ground truth)
                rec["n_contact"] = int(contact.sum())
                arr["contact"] = contact
            if filtered is not None:
                rec["n_filtered"] = int(filtered.sum())
                if contact is not None:  # filtered transitions that overlap a push
                    rec["n_filtered_contact"] = int((filtered & contact).sum())
            episodes.append({"obs": ep["obs"], "actions": ep["actions"], "filtered": filtered})
            rec.update(episode_outcome(ep, t0))
            # seconds of interaction so far (episodes that terminate early count what they ran)
            rec["experience_s"] = sum(len(e["actions"]) for e in episodes) * dt
            arr.update(real=ep["states"], **{key: rec[key] for key in ("cost", "success")})
            arr["excluded"] = (
                task.touches_limit(ep["obs"][:-1], ep["obs"][1:]) if task.limits else None
            )
            if filtered is not None:
                arr["excluded"] = filtered | (False if arr["excluded"] is None else arr["excluded"])
            arr.update(time_in_goal=rec["time_in_goal"])
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
                        task.state_names,
                        title=f"trial {k}: particles (model) vs real, success={ep['success']}",
                        references=task.tracked_states(),
                        excluded=arr["excluded"],
                        contact=arr.get("contact"),
                    )
                )
            _write_outputs(out, config, records, arrays, task, write_rrd)
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
                    "policy_settings": policy.settings(),
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


class _CostFn(torch.nn.Module):
    """A task's plain cost function as a module."""

    def __init__(self, task: TaskSpec) -> None:
        super().__init__()
        self.fn = task.cost_fn

    def forward(self, state: torch.Tensor) -> torch.Tensor:
        return self.fn(state)


def _write_outputs(
    out: Path,
    config: MCPilcoConfig,
    records: list[dict[str, Any]],
    arrays: list[dict[str, Any]],
    task: TaskSpec,
    write_rrd: bool,
) -> None:
    curves = [(a["opt_costs"], f"trial {a['index']}") for a in arrays if a["opt_costs"] is not None]
    if curves:
        plot_optimisation(out / "optimisation.png", [c for c, _ in curves], [n for _, n in curves])
    if write_rrd:
        write_rerun_recording(
            out / "run.rrd",
            arrays,
            task.dt,
            task.state_names,
            task.gp_output_names(),
            references=task.tracked_states(),
        )
    write_records(out, config, records)
