"""MC-PILCO's configuration: :class:`MCPilcoConfig` and the per-env YAML files.

A config is the agent's hyperparameters; the task (state layout, cost, success test) is a
:class:`~mcpilco.envs.tasks.spec.TaskSpec`. :func:`load_config` builds the config of an env
from (later wins) the defaults here (thesis 5.5.1), the env's file in :data:`CONF_DIR`, one
of its presets, and overrides (``--set key=value``, :func:`parse_set`). Every config
round-trips through :meth:`MCPilcoConfig.to_dict` / :meth:`MCPilcoConfig.from_dict`, which
also reads the configs saved by earlier versions.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcpilco.agents.common.trials import DEFAULT_ENV_ID, plain_env_id
from mcpilco.agents.mc_pilco.dynamics import KERNEL_CHOICES, check_mpk_degree
from mcpilco.agents.mc_pilco.fast import BACKENDS
from mcpilco.agents.mc_pilco.optimize import (
    SNAPSHOTS_PER_OPTIMISATION,
    PolicyOptConfig,
    snapshot_interval,
)
from mcpilco.envs.tasks.spec import ANGLE_MODES, TaskSpec
from mcpilco.models.device import check_device_name

RESUME_FIXED = (
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
    "policy_linear",
    "push_filter",
)
"""Config fields that must not change when a run is resumed."""
ROLLOUT_DTYPES = ("float32", "float64")
"""Choices of :attr:`MCPilcoConfig.rollout_dtype`."""
CONF_DIR = Path(__file__).resolve().parent / "conf"
"""The shipped per-env config files (one YAML file per env id)."""
_LEGACY_FIELD_VALUES: dict[str, Any] = {
    "explore_hold": 1,
    "explore_limits": "none",
    "policy_init": "box",
    "push_filter": None,
}  # value of each field added after results were saved, for configs that lack it
POLICY_INITS = ("box", "data")  # MCPilcoConfig.policy_init
EXPLORE_LIMITS = ("limits", "termination", "none")  # MCPilcoConfig.explore_limits
# range of each number of MCPilcoConfig (mcpilco.envs.numbers.check_number keywords): what a
# run on one machine can hold (particles x horizon x candidates tensors, GP subsets)
CONFIG_NUMBER_RANGES: dict[str, dict[str, Any]] = {
    "num_trials": {"lo": 0, "hi": 10_000, "integer": True},
    "eval_episodes": {"lo": 0, "hi": 1000, "integer": True},
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
    :class:`~mcpilco.envs.tasks.spec.TaskSpec`). Per-env values live in YAML files
    (:func:`load_config`); the defaults here are MC-PILCO's (thesis 5.5.1).

    Attributes:
        env_id: registered Gymnasium id (``import mcpilco.envs`` registers ``mcpilco/...``).
        task: the task as plain data (a task file's content) for an env without a shipped
            task; None: the task that ships for ``env_id``.
        num_trials: policy trials after the exploration trial.
        horizon: ``H``, steps per trial and of the particle rollout (None: the task's); the
            first trial's, when ``grow_horizon`` lets it grow.
        grow_horizon: grow the horizon over trials while too few of the model's particles
            reach the goal a success window before its end, up to the env's episode length
            (:mod:`~mcpilco.agents.mc_pilco.horizon`; only for a goal held over a success
            window).
        num_particles: ``M``.
        window_objective: where the task's success keeps the state in a goal for a final
            window of ``W`` steps (:func:`~mcpilco.agents.mc_pilco.horizon.success_window`),
            optimise ``J^_W``, the summed cost with the window's steps counted twice
            (:mod:`~mcpilco.agents.mc_pilco.loss` glossary), which asks a swing-up to be in
            the goal before the window starts; false (default): the plain sum (5.8). No
            effect on a task without a success window.
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
        policy_linear: give the policy a linear feedback term around the task's regulation
            point, the RBF network a residual on it (:mod:`~mcpilco.agents.mc_pilco.policy`,
            "linear feedback"; its feature scales are the spread of the exploration trial's
            states). None (default): derived from the task, on for a regulation task
            (:func:`~mcpilco.agents.mc_pilco.trainer.regulation_point`: it starts inside the
            set it must stay in for the whole episode, a balance) and, gated around the
            goal, for a fully actuated swing-up (a catch,
            :func:`~mcpilco.agents.mc_pilco.trainer.catch_point`), off otherwise. A task
            that starts outside its goal gets the gated term whenever it has one.
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
        explore_limits: ``"limits"`` (default): brake the random exploration before the
            task's declared ``limits`` (:class:`~mcpilco.agents.common.trials.LimitGuard`:
            an action that could drive past a bound is reversed); ``"termination"``: before
            its ``termination`` box too; ``"none"``: plain random actions.
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
            (:func:`~mcpilco.agents.mc_pilco.fast.use_fast_rollout`, backend
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
        eval_episodes: ``E``: after each policy trial, ``E`` episodes of the applied policy
            from the task's initial distribution (reset seeds disjoint from the trials', not
            counted as experience), their success rate with a 95 % interval in the record
            (:func:`~mcpilco.agents.common.trials.evaluate`); 0: none.
        device: where the policy optimisation runs (policy, particles, GP posterior):
            ``"cpu"`` (default) or ``"cuda"`` / ``"cuda:<index>"``. The GP fit (float64,
            ``N <= max_points``) and the env stay on the CPU.
    """

    env_id: str = DEFAULT_ENV_ID
    task: dict[str, Any] | None = None
    num_trials: int = 5
    horizon: int | None = None
    grow_horizon: bool = True
    num_particles: int = 400
    window_objective: bool = False
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
    policy_linear: bool | None = None
    push_filter: str | None = None
    push_filter_margin: int = 1
    cost_length_scales: dict[str, float] | None = None
    cost_angle_mode: str | None = None
    cost_limit_widths: dict[str, float] | None = None
    num_candidates: int = 1
    candidate_weight_scales: list[float] | None = None
    explore_hold: int = 1
    explore_steps: int | None = None
    explore_limits: str = "limits"
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
    eval_episodes: int = 0

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
        if self.explore_limits not in EXPLORE_LIMITS:
            raise ValueError(
                f"explore_limits must be one of {EXPLORE_LIMITS}, got {self.explore_limits!r}"
            )
        if not isinstance(self.window_objective, bool):
            raise ValueError(
                f"window_objective must be true or false, got {self.window_objective!r}"
            )
        if not isinstance(self.grow_horizon, bool):
            raise ValueError(f"grow_horizon must be true or false, got {self.grow_horizon!r}")
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
        if self.policy_linear is not None and not isinstance(self.policy_linear, bool):
            raise ValueError(
                f"policy_linear must be true, false or null, got {self.policy_linear!r}"
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
        return cls(**{**_LEGACY_FIELD_VALUES, **d})

    def task_spec(self) -> TaskSpec:
        """The task: ``task`` when given, else the one that ships for ``env_id``; the
        config's ``horizon`` replaces the task's."""
        spec = (
            TaskSpec.from_dict(self.task)
            if self.task
            else TaskSpec.for_env(plain_env_id(self.env_id))
        )
        if plain_env_id(spec.env_id) != plain_env_id(self.env_id):
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


CONFIG_FILE_KEYS = ("env_id", "config", "presets")  # top-level keys of a config file


def read_config_file(path: str | Path) -> dict[str, Any]:
    """A config file's mapping (:func:`load_config`'s format), its keys checked.

    Raises:
        ValueError: the file cannot be read, is not YAML, or has other keys; the message
            names the file.
    """
    from mcpilco.envs.yaml_files import read_yaml

    try:
        data = read_yaml(path, "config file")
    except OSError as err:
        raise ValueError(f"config file {path}: {err}") from None
    if not isinstance(data, dict):
        raise ValueError(f"config file {path}: expected a mapping with {CONFIG_FILE_KEYS}")
    unknown = sorted(set(data) - set(CONFIG_FILE_KEYS))
    if unknown:
        raise ValueError(f"config file {path}: unknown keys {unknown} (keys: {CONFIG_FILE_KEYS})")
    for key in ("config", "presets"):
        if not isinstance(data.get(key) or {}, dict):
            raise ValueError(f"config file {path}: {key} must be a mapping")
    return data


def load_config(
    env_id: str,
    conf_dir: str | Path | None = CONF_DIR,
    preset: str | None = None,
    overrides: dict[str, Any] | None = None,
    config_file: str | Path | None = None,
) -> MCPilcoConfig:
    """The config of ``env_id``: :class:`MCPilcoConfig`'s defaults, then the env's file in
    ``conf_dir`` (default: the shipped :data:`CONF_DIR`; None: no file), then the user's
    ``config_file`` (same format; ``mcpilco-train --config``): of each file its ``config``
    mapping, then the named ``preset`` of its ``presets`` (which must exist in one of
    them); then ``overrides`` (nested dicts, e.g. from :func:`parse_set`).

    A config file (one per env, like the SB3 zoo's ``hyperparams/*.yml``)::

        env_id: mcpilco/CartpoleSwingUp-v0
        config:                 # each value with a comment saying where it comes from
          num_particles: 400
        presets:
          demo: {num_trials: 3}
    """
    files: list[tuple[str, dict[str, Any]]] = []
    path = config_files(conf_dir).get(plain_env_id(env_id)) if conf_dir is not None else None
    if path is not None:
        files.append((path.name, read_config_file(path)))
    if config_file is not None:
        data = read_config_file(config_file)
        named = data.get("env_id")
        if named is not None and plain_env_id(str(named)) != plain_env_id(env_id):
            raise ValueError(f"config file {config_file} is for env {named!r}, not {env_id!r}")
        files.append((str(config_file), data))
    named = preset is not None and preset != "default"
    if named and not any(preset in (data.get("presets") or {}) for _, data in files):
        where = ", ".join(name for name, _ in files) or f"no config file for {env_id}"
        names = sorted({p for _, data in files for p in data.get("presets") or {}})
        raise ValueError(
            f"unknown preset {preset!r} for {env_id} ({where}; presets: {names or 'none'})"
        )
    merged: dict[str, Any] = {"env_id": env_id}
    for _, data in files:  # the shipped file, then the user's: each its config, then preset
        merged = _merge(merged, data.get("config") or {})
        if named:
            merged = _merge(merged, (data.get("presets") or {}).get(preset) or {})
    merged = _merge(merged, overrides or {})
    if merged.get("env_id") != env_id:
        raise ValueError(f"the config names env {merged.get('env_id')!r}, not {env_id!r}")
    return with_derived_budget(MCPilcoConfig.from_dict(merged), merged)


def with_derived_budget(config: MCPilcoConfig, given: dict[str, Any]) -> MCPilcoConfig:
    """``config`` with the budget derived from its task
    (:func:`~mcpilco.agents.mc_pilco.budget.derive_budget`) in each of ``num_particles``,
    ``opt.max_steps`` and ``max_points`` that ``given`` (the merged files and overrides)
    does not set. A task that cannot be built yet keeps the defaults (its error comes from
    the checks before a run); so does a task that learns no dynamics."""
    from mcpilco.agents.mc_pilco.budget import derive_budget

    try:
        task = config.task_spec()
    except ValueError:
        return config
    if task.model != "dynamics":
        return config
    budget = derive_budget(task)
    over: dict[str, Any] = {}
    if "num_particles" not in given:
        over["num_particles"] = budget.num_particles
    if "max_points" not in given:
        over["max_points"] = budget.max_points
    opt = given.get("opt")
    if not (isinstance(opt, dict) and "max_steps" in opt):
        over["opt"] = dataclasses.replace(config.opt, max_steps=budget.opt_steps)
        if config.opt_steps_first is not None:
            over["opt_steps_first"] = min(config.opt_steps_first, budget.opt_steps)
    return dataclasses.replace(config, **over)


def budget_report(config: MCPilcoConfig) -> str:
    """The line ``mcpilco-train`` prints once at the start: the budget derived from the
    task and the values of the config that differ from it (a shipped or the user's config
    file, ``--set`` or an option)."""
    from mcpilco.agents.mc_pilco.budget import budget_line, derive_budget

    task = config.task_spec()
    budget = derive_budget(task)
    used = {
        "num_particles": (config.num_particles, budget.num_particles),
        "opt.max_steps": (config.opt.max_steps, budget.opt_steps),
        "max_points": (config.max_points, budget.max_points),
    }
    line = budget_line(task, budget, {k: v for k, (v, d) in used.items() if v != d})
    from mcpilco.agents.mc_pilco.horizon import success_window

    window = success_window(task) if config.window_objective else None
    if window is not None:
        line += f"; objective J^_W: the last {window} steps (the success window) counted twice"
    every = snapshot_interval(config.opt)
    if every:
        line += (
            f"; applied each trial: the lowest J^ without dropout among the previous policy "
            f"and a copy every {every} opt steps ("
            + (
                "opt.snapshot_every"
                if config.opt.snapshot_every is not None
                else f"derived: ceil(N_opt / {SNAPSHOTS_PER_OPTIMISATION}) of each optimisation"
            )
            + ")"
        )
    return line
