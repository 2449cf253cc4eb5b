"""PILCO baseline from TorchRL's own parts, run in MC-PILCO's outer loop.

Glossary (Deisenroth & Rasmussen, ICML 2011; thesis section 5.2)
-----------------------------------------------------------------
``x_t ~ N(mu_t, Sigma_t)``
    Gaussian state belief propagated by moment matching (no particles).
GP model
    :class:`torchrl.modules.models.GPWorldModel`: one SE-ARD GP per state coordinate on the
    change ``Delta = x_{t+1} - x_t`` from ``x~ = [x, u]``, hyper-parameters by evidence
    maximisation (botorch ``fit_gpytorch_mll``), exact moment matching (PILCO eqs. 10-23).
policy ``pi(x) = u_max sin(sum_i w_i exp(-(x - c_i)^T Lambda^-1 (x - c_i) / 2))``
    :class:`torchrl.modules.models.RBFController` (``num_basis`` centres ``c_i``), its action
    moments computed analytically for a Gaussian input; ``u_max`` the task's (symmetric)
    action bound.
cost ``c(x) = 1 - exp(-(x - x*)^T W (x - x*) / 2)``, ``E[c(x_t)]`` in closed form
    :class:`torchrl.objectives.ExponentialQuadraticCost` with the task's cost terms: target
    ``x*_j`` and ``W_jj = 2 / l_j^2`` on each term's state, 0 elsewhere, so that on a point
    belief ``c`` equals the task's saturating cost with plain differences. On the cart-pole
    (``x* = [0, 0, pi, 0]``, ``W = diag(2 / l_x^2, 0, 2 / l_theta^2, 0)``) that is the
    swing-up cost of thesis 5.5.1 for ``theta`` in ``[0, pi]``: TorchRL's parts have no
    ``sin/cos`` augmentation of angles, so the state is the raw observation.
``J(theta) = sum_{t=1..H} E[c(x_t)]``
    expected cost of an ``H``-step imagined rollout (TorchRL ``ImaginedEnv``). It is
    deterministic, so it is minimised as PILCO minimises it, with a quasi-Newton method and
    line searches (here L-BFGS with strong-Wolfe line searches, ``opt_steps`` evaluations per
    trial); Adam, as in TorchRL's ``sota-implementations/pilco`` example, is an option.
units fix
    TorchRL 0.14's ``GPWorldModel`` keeps the signal and noise variances of botorch's
    standardised targets next to the raw targets, which scales every predicted variance by
    ``1 / s_a^2`` (``s_a`` the target's std); :func:`rescale_to_raw_targets` puts
    them back in target units after each fit (tested against botorch's own posterior).
outer loop
    exactly MC-PILCO's (:mod:`mcpilco.agents.common.trials`): the same exploration trial
    (``u ~ U(-1, 1)`` from the same generator and seed), the same env, reset seeds and
    success flag; the experience is every env step taken so far (exploration included)
    times the control period (``3 (k + 1)`` s after trial ``k`` on the cart-pole, whose
    episodes never terminate early). ``explore_steps`` replaces the exploration trial with a
    random rollout of that many steps that resets whenever an episode ends (TorchRL's
    example). Data for the GP: the latest ``max_points`` transitions (the example's
    ``max_rollout_length``), since the moment-matching cost grows as ``O(n^2 D^2)`` memory
    per step.
settings per env
    :data:`CONF_FILE` holds settings keyed by env id (TorchRL's example's on
    ``InvertedPendulum-v5``, each with its source); :func:`pilco_config` builds a run's
    config from them.

After every trial the run is checkpointed atomically (``checkpoint.pt``); ``resume=True``
continues from it. ``records.json`` has one record per trial in MC-PILCO's format.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mcpilco.agents.common.checkpoint import (
    CHECKPOINT_NAME,
    check_resume,
    load_checkpoint,
    restore_state,
    rng_state,
    save_checkpoint,
    set_rng_state,
)
from mcpilco.agents.common.records import RunSummary, TrialRecord, record_line, write_records
from mcpilco.agents.common.trials import (
    DEFAULT_ENV_ID,
    env_dt,
    episode_outcome,
    exploration_episodes,
    make_env,
    run_episode,
    transitions,
    trial_seed,
)
from mcpilco.agents.mc_pilco.config import load_config
from mcpilco.agents.mc_pilco.viz import plot_optimisation
from mcpilco.envs.tasks.spec import TaskSpec
from mcpilco.models.device import check_device_name, resolve_device

OPTIMIZERS = ("lbfgs", "adam")  # choices of PilcoConfig.optimizer
RESUME_FIXED = ("env_id", "seed", "horizon", "num_basis", "explore_hold", "explore_steps")
"""PilcoConfig fields that must not change when a run is resumed."""
_LEGACY_FIELD_VALUES: dict[str, Any] = {"explore_hold": 1}  # fields added after runs were saved
DTYPE = torch.float64  # dtype of TorchRL's GP world model, controller and cost
CONF_FILE = Path(__file__).resolve().parent / "conf" / "pilco.yaml"  # settings by env id


@dataclass
class PilcoConfig:
    """One PILCO run (TorchRL parts, MC-PILCO's outer loop).

    Attributes:
        env_id: registered env id with a task specification whose state is the observation
            and whose action bounds are symmetric and equal.
        num_trials: policy trials after the exploration trial.
        horizon: ``H``, steps per trial (None: the task's).
        imagined_horizon: steps of the imagined rollout in ``J`` (None: ``H``; TorchRL's
            example: 40 on InvertedPendulum-v5).
        num_basis: RBF centres of the controller (50: the size of PILCO's cart-pole policy).
        max_points: GP training set = the latest ``max_points`` transitions; 180 keeps all
            the data up to 12 s of experience (the bench budget's last trial drops the first
            60). A smaller set forgets the swings of the earlier trials; a larger one costs
            more: the memory of one evaluation of ``J`` (60-step moment-matching rollout,
            forward and backward) grows as ``n^2``.
        optimizer: ``"lbfgs"`` (default): L-BFGS with a strong-Wolfe line search on the
            deterministic ``J``, the kind of quasi-Newton search PILCO itself uses (its
            ``minimize``, conjugate gradients / BFGS with line searches); ``"adam"``: Adam as
            in TorchRL's ``sota-implementations/pilco`` example.
        opt_steps: evaluations of ``J`` and its gradient per trial (L-BFGS: this many, line
            search evaluations included, plus at most the rest of the last line search;
            Adam: this many steps). 150: the order of the 150 line searches PILCO's cart-pole
            settings allow per policy update.
        lr: Adam learning rate (L-BFGS takes the usual initial step 1).
        cost_length_scales: length scales ``l_j`` of the cost by state name (None: the
            task's evaluation cost's); pass MC-PILCO's optimisation values of the same env
            (on the cart-pole ``l_x = 1``, ``l_theta = 3``, Amadio et al. 2022). A state
            without a cost term in the task gets the target 0 (TorchRL's default target);
            ``sqrt(2)`` on every state is ``ExponentialQuadraticCost``'s default ``W = I``.
        explore_hold: steps each random exploration action is held (pass
            :attr:`MCPilcoConfig.explore_hold <mcpilco.agents.mc_pilco.MCPilcoConfig>` of the
            same env, so that both agents start from the same exploration trial).
        explore_steps: random steps of the exploration trial, in episodes of at most ``H``
            steps that reset whenever one ends (None: one episode of ``H`` steps, MC-PILCO's
            exploration trial; TorchRL's example: 200).
        init_std: ``Sigma_0 = init_std^2 I`` of the initial belief (the env's 0.01); must be
            > 1e-3 so that TorchRL's world model takes its moment-matching path.
        seed: seeds torch, numpy and the env resets (same trial seeds as MC-PILCO).
        torch_threads: ``torch.set_num_threads`` (None: leave as is).
        device: torch device of the GP world model, the controller, the cost and the
            imagined rollout (``"cuda"`` runs the moment matching on a GPU; the real env and
            the GP's evidence maximisation data come from the host).
    """

    env_id: str = DEFAULT_ENV_ID
    num_trials: int = 5
    horizon: int | None = None
    imagined_horizon: int | None = None
    num_basis: int = 50
    max_points: int = 180
    optimizer: str = "lbfgs"
    opt_steps: int = 150
    lr: float = 0.02
    cost_length_scales: dict[str, float] | None = None
    explore_hold: int = 1
    explore_steps: int | None = None
    init_std: float = 0.01
    seed: int = 0
    torch_threads: int | None = None
    device: str = "cpu"

    def __post_init__(self) -> None:
        check_device_name(self.device)
        for name in ("num_trials",):
            v = getattr(self, name)
            if int(v) != v or v < 0:
                raise ValueError(f"{name} must be an integer >= 0, got {v!r}")
        for name in (
            "horizon",
            "imagined_horizon",
            "explore_steps",
            "num_basis",
            "opt_steps",
            "explore_hold",
        ):
            v = getattr(self, name)
            if v is None and name in ("horizon", "imagined_horizon", "explore_steps"):
                continue
            if int(v) != v or v < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        if int(self.max_points) != self.max_points or self.max_points < 10:
            raise ValueError(f"max_points must be an integer >= 10, got {self.max_points!r}")
        if self.optimizer not in OPTIMIZERS:
            raise ValueError(f"optimizer must be one of {OPTIMIZERS}, got {self.optimizer!r}")
        if not self.lr > 0:
            raise ValueError(f"lr must be > 0, got {self.lr}")
        if self.cost_length_scales is not None and not all(
            float(v) > 0 for v in self.cost_length_scales.values()
        ):
            raise ValueError(f"cost length scales must be > 0, got {self.cost_length_scales}")
        if not self.init_std >= 1e-3:
            raise ValueError(
                f"init_std must be >= 1e-3 (TorchRL's GPWorldModel treats a smaller covariance "
                f"as zero and stops gradients), got {self.init_std}"
            )

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PilcoConfig:
        """Inverse of :meth:`to_dict`; unknown fields are an error that names them. Configs
        saved before ``explore_hold`` existed read with it 1; the cart-pole's ``l_x``,
        ``l_theta`` read as ``cost_length_scales``."""
        d = dict(d)
        if "l_x" in d or "l_theta" in d:
            d.setdefault(
                "cost_length_scales", {"x": d.pop("l_x", 1.0), "theta": d.pop("l_theta", 3.0)}
            )
            d.pop("l_x", None), d.pop("l_theta", None)
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"unknown PILCO config fields {unknown} (fields: {sorted(known)})")
        return cls(**{**_LEGACY_FIELD_VALUES, **d})


def env_settings(env_id: str, path: str | Path = CONF_FILE) -> dict[str, Any]:
    """The settings of ``env_id`` in the PILCO config file ``path`` (``envs: {id: {...}}``;
    empty for an env without an entry).

    Raises:
        ValueError: the entry names a field that :class:`PilcoConfig` does not have.
    """
    from mcpilco.envs.yaml_files import read_yaml

    data = read_yaml(path, "PILCO config file", mapping=False) or {}
    if not isinstance(data, dict):
        raise ValueError(f"PILCO config file {path} must hold a mapping, not {type(data).__name__}")
    entry = dict((data.get("envs") or {}).get(env_id) or {})
    fields = {f.name for f in dataclasses.fields(PilcoConfig)}
    unknown = sorted(set(entry) - fields)
    if unknown:
        raise ValueError(
            f"{Path(path).name}: {env_id}: unknown PILCO field(s) {', '.join(unknown)}"
        )
    return entry


def pilco_config(
    env_id: str,
    overrides: dict[str, Any] | None = None,
    mcpilco_preset: str | None = None,
    path: str | Path = CONF_FILE,
    mcpilco_overrides: dict[str, Any] | None = None,
) -> PilcoConfig:
    """The PILCO config of a run on ``env_id``, from (later wins): :class:`PilcoConfig`'s
    defaults; MC-PILCO's ``explore_hold`` and cost length scales on that env (its config
    file, its preset ``mcpilco_preset`` if given, then ``mcpilco_overrides``), so that both
    agents start from the same exploration trial and optimise the same cost; the env's entry
    in ``path`` (:func:`env_settings`); ``overrides``. ``num_trials`` defaults to MC-PILCO's."""
    mc = load_config(env_id, preset=mcpilco_preset, overrides=mcpilco_overrides)
    merged: dict[str, Any] = {
        "env_id": env_id,
        "num_trials": mc.num_trials,
        "explore_hold": mc.explore_hold,
        "cost_length_scales": mc.cost_length_scales,
        **env_settings(env_id, path),
        **dict(overrides or {}),
    }
    return PilcoConfig(**merged)


# ------------------------------------------------------------------------ TorchRL parts
def make_controller(
    obs_dim: int,
    action_dim: int,
    num_basis: int,
    seed: int,
    max_action: float = 1.0,
    device: str | torch.device = "cpu",
):
    """TorchRL's :class:`RBFController` (float64, ``u_max = max_action``, on ``device``) as a
    ``TensorDictModule``."""
    from tensordict.nn import TensorDictModule
    from torchrl.modules.models import RBFController

    torch.manual_seed(seed)
    controller = RBFController(
        input_dim=obs_dim, output_dim=action_dim, max_action=max_action, n_basis=num_basis
    ).to(device=device, dtype=DTYPE)
    module = TensorDictModule(
        controller,
        in_keys=[("observation", "mean"), ("observation", "var")],
        out_keys=[("action", "mean"), ("action", "var"), ("action", "cross_covariance")],
    )
    return controller, module


def make_cost(task: TaskSpec, length_scales: dict[str, float] | None = None):
    """TorchRL's :class:`ExponentialQuadraticCost` of the task's cost terms (see the
    glossary); ``length_scales`` by state name replace the task's, and a named state without
    a cost term in the task is added with target 0 (TorchRL's default target).

    Raises:
        ValueError: a length scale for a name that is not one of the task's states.
    """
    from torchrl.objectives import ExponentialQuadraticCost

    length_scales = dict(length_scales or {})
    unknown = sorted(set(length_scales) - set(task.state_names))
    if unknown:
        raise ValueError(
            f"cost_length_scales: unknown state(s) {', '.join(unknown)} "
            f"(states: {', '.join(task.state_names)})"
        )
    target = torch.zeros(task.state_dim, dtype=DTYPE)
    w = torch.zeros(task.state_dim, dtype=DTYPE)
    for name, scale in length_scales.items():
        w[task.index(name)] = 2.0 / float(scale) ** 2
    for term in task.cost_terms:
        j = task.index(term.state)
        target[j] = term.target
        w[j] = 2.0 / float(length_scales.get(term.state, term.length_scale)) ** 2
    return ExponentialQuadraticCost(target=target, weights=torch.diag(w), reduction="none")


def fit_world_model(
    obs: np.ndarray,
    actions: np.ndarray,
    next_obs: np.ndarray,
    device: str | torch.device = "cpu",
):
    """TorchRL's :class:`GPWorldModel` on ``device``, fitted on transitions
    ``(x_t, u_t, x_{t+1})``."""
    from tensordict import TensorDict
    from torchrl.modules.models import GPWorldModel

    n, d = obs.shape
    data = TensorDict(
        {
            "observation": torch.as_tensor(obs, dtype=DTYPE),
            "action": torch.as_tensor(actions, dtype=DTYPE).reshape(n, -1),
            ("next", "observation"): torch.as_tensor(next_obs, dtype=DTYPE),
        },
        batch_size=[n],
    )
    model = GPWorldModel(obs_dim=d, action_dim=data["action"].shape[-1]).to(device)
    model.fit(data)
    rescale_to_raw_targets(model)
    model.eval()
    return model


def rescale_to_raw_targets(model) -> torch.Tensor:
    """Put a fitted ``GPWorldModel``'s ``alpha_a^2``, ``sigma_eps_a^2`` in the units of ``Delta_a``.

    TorchRL 0.14's ``GPWorldModel.fit`` builds botorch ``SingleTaskGP`` models, which by
    default standardise each target (``Standardize``: ``y~_a = (Delta_a - m_a) / s_a``), and
    then copies their signal and noise variances, fitted on ``y~_a``, next to the raw targets
    ``Delta_a``. The predictive mean ``k_*^T (K_a + sigma_eps_a^2 I)^{-1} Delta_a`` does not
    depend on a common scale of ``K_a`` and ``sigma_eps_a^2``, but every variance does: with
    a small ``s_a`` (a coordinate that changes little per step) the belief grows by the
    standardised noise variance instead of the raw one, so every imagined rollout spreads
    over the whole state space and the expected cost stays near its maximum whatever the
    policy. Here

        ``alpha_a^2 <- s_a^2 alpha_a^2``,  ``sigma_eps_a^2 <- s_a^2 sigma_eps_a^2``,

    and TorchRL's cached factors follow from the same common scale without a new solve:
    ``(K_a + sigma_eps_a^2 I)^{-1} <- (K_a + sigma_eps_a^2 I)^{-1} / s_a^2`` and
    ``beta_a <- beta_a / s_a^2`` (TorchRL's ``1e-6`` jitter is scaled with them, to
    ``1e-6 s_a^2``). The GP's constant prior mean ``m_a`` stays dropped, as in TorchRL and in
    PILCO (zero prior mean on ``Delta``).

    Args:
        model: a ``GPWorldModel`` right after ``fit``.

    Returns:
        ``s_a^2`` per state dimension (ones when a model was fitted without standardisation).
    """
    scales = []
    for gp in model.model_list.models:
        stdvs = getattr(getattr(gp, "outcome_transform", None), "stdvs", None)
        scales.append(torch.ones(()) if stdvs is None else stdvs.reshape(()).detach())
    s2 = torch.stack([s.to(model.alpha_sq) for s in scales]) ** 2
    inv_k, beta = model.compute_factorizations()
    model.alpha_sq = model.alpha_sq * s2.unsqueeze(-1)
    model.sigma_sq_eps = model.sigma_sq_eps * s2
    model._cached_inv_K_noisy = inv_k / s2.view(-1, 1, 1)
    model._cached_beta = beta / s2.view(-1, 1)
    return s2


def controller_act(controller) -> Callable[[np.ndarray], np.ndarray]:
    """The deterministic action ``E[pi(x)]`` for a point observation (zero covariance)."""

    device = next(controller.parameters()).device

    @torch.no_grad()
    def act(obs: np.ndarray) -> np.ndarray:
        x = torch.as_tensor(obs, dtype=DTYPE, device=device).reshape(1, -1)
        zero = torch.zeros(1, x.shape[1], x.shape[1], dtype=DTYPE, device=device)
        mean, _, _ = controller(x, zero)
        return mean[0].cpu().numpy()

    return act


class ImaginedCost:
    """``J = sum_{t=1..H} E[c(x_t)]`` of a moment-matching rollout (TorchRL ``ImaginedEnv``)."""

    def __init__(
        self,
        world_model,
        base_env,
        policy_module,
        cost,
        horizon: int,
        init_std: float,
        init_mean=None,
    ):
        from tensordict import TensorDict
        from torchrl.envs.model_based import ImaginedEnv

        self.env = ImaginedEnv(world_model_module=world_model, base_env=base_env)
        d, device = world_model.obs_dim, world_model.device
        self.reset_td = TensorDict(
            {
                ("observation", "mean"): (
                    torch.zeros(d, dtype=DTYPE, device=device)
                    if init_mean is None
                    else torch.as_tensor(init_mean, dtype=DTYPE, device=device)
                ),
                ("observation", "var"): init_std**2 * torch.eye(d, dtype=DTYPE, device=device),
            },
            device=device,
        ).expand(*self.env.batch_size)
        self.policy_module = policy_module
        self.cost = cost
        self.horizon = int(horizon)

    def __call__(self) -> torch.Tensor:
        data = self.env.rollout(
            max_steps=self.horizon, policy=self.policy_module, tensordict=self.reset_td
        )
        return self.cost(data["next"])["loss_cost"].sum(-1).mean()


def _torchrl_env(env_id: str, device: str | torch.device = "cpu"):
    """TorchRL ``GymEnv`` of a registered id on ``device`` (its specs and device shape the
    imagined env)."""
    import warnings

    import mcpilco.envs  # noqa: F401  (registers the ids)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from torchrl.envs import GymEnv

        return GymEnv(env_id, device=device)


def optimize_controller(
    objective: ImaginedCost,
    controller,
    steps: int,
    lr: float,
    on_step: Callable[[int, float], None] | None = None,
    optimizer: str = "adam",
) -> dict[str, Any]:
    """Minimise ``J`` over the controller's parameters; the best parameters seen are kept.

    ``optimizer="adam"``: ``steps`` Adam steps; a non-finite ``J`` or gradient skips the step.
    ``optimizer="lbfgs"``: one L-BFGS run (strong-Wolfe line search, initial step ``lr``) that
    stops after the iteration in which the evaluations of ``J`` reach ``steps`` (its last line
    search may add a few), at a non-finite ``J``, or when L-BFGS converges. Every evaluation
    is recorded in ``costs`` and reported to ``on_step``.
    """
    if optimizer not in OPTIMIZERS:
        raise ValueError(f"optimizer must be one of {OPTIMIZERS}, got {optimizer!r}")
    params = list(controller.parameters())
    costs: list[float] = []
    state = {"best": math.inf, "best_state": None, "skipped": 0}
    t0, c0 = time.perf_counter(), time.process_time()

    def evaluate() -> tuple[torch.Tensor, bool]:
        """``J`` with its gradient in ``.grad``; False when ``J`` or a gradient is not finite."""
        for p in params:
            p.grad = None
        try:
            J = objective()
        except RuntimeError:  # e.g. a singular matrix in the moment matching
            J = torch.tensor(math.nan, dtype=DTYPE)
        value = float(J.detach())
        costs.append(value)
        ok = math.isfinite(value)
        if ok:
            if value < state["best"]:
                state["best"] = value
                state["best_state"] = {
                    k: v.detach().clone() for k, v in controller.state_dict().items()
                }
            J.backward()
            ok = all(p.grad is None or bool(torch.isfinite(p.grad).all()) for p in params)
        if not ok:
            state["skipped"] += 1
        if on_step is not None:
            on_step(len(costs) - 1, value)
        return J.detach(), ok

    if optimizer == "adam":
        opt = torch.optim.Adam(params, lr=lr)
        for _ in range(steps):
            _, ok = evaluate()
            if ok:
                opt.step()
    else:

        class _NonFinite(Exception):
            pass

        def closure() -> torch.Tensor:
            J, ok = evaluate()
            if not ok:
                raise _NonFinite
            return J

        opt = torch.optim.LBFGS(
            params,
            lr=lr,
            max_iter=steps,
            max_eval=steps,
            tolerance_grad=1e-9,
            tolerance_change=1e-12,
            history_size=50,
            line_search_fn="strong_wolfe",
        )
        try:
            opt.step(closure)
        except _NonFinite:
            pass
    if state["best_state"] is not None:
        controller.load_state_dict(state["best_state"])
    n = max(len(costs), 1)
    return {
        "costs": costs,
        "best": state["best"],
        "skipped": state["skipped"],
        "seconds": time.perf_counter() - t0,
        "s_per_step": (time.perf_counter() - t0) / n,
        "cpu_s_per_step": (time.process_time() - c0) / n,
    }


# ---------------------------------------------------------------------------------- loop
def run_pilco(
    config: PilcoConfig,
    out_dir: str | Path,
    resume: bool = False,
    progress: bool = True,
    log: Callable[[str], None] | None = print,
) -> RunSummary:
    """Run (or resume) PILCO in MC-PILCO's outer loop; writes checkpoint, records, PNG.

    Args:
        config: the experiment.
        out_dir: output folder (created).
        resume: continue from ``out_dir/checkpoint.pt`` (``num_trials`` may grow).
        progress: tqdm bars on trials and optimisation steps.
        log: called with one line per trial (None: silent).
    """
    t_start = time.perf_counter()
    device = resolve_device(config.device)  # refuses a CUDA device this machine lacks
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ckpt_path = out / CHECKPOINT_NAME
    if config.torch_threads is not None:
        torch.set_num_threads(int(config.torch_threads))
    task = TaskSpec.for_env(config.env_id)
    if config.horizon is not None:
        task = task.replace(horizon=config.horizon)
    horizon = task.horizon
    half = {(hi - lo) / 2 for lo, hi in zip(task.action_low, task.action_high, strict=True)}
    if (
        task.obs_indices is not None
        or task.state_from is not None
        or len(half) != 1
        or task.cost_fn is not None
        or any(lo != -hi for lo, hi in zip(task.action_low, task.action_high, strict=True))
    ):
        raise ValueError(
            f"{config.env_id}: TorchRL's PILCO needs a task whose state is the observation, "
            "with symmetric, equal action bounds and cost terms (no cost function)"
        )
    env = make_env(config.env_id, horizon, task)
    obs_dim, act_dim = task.state_dim, task.action_dim
    dt = env_dt(env, task)
    base_env = _torchrl_env(config.env_id, device)

    torch.manual_seed(config.seed)
    np_rng = np.random.default_rng(config.seed)
    controller, policy_module = make_controller(
        obs_dim, act_dim, config.num_basis, config.seed, half.pop(), device
    )
    cost = make_cost(task, config.cost_length_scales).to(device)
    episodes: list[dict[str, Any]] = []
    records: list[TrialRecord] = []
    opt_curves: list[list[float]] = []
    start_trial = 0
    resumed_from = None
    if resume:
        ckpt = load_checkpoint(ckpt_path)
        check_resume(ckpt["config"], config, RESUME_FIXED)
        episodes = ckpt["episodes"]
        records = [TrialRecord.from_dict(r) for r in ckpt["records"]]
        opt_curves = ckpt["opt_curves"]
        restore_state(controller, ckpt["policy"], "policy", ckpt_path)
        set_rng_state(ckpt["rng"], np_rng)
        start_trial = resumed_from = int(ckpt["next_trial"])
        if log:
            log(f"resumed {ckpt_path}: trials 0..{start_trial - 1} done")

    total = config.num_trials + 1
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=total, initial=min(start_trial, total), desc="PILCO trials")
    try:
        for k in range(start_trial, total):
            t0 = time.perf_counter()
            rec = TrialRecord(index=k, kind="exploration" if k == 0 else "policy")
            if k == 0:
                eps = exploration_episodes(
                    env,
                    np_rng,
                    config.seed,
                    horizon,
                    task,
                    config.explore_hold,
                    config.explore_steps,
                )
                ep = eps[0]  # its outcome is the record's (MC-PILCO's exploration trial)
                rec.episodes = len(eps)
            else:
                s, a, s1 = transitions(episodes, task)  # the same data as MC-PILCO
                s, a, s1 = (
                    s[-config.max_points :],
                    a[-config.max_points :],
                    s1[-config.max_points :],
                )
                t_fit = time.perf_counter()
                world_model = fit_world_model(s, a, s1, device)
                rec.update(gp_fit_s=time.perf_counter() - t_fit, gp_points=int(s.shape[0]))
                objective = ImaginedCost(
                    world_model,
                    base_env,
                    policy_module,
                    cost,
                    config.imagined_horizon or horizon,
                    config.init_std,
                    task.init_mean,
                )
                obar = None
                if progress:
                    from tqdm.auto import tqdm

                    obar = tqdm(total=config.opt_steps, desc=f"trial {k} PILCO opt", leave=False)

                def on_step(i, c, obar=obar):
                    if obar is not None:
                        obar.update(1)
                        obar.set_postfix(J=f"{c:.2f}")

                lr = config.lr if config.optimizer == "adam" else 1.0
                res = optimize_controller(
                    objective, controller, config.opt_steps, lr, on_step, config.optimizer
                )
                if obar is not None:
                    obar.close()
                opt_curves.append(res["costs"])
                rec.update(
                    opt_steps=len(res["costs"]),
                    opt_s=res["seconds"],
                    s_per_opt_step=res["s_per_step"],
                    cpu_s_per_opt_step=res["cpu_s_per_step"],
                    opt_skipped=res["skipped"],
                    opt_final_cost=res["best"],
                )
                ep = run_episode(
                    env,
                    controller_act(controller),
                    trial_seed(config.seed, k),
                    horizon,
                    task,
                )
                eps = [ep]
            episodes += [{"obs": e["obs"], "actions": e["actions"]} for e in eps]
            rec.update(**episode_outcome(ep, t0))
            if k == 0:  # every step of the exploration counts
                rec.steps = sum(len(e["actions"]) for e in episodes)
            rec.experience_s = sum(len(e["actions"]) for e in episodes) * dt
            records.append(rec)
            _write_outputs(out, config, records, opt_curves)
            save_checkpoint(
                ckpt_path,
                config,
                k + 1,
                episodes=episodes,
                records=[r.to_dict() for r in records],
                opt_curves=opt_curves,
                policy=controller.state_dict(),
                rng=rng_state(np_rng),
            )
            if log:
                log("PILCO " + record_line(rec))
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
        env.close()
        base_env.close()
    png = out / "optimisation.png"
    return RunSummary(
        config=config.to_dict(),
        records=[r.to_dict() for r in records],
        out_dir=out,
        checkpoint=ckpt_path,
        rrd=None,
        pngs=[png] if png.exists() else [],
        seconds=time.perf_counter() - t_start,
        resumed_from_trial=resumed_from,
    )


def _write_outputs(
    out: Path, config: PilcoConfig, records: list[TrialRecord], opt_curves: list[list[float]]
) -> None:
    if opt_curves:
        plot_optimisation(
            out / "optimisation.png",
            [np.asarray(c) for c in opt_curves],
            [f"trial {i + 1}" for i in range(len(opt_curves))],
        )
    write_records(out, config, records)


__all__ = [
    "ImaginedCost",
    "PilcoConfig",
    "controller_act",
    "fit_world_model",
    "make_controller",
    "make_cost",
    "optimize_controller",
    "pilco_config",
    "env_settings",
    "run_pilco",
]
