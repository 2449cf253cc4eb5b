"""Policy optimisation loop of MC-PILCO: Adam, dropout and the monitoring rule.

Glossary (Amadio et al. 2022, sec. IV-B/C; thesis Algorithm 1)
----------------------------------------------------------------
``J^_k``
    expected-cost estimate (5.8) at optimisation step ``k``
    (:class:`~mcpilco.agents.mc_pilco.loss.MCPilcoLoss` output ``loss_cost``).
``d_k = J^_k - J^_{k-1}``
    cost change of one step; it has a trend (the optimisation progress) and Monte Carlo
    noise (fresh particles at every step).
``m_k = alpha_s m_{k-1} + (1 - alpha_s) d_k``,  ``v_k = alpha_s (v_{k-1} + (1 - alpha_s)
(d_k - m_{k-1})^2)``
    exponentially weighted mean and variance of ``d`` (``alpha_s = 0.99``).
``s_k = alpha_s s_{k-1} + (1 - alpha_s) m_k / sqrt(v_k)``
    monitoring signal: the smoothed ratio of the cost change to its own spread. ``|s|`` is
    large while the cost falls steadily and near 0 once the change is within the noise.
stall
    ``|s_k| < sigma_s`` for ``n_s`` consecutive steps (``sigma_s = 0.08``, ``n_s = 200``),
    and not within the first ``min_steps`` steps. Then the learning rate ``a`` is halved
    (down to ``a_min``), the dropout probability ``p`` lowered by ``Delta p``
    (``0.25 -> 0.125 -> 0``), ``sigma_s`` halved (down to ``0.01``), Adam restarted (fresh
    moments) and the count reset (the filters run on). A stall at ``a = a_min`` ends the
    optimisation, as does ``N_opt`` steps.
snapshot
    a copy of the policy parameters after every ``S``-th step
    (:attr:`OptimizationResult.snapshots`), preceded by the parameters the optimisation
    starts from (step 0: the previous trial's policy) and ended by the final ones. ``S`` is
    ``opt.snapshot_every``; None (the default) derives it from the step budget,
    ``S = ceil(N_opt / n_snap)`` with ``n_snap =`` :data:`SNAPSHOTS_PER_OPTIMISATION`
    (:func:`snapshot_interval`); 0 keeps the final parameters only. The caller evaluates
    them without dropout on common random numbers and applies the best
    (:func:`choose_policy`, :data:`CHOOSE_REPEATS` rollouts of ``M`` particles per copy):
    Adam on a noisy ``J^`` can leave a good policy late in the run
    (a sudden rise of ``J^`` that later steps do not undo), and the last parameters are
    then not the best ones seen; and a new model can judge the previous policy better than
    anything the optimisation reached, which then stays applied.
NaN restart
    a non-finite ``J^`` re-initialises the policy parameters and Adam (at most
    ``max_reinits`` times, then ``FloatingPointError``).
plateau restart
    given the task's success level ``J_succ`` (the largest ``J`` of a trajectory that
    succeeds and is never costlier than its start on the way,
    :func:`~mcpilco.agents.mc_pilco.trainer.success_cost_level`), a
    stall whose plateau ``J-bar`` (the mean ``J^`` per candidate over the last ``n_s``
    steps) lies above ``J_succ`` means the search sits in a basin none of whose policies
    succeed on the model: a finer learning rate would only settle there. Instead the
    parameters at the plateau are kept as a snapshot and the policy is drawn afresh
    (``reset_parameters`` with a new seed), with the initial learning rate, dropout,
    threshold and fresh Adam moments, at most ``max_restarts`` times and only while
    ``min_steps + n_s`` steps of the budget remain (the time a fresh start needs before its
    own first stall). The caller applies the snapshot with the lowest ``J^``
    (:func:`choose_policy`), so a restart can only add candidates.

The constants are those of the MC-PILCO reference cart-pole configuration (``a = 0.01``,
``a_min = 0.0025``, ``p = 0.25``, ``Delta p = 0.125``, ``alpha_s = 0.99``, ``sigma_s = 0.08``,
``n_s = 200``, ``min_steps = 200``); the experiment configs set ``N_opt`` (and may shorten
``n_s``) to fit the compute budget.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor, nn

if TYPE_CHECKING:
    from mcpilco.agents.mc_pilco.policy import PolicyPopulation, SquashedRBFPolicy


@dataclass
class PolicyOptConfig:
    """Budget and schedule of one policy optimisation (defaults: MC-PILCO).

    ``cuda_graph``: when the policy lives on a CUDA device, capture each step's forward and
    backward pass as one CUDA graph and replay it (:func:`loss_and_grad_fn`); no effect on
    the CPU. ``catch_restart``: on a task whose success is a goal held over a window, a
    trial whose applied policy the model predicts to reach the goal but not to hold it runs
    the optimisation once more from a fresh policy draw and applies the better of the two
    (:class:`~mcpilco.agents.mc_pilco.trainer.Trainer`).
    """

    max_steps: int = 1500
    lr: float = 0.01
    lr_min: float = 0.0025
    dropout: float = 0.25
    dropout_reduction: float = 0.125
    monitor_alpha: float = 0.99
    monitor_threshold: float = 0.08
    monitor_threshold_min: float = 0.01
    monitor_patience: int = 200
    min_steps: int = 200
    max_reinits: int = 3
    max_restarts: int = 2  # plateau restarts per optimisation (module glossary)
    cuda_graph: bool = True
    snapshot_every: int | None = None  # steps between kept copies (None: derived; 0: final only)
    catch_restart: bool = True  # search again from a fresh policy when a catch is missed

    def __post_init__(self) -> None:
        from mcpilco.envs.numbers import check_number

        for name, rule in _OPT_NUMBER_RANGES.items():
            if getattr(self, name) is None and name in _OPT_DERIVED:
                continue
            setattr(self, name, check_number(getattr(self, name), f"opt.{name}", **rule))
        for flag in ("cuda_graph", "catch_restart"):
            if not isinstance(getattr(self, flag), bool):
                raise ValueError(f"opt.{flag} must be true or false, got {getattr(self, flag)!r}")
        if self.max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {self.max_steps}")
        if not (self.lr > 0 and self.lr_min > 0):
            raise ValueError(f"lr and lr_min must be > 0, got {self.lr}, {self.lr_min}")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {self.dropout}")
        if not 0.0 <= self.monitor_alpha < 1.0:
            raise ValueError(f"monitor_alpha must be in [0, 1), got {self.monitor_alpha}")
        if self.monitor_patience < 1:
            raise ValueError(f"monitor_patience must be >= 1, got {self.monitor_patience}")
        if self.min_steps < 0:
            raise ValueError(f"min_steps must be >= 0, got {self.min_steps}")
        if self.snapshot_every is not None and (
            int(self.snapshot_every) != self.snapshot_every or self.snapshot_every < 0
        ):
            raise ValueError(
                f"snapshot_every must be an integer >= 0 or null, got {self.snapshot_every!r}"
            )


_OPT_NUMBER_RANGES: dict[str, dict] = {
    "max_steps": {"lo": 1, "hi": 10_000_000, "integer": True},
    "lr": {"lo": 0.0, "hi": 1e3, "lo_open": True},
    "lr_min": {"lo": 0.0, "hi": 1e3, "lo_open": True},
    "dropout": {"lo": 0.0, "hi": 1.0, "hi_open": True},
    "dropout_reduction": {"lo": 0.0, "hi": 1.0},
    "monitor_alpha": {"lo": 0.0, "hi": 1.0, "hi_open": True},
    "monitor_threshold": {"lo": 0.0, "hi": 1e9},
    "monitor_threshold_min": {"lo": 0.0, "hi": 1e9},
    "monitor_patience": {"lo": 1, "hi": 10_000_000, "integer": True},
    "min_steps": {"lo": 0, "hi": 10_000_000, "integer": True},
    "max_reinits": {"lo": 0, "hi": 1_000, "integer": True},
    "max_restarts": {"lo": 0, "hi": 1_000, "integer": True},
    "snapshot_every": {"lo": 0, "hi": 10_000_000, "integer": True},
}  # range of each number of PolicyOptConfig (mcpilco.envs.numbers.check_number keywords)
_OPT_DERIVED = ("snapshot_every",)  # numbers of PolicyOptConfig whose None means derived

SNAPSHOTS_PER_OPTIMISATION = 10  # n_snap: parameter copies a derived snapshot_every keeps
CHOOSE_REPEATS = 2  # rollouts of M particles per copy and candidate in choose_policy


def snapshot_interval(config: PolicyOptConfig, max_steps: int | None = None) -> int:
    """``S``, the steps between kept parameter copies (module glossary, snapshot): the
    config's ``snapshot_every``, else ``ceil(N_opt / n_snap)`` for an optimisation of
    ``max_steps`` ``N_opt`` steps (default: the config's), so that every optimisation keeps
    about :data:`SNAPSHOTS_PER_OPTIMISATION` copies whatever its budget. 0: none but the
    final parameters."""
    if config.snapshot_every is not None:
        return int(config.snapshot_every)
    steps = config.max_steps if max_steps is None else int(max_steps)
    return max(1, math.ceil(steps / SNAPSHOTS_PER_OPTIMISATION))


class CostMonitor:
    """The monitoring signal ``s_k`` and the stall test (see the module glossary)."""

    def __init__(
        self,
        alpha: float = 0.99,
        threshold: float = 0.08,
        patience: int = 200,
        min_steps: int = 0,
        threshold_min: float = 0.01,
    ):
        self.alpha = float(alpha)
        self.threshold = float(threshold)
        self.threshold_min = float(threshold_min)
        self.patience = int(patience)
        self.min_steps = int(min_steps)
        self.signal = 0.0
        self.count = 0
        self.steps = 0
        self._mean = 0.0
        self._var = 0.0
        self._prev: float | None = None

    def update(self, cost: float) -> bool:
        """Feed ``J^_k``; True when the signal has stalled (see the glossary)."""
        a = self.alpha
        if self._prev is not None:
            d = cost - self._prev
            self._var = a * (self._var + (1.0 - a) * (d - self._mean) ** 2)
            self._mean = a * self._mean + (1.0 - a) * d
            ratio = self._mean / max(math.sqrt(self._var), 1e-300)
            self.signal = a * self.signal + (1.0 - a) * ratio
            self.count = self.count + 1 if abs(self.signal) < self.threshold else 0
        self._prev = float(cost)
        self.steps += 1
        return self.count >= self.patience and self.steps > self.min_steps

    def on_stall(self) -> None:
        """After a stall: halve the threshold (not below ``threshold_min``) and count anew."""
        self.threshold = max(self.threshold / 2.0, self.threshold_min)
        self.count = 0


@dataclass
class OptimizationResult:
    """History of one policy optimisation."""

    costs: list[float] = field(default_factory=list)
    cost_stds: list[float] = field(default_factory=list)
    lrs: list[float] = field(default_factory=list)
    dropouts: list[float] = field(default_factory=list)
    signals: list[float] = field(default_factory=list)
    num_lr_reductions: int = 0
    num_reinits: int = 0
    restarts: list[str] = field(default_factory=list)
    """Why each plateau restart ran (its step, plateau ``J-bar`` and the success level)."""
    success_level: float | None = None
    seconds: float = 0.0
    cpu_seconds: float = 0.0
    stop_reason: str = "max_steps"
    snapshots: list[tuple[int, list[Tensor]]] = field(default_factory=list)
    """``(steps done, parameter copies)``: with snapshots (:func:`snapshot_interval`), the
    starting parameters (step 0) and every ``S`` steps; always the final ones last."""
    snapshot_every: int = 0
    """``S`` of this optimisation (0: the final parameters only)."""

    @property
    def num_steps(self) -> int:
        return len(self.costs)

    def extend(self, later: OptimizationResult) -> None:
        """Append a ``later`` optimisation of the same policy (a fresh start after this one):
        its steps, histories, snapshots (their steps shifted by this run's), counts, seconds,
        restart reasons and stop reason."""
        done = self.num_steps
        for name in ("costs", "cost_stds", "lrs", "dropouts", "signals", "restarts"):
            getattr(self, name).extend(getattr(later, name))
        self.snapshots += [(done + step, vals) for step, vals in later.snapshots]
        self.num_lr_reductions += later.num_lr_reductions
        self.num_reinits += later.num_reinits
        self.seconds += later.seconds
        self.cpu_seconds += later.cpu_seconds
        self.stop_reason = later.stop_reason

    @property
    def seconds_per_step(self) -> float:
        """Wall-clock seconds per step."""
        return self.seconds / max(self.num_steps, 1)

    @property
    def cpu_seconds_per_step(self) -> float:
        """CPU seconds of this process per step (robust to other processes on the cores)."""
        return self.cpu_seconds / max(self.num_steps, 1)


def _set_dropout(net: nn.Module, p: float) -> None:
    if hasattr(net, "dropout"):
        net.dropout = float(p)


StepFn = Callable[[], tuple[Tensor, Tensor]]
"""``() -> (J^, s_J)``: one evaluation of the loss that leaves ``dJ^/dtheta`` in ``.grad``."""


def loss_and_grad_fn(
    loss_module: Callable[[], Any], params: Sequence[Tensor], cuda_graph: bool = False
) -> StepFn:
    """A function that evaluates ``loss_module()`` (``loss_cost`` ``J^`` and ``cost_std``)
    and writes ``dJ^/dtheta`` into the ``.grad`` of ``params`` (previous gradients dropped).

    Eager by default. With ``cuda_graph`` and ``params`` on a CUDA device, the forward and
    backward pass is captured once as a CUDA graph (PyTorch's whole-network capture: a few
    warm-up calls on a side stream, then the capture) and every call replays it: the
    thousands of small kernels of the ``H``-step rollout are launched as one graph instead of
    one by one from Python. The random numbers (particles, noise, dropout masks) are fresh at
    every replay. What the Python code reads at capture (the dropout rate, the horizon, the
    GP) is frozen in the graph: build a new function after changing it. The ``.grad`` tensors
    are the graph's outputs, bound to the parameters again at every replay. Capturing costs
    about four eager steps (three warm-up calls on a side stream, then the capture).
    """
    params = list(params)

    def eager() -> tuple[Tensor, Tensor]:
        for p in params:
            p.grad = None
        out = loss_module()
        loss = out["loss_cost"]
        loss.backward()
        return loss.detach(), out["cost_std"]

    if not (cuda_graph and params and params[0].is_cuda):
        return eager

    side = torch.cuda.Stream()
    side.wait_stream(torch.cuda.current_stream())
    with torch.cuda.stream(side):  # warm-up: lazy initialisations happen outside the capture
        for _ in range(3):
            eager()
    torch.cuda.current_stream().wait_stream(side)
    for p in params:
        p.grad = None  # the captured backward allocates them in the graph's memory pool
    graph = torch.cuda.CUDAGraph()
    with torch.cuda.graph(graph):
        out = loss_module()
        out["loss_cost"].backward()
    static_loss, static_std = out["loss_cost"].detach(), out["cost_std"]
    static_grads = [p.grad for p in params]

    def replay() -> tuple[Tensor, Tensor]:
        graph.replay()
        for p, g in zip(params, static_grads, strict=True):
            p.grad = g  # (again, in case other code replaced .grad in between)
        return static_loss, static_std

    return replay


def optimize_policy(
    loss_module: nn.Module,
    policy: nn.Module,
    config: PolicyOptConfig,
    on_step: Callable[[int, float, float, float], None] | None = None,
    success_level: float | None = None,
    num_candidates: int = 1,
) -> OptimizationResult:
    """Minimise ``loss_module()["loss_cost"]`` over ``policy``'s parameters with Adam.

    Args:
        loss_module: returns a TensorDict with ``loss_cost`` (scalar) and ``cost_std``.
        policy: the policy network (the module inside the ``TensorDictModule``); its
            ``dropout`` attribute is scheduled and it must have ``reset_parameters()`` for the
            NaN restart.
        config: schedule and budget.
        on_step: called as ``on_step(k, J^_k, s_J,k, a_k)`` after each step (progress bars).
        success_level: ``J_succ`` of the plateau restarts (module glossary), per candidate;
            None: no restarts.
        num_candidates: ``K``, the candidates whose ``J^`` the loss sums (the plateau is
            compared per candidate).
    """
    every = snapshot_interval(config)
    res = OptimizationResult(success_level=success_level, snapshot_every=every)
    lr = config.lr
    dropout = config.dropout
    params = [p for p in policy.parameters() if p.requires_grad]
    opt = torch.optim.Adam(params, lr=lr)

    def new_monitor() -> CostMonitor:
        return CostMonitor(
            config.monitor_alpha,
            config.monitor_threshold,
            config.monitor_patience,
            config.min_steps,
            config.monitor_threshold_min,
        )

    def fresh_start(seed: int | None):
        """A new draw of the policy (seeded, or from the global generator) with the initial
        learning rate and dropout, a new Adam and monitor: (lr, dropout, step_fn, opt,
        monitor)."""
        policy.reset_parameters(seed)
        _set_dropout(policy, config.dropout)
        fresh_opt = torch.optim.Adam(params, lr=config.lr)
        return config.lr, config.dropout, None, fresh_opt, new_monitor()

    monitor = new_monitor()
    _set_dropout(policy, dropout)
    policy.train()
    step_fn: StepFn | None = None  # rebuilt whenever the dropout rate changes (CUDA graph)
    if every:  # the starting point (the previous trial's policy) competes with the iterates
        res.snapshots.append((0, [p.detach().clone() for p in params]))
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        for k in range(config.max_steps):
            if step_fn is None:
                step_fn = loss_and_grad_fn(loss_module, params, config.cuda_graph)
            loss, std_t = step_fn()
            cost = float(loss)
            std = float(std_t)
            if not math.isfinite(cost):
                res.num_reinits += 1
                if res.num_reinits > config.max_reinits:
                    res.stop_reason = "nan"
                    raise FloatingPointError(
                        f"expected cost is not finite after {config.max_reinits} policy "
                        "re-initialisations; check the GP model (noise, data) and the policy"
                    )
                lr, dropout, step_fn, opt, monitor = fresh_start(None)
                continue
            opt.step()
            res.costs.append(cost)
            res.cost_stds.append(std)
            res.lrs.append(lr)
            res.dropouts.append(dropout)
            stalled = monitor.update(cost)
            res.signals.append(monitor.signal)
            if on_step is not None:
                on_step(k, cost, std, lr)
            if every and res.num_steps % every == 0:
                res.snapshots.append((res.num_steps, [p.detach().clone() for p in params]))
            if stalled and _plateau_restart(res, config, success_level, num_candidates):
                if not res.snapshots or res.snapshots[-1][0] != res.num_steps:  # keep the plateau
                    res.snapshots.append((res.num_steps, [p.detach().clone() for p in params]))
                lr, dropout, step_fn, opt, monitor = fresh_start(int(torch.randint(2**31 - 1, ())))
                continue
            if stalled:
                if lr <= config.lr_min:
                    res.stop_reason = "lr_min"
                    break
                lr = max(lr * 0.5, config.lr_min)
                dropout = max(dropout - config.dropout_reduction, 0.0)
                _set_dropout(policy, dropout)
                step_fn = None
                opt = torch.optim.Adam(params, lr=lr)
                monitor.on_stall()
                res.num_lr_reductions += 1
        if not res.snapshots or res.snapshots[-1][0] != res.num_steps:
            res.snapshots.append((res.num_steps, [p.detach().clone() for p in params]))
    finally:
        res.seconds = time.perf_counter() - t0
        res.cpu_seconds = time.process_time() - c0
        policy.eval()
        for p in params:  # release the gradients (a CUDA graph's memory pool with them)
            p.grad = None
    return res


def _plateau_restart(
    res: OptimizationResult,
    config: PolicyOptConfig,
    level: float | None,
    num_candidates: int,
) -> bool:
    """At a stall: whether to restart (module glossary, plateau restart); when so, the
    reason is appended to ``res.restarts``."""
    if level is None or len(res.restarts) >= config.max_restarts:
        return False
    if config.max_steps - res.num_steps < config.min_steps + config.monitor_patience:
        return False
    recent = res.costs[-config.monitor_patience :]
    plateau = sum(recent) / len(recent) / num_candidates
    if plateau <= level:
        return False
    res.restarts.append(
        f"step {res.num_steps}: J^ plateau {plateau:.2f} above the success level {level:.2f}"
    )
    return True


@torch.no_grad()
def choose_policy(
    loss: Callable[[], dict[str, Tensor]],
    population: PolicyPopulation,
    policy: SquashedRBFPolicy,
    snapshots: Sequence[tuple[int, Sequence[Tensor]]] = (),
    repeats: int = CHOOSE_REPEATS,
) -> tuple[Tensor, int]:
    """The policy to apply: the candidate and parameter snapshot with the lowest ``J^``.

    ``J^`` of every candidate in every snapshot (``(steps, parameter copies)`` as in
    :attr:`OptimizationResult.snapshots`; none: the population's current
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
