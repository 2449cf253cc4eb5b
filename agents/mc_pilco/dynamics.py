"""GP dynamics model of MC-PILCO with speed integration (thesis sections 5.3.1 and 5.4.3).

The shapes come from the task's :class:`~mcpilco.agents.mc_pilco.features.StateLayout`.

Glossary
--------
``x_t``
    state of ``n`` coordinates; the task pairs positions ``q_i`` with velocities ``q_dot_i``
    and leaves the other coordinates ``o_j`` unpaired.
``u_t``
    action (env units).
``x~_t = [f(x_t), u_t]``
    GP input: the state features (angles through sin/cos, :mod:`.features`) and the action.
``Delta_t``
    change of each predicted coordinate: ``q_dot_{t+1} - q_dot_t`` per pair (thesis 5.4.3:
    only the velocities are modelled) and ``o_{t+1} - o_t`` per unpaired coordinate; one GP
    ``h_i`` per output, batched as one ``GPRegressor`` with ``m`` outputs.
``E[Delta^_t], var[Delta^_t]``
    GP posterior mean (5.3) and latent variance (5.4): no measurement noise ``sigma_i^2``.
``Delta_t = E[Delta^_t] + sqrt(var[Delta^_t]) eps``, ``eps ~ N(0, I)``
    reparameterised sample of (5.5) (thesis 5.4.2, Kingma & Welling 2013). It uses the
    latent variance (5.4), as in (5.7), not ``var + sigma_i^2``: ``sigma_i^2`` is the
    noise of the *measured* targets, not of the system's evolution; ``sample_noise=True``
    adds it (ablation).
``Delta_t <- clip(Delta_t, -b, b)``
    safeguard: ``b = c_clip max |Delta|`` over the training targets (``c_clip = 3``). A
    polynomial (MPK) kernel extrapolates polynomially, so a particle far from the data can
    get a huge ``Delta`` that feeds back into a larger input and overflows within a few steps
    (NaN cost); the clip keeps particles finite without touching those near the data.
``q_dot_{t+1} = q_dot_t + Delta_t``, ``q_{t+1} = q_t + T_s q_dot_t + T_s / 2 Delta_t``
    speed integration, eq. (5.9) (constant acceleration over one period ``T_s``);
    ``o_{t+1} = o_t + Delta_t`` for an unpaired coordinate.
``k = k_RBF + k_MP^(2)``
    kernel of each GP, eq. (5.10) (``kernel="rbf"``: RBF only, the ablation of Fig. 5.5).
``k = k_q(q, q') (sigma^2 + v^T Sigma v')``, ``kernel="rigid_body"``
    the structured kernel of an arm task (:class:`~mcpilco.models.kernels.RigidBodyDynamicsKernel`)
    on the raw joint-space input ``x~ = [q, qd, tau, w]`` (:class:`JointSpaceInputs`; the
    task's ``joints``, their velocities, the actions as torques, its ``affine_inputs``)
    instead of ``[f(x), u]``. Why this structure: for a rigid arm
    ``qdd = M(q)^-1 (tau - C(q) [qd_i qd_j] - g(q) - F_v qd)``, so at a fixed configuration
    ``q`` the acceleration, and over one control period ``T_s`` with the action held the
    velocity change ``Delta qd ~ T_s qdd``, is affine in ``tau``, in the products
    ``qd_i qd_j`` and in ``qd``; the kernel's RKHS is exactly
    ``{f_0(q) + sum_j f_j(q) v_j}`` with ``v = [tau, qd_i qd_j, qd, w]``, so only the smooth
    coefficient functions of ``q`` are learned, not how the torques and velocities enter.
    A PD controller in the loop, ``tau_c = K_p (q_r - q) + K_d (qd_r - qd) + g^(q) + u``,
    keeps the structure with ``u`` in the place of ``tau`` and the reference
    ``w = [q_r, qd_r]`` as affine inputs. Every GP output (also the reference's own
    velocity change, affine in ``w`` for a sinusoidal reference) gets this kernel. The
    structure is that of the accelerations: where the control period is long against the
    closed loop's time constants (a stiff PD loop moving the state within one period) the
    velocity change departs from it, and RBF + MPK may predict such data better. How it
    compares with RBF + MPK on the UR10 tracking task (40 ms, the env's PD in the loop), on
    all of a run's data and on the exploration trial alone: docs/mcpilco.md, "Which kernel
    models the arm" (results/mcpilco_tracking.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, Literal, NamedTuple

import numpy as np
import torch
from torch import Tensor, nn

from mcpilco.agents.mc_pilco.features import StateLayout, gp_inputs, take

KernelName = Literal["rbf+mpk", "rbf", "rigid_body"]
KERNEL_CHOICES: tuple[str, ...] = ("rbf+mpk", "rbf", "rigid_body")  # GPDynamicsModel's kernels


def speed_integration(state: Tensor, delta: Tensor, dt: float, layout: StateLayout) -> Tensor:
    """Next state by eq. (5.9): ``q+ = q + T_s q_dot + T_s/2 Delta``, ``q_dot+ = q_dot + Delta``
    per pair, ``o+ = o + Delta`` per unpaired coordinate, and the exact step of each known
    oscillator ``(r, r_dot)`` of the layout (a sinusoidal reference
    ``r(t) = c + a sin(w t + phi)``, ``theta = w T_s``)::

        r+ - c = cos(theta) (r - c) + sin(theta) / w r_dot
        r_dot+ = -w sin(theta) (r - c) + cos(theta) r_dot

    (``sin(theta) / w -> T_s`` for ``w = 0``: a constant reference). The oscillators take no
    GP output: the reference a tracking controller follows is known, not learned.

    Written as ``x+ = x A^T + Delta S^T + z`` with constant matrices and offset (two small
    matmuls instead of slicing ops in the rollout's hot loop; ``z`` only with oscillators).

    Args:
        state: (..., n).
        delta: (..., m) changes of ``layout.output_idx``.
        dt: control period ``T_s`` [s].
        layout: the task's state layout.
    """
    A, S, z = integration_matrices(dt, layout, state.dtype, state.device)
    nxt = state @ A + delta @ S
    return nxt if z is None else nxt + z


_INTEGRATION_CACHE: dict = {}


def integration_matrices(
    dt: float, layout: StateLayout, dtype: torch.dtype, device
) -> tuple[Tensor, Tensor, Tensor | None]:
    """``A^T`` (n, n), ``S^T`` (m, n) and ``z`` (n,) or None (no oscillators) of
    :func:`speed_integration` (cached)."""
    key = (float(dt), layout, dtype, str(device))
    if key not in _INTEGRATION_CACHE:
        n = layout.n
        A = torch.eye(n, dtype=torch.float64)
        S = torch.zeros(n, layout.output_dim, dtype=torch.float64)
        for j, (q, qd) in enumerate(zip(layout.position_idx, layout.velocity_idx, strict=True)):
            A[q, qd] = dt
            S[q, j] = 0.5 * dt
            S[qd, j] = 1.0
        for j, o in enumerate(layout.delta_idx, start=len(layout.velocity_idx)):
            S[o, j] = 1.0
        z = None
        if layout.oscillators:
            z = torch.zeros(n, dtype=torch.float64)
            for r, rd, w, c in layout.oscillators:
                cos, sin = math.cos(w * dt), math.sin(w * dt)
                A[r, r], A[r, rd] = cos, (sin / w if w != 0.0 else dt)
                A[rd, r], A[rd, rd] = -w * sin, cos
                z[r], z[rd] = c * (1.0 - cos), c * w * sin
            z = z.to(dtype=dtype, device=device)
        _INTEGRATION_CACHE[key] = (
            A.T.contiguous().to(dtype=dtype, device=device),
            S.T.contiguous().to(dtype=dtype, device=device),
            z,
        )
    return _INTEGRATION_CACHE[key]


class JointSpaceInputs:
    """GP input ``x~ = [q, qd, tau, w]`` of the rigid-body kernel (module glossary): the
    task's joint positions, their velocities, the actions (one torque per joint) and the
    task's affine inputs, raw (no angle features, no standardisation: the kernel takes the
    cosine and sine of a revolute ``q`` itself). Differentiable (index and concatenation).

    Args:
        task: a :class:`~mcpilco.envs.tasks.spec.TaskSpec` with ``joints``.
    """

    def __init__(self, task: Any) -> None:
        if not task.joints:
            raise ValueError(
                "task.joints: the rigid_body kernel needs the arm's joint positions (the "
                "task has none); use kernel 'rbf+mpk' or 'rbf' for other tasks"
            )
        self.q_idx = tuple(task.index(j) for j in task.joints)
        self.qd_idx = tuple(task.index(v) for v in task.joint_velocities)
        self.w_idx = tuple(task.index(a) for a in task.affine_inputs)
        self.joint_types = task.joint_type_string
        self.names = (
            list(task.joints)
            + list(task.joint_velocities)
            + [f"u{j}" for j in range(task.action_dim)]
            + list(task.affine_inputs)
        )

    @property
    def dim(self) -> int:
        return len(self.names)

    def __call__(self, state: Tensor, action: Tensor) -> Tensor:
        parts = [take(state, self.q_idx), take(state, self.qd_idx), action]
        if self.w_idx:
            parts.append(take(state, self.w_idx))
        return torch.cat(parts, dim=-1)


def transitions_to_dataset(
    states: np.ndarray | Tensor,
    actions: np.ndarray | Tensor,
    next_states: np.ndarray | Tensor,
    layout: StateLayout,
    inputs: Callable[[Tensor, Tensor], Tensor] | None = None,
) -> tuple[Tensor, Tensor]:
    """GP training set from transitions ``(x_t, u_t, x_{t+1})``.

    Returns ``X = x~_t`` (N, d) (``[f(x), u]``, or ``inputs(x, u)`` when given, e.g.
    :class:`JointSpaceInputs`) and ``Y = x_{t+1} - x_t`` on ``layout.output_idx`` (N, m),
    float64.
    """
    s = torch.as_tensor(np.asarray(states), dtype=torch.float64)
    a = torch.as_tensor(np.asarray(actions), dtype=torch.float64)
    s1 = torch.as_tensor(np.asarray(next_states), dtype=torch.float64)
    if a.ndim == 1:
        a = a[:, None]
    n = layout.n
    if s.ndim != 2 or s.shape[1] != n or s1.shape != s.shape or a.shape[0] != s.shape[0]:
        raise ValueError(
            f"expected states (N, {n}), actions (N, A), next_states (N, {n}); got "
            f"{tuple(s.shape)}, {tuple(a.shape)}, {tuple(s1.shape)}"
        )
    out = list(layout.output_idx)
    X = gp_inputs(s, a, layout) if inputs is None else inputs(s, a)
    return X, s1[:, out] - s[:, out]


class _CastPredictor(nn.Module):
    """A float64 predictor seen at another dtype: inputs cast up, ``(mean, var)`` cast back
    (differentiable)."""

    def __init__(self, inner: nn.Module, dtype: torch.dtype) -> None:
        super().__init__()
        self.inner, self.dtype = inner, dtype
        self.noise_variance = inner.noise_variance.to(dtype)

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor]:
        mean, var = self.inner(x.to(torch.float64))
        return mean.to(self.dtype), var.to(self.dtype)


class SpeedIntegrationDynamics(nn.Module):
    """One-step particle dynamics: sample ``Delta`` from a velocity-change model, integrate.

    Args:
        delta_model: callable ``x~ (..., F + A) -> (mean (..., m), var (..., m))`` of ``Delta``
            (a GP ``CachedPredictor`` or any stub with the same interface, e.g. in tests).
        dt: control period ``T_s`` [s].
        layout: the task's state layout (pairs, angles).
        noise_variance: (m,) variance added to ``var`` when ``sample_noise`` is True.
        sample_noise: add ``noise_variance`` to the sampling variance (default False, see
            the glossary).
        delta_bound: (m,) bound ``b`` on ``|Delta|`` (None: no clipping).
        joint_inputs: the GP input map of the rigid-body kernel (:class:`JointSpaceInputs`);
            None: ``x~ = [f(x), u]``.

    Shapes:
        ``forward(state (..., n), action (..., A), eps (..., m)) -> next_state (..., n)``;
        ``eps = None`` gives the mean prediction.
    """

    def __init__(
        self,
        delta_model: Callable[[Tensor], tuple[Tensor, Tensor]],
        dt: float,
        layout: StateLayout,
        noise_variance: Tensor | None = None,
        sample_noise: bool = False,
        delta_bound: Tensor | None = None,
        joint_inputs: JointSpaceInputs | None = None,
    ) -> None:
        super().__init__()
        if not dt > 0:
            raise ValueError(f"dt must be > 0, got {dt}")
        self.delta_model = delta_model
        self.dt = float(dt)
        self.layout = layout
        self.joint_inputs = joint_inputs
        self.sample_noise = bool(sample_noise)
        if sample_noise and noise_variance is None:
            raise ValueError("sample_noise=True needs noise_variance")
        self.register_buffer(
            "noise_variance", None if noise_variance is None else torch.as_tensor(noise_variance)
        )
        self.register_buffer(
            "delta_bound", None if delta_bound is None else torch.as_tensor(delta_bound)
        )

    def delta_distribution(self, state: Tensor, action: Tensor) -> tuple[Tensor, Tensor]:
        """``E[Delta]`` and ``var[Delta]`` (..., m) at ``(state, action)``."""
        if self.joint_inputs is None:
            x = gp_inputs(state, action, self.layout)
        else:
            x = self.joint_inputs(state, action)
        mean, var = self.delta_model(x)
        if self.sample_noise:
            var = var + self.noise_variance.to(var.dtype)
        return mean, var

    def forward(self, state: Tensor, action: Tensor, eps: Tensor | None = None) -> Tensor:
        mean, var = self.delta_distribution(state, action)
        return _SampleClipIntegrate.apply(
            state, mean, var, eps, self.delta_bound, self.dt, self.layout
        )


VAR_FLOOR = 1e-12
"""``var`` is clamped to at least this before the square root of the reparameterised sample."""


class SampleClipIntegrateSaved(NamedTuple):
    """What :func:`sample_clip_integrate_backward` needs: ``eps``, ``sqrt(max(var,
    VAR_FLOOR))`` and ``1[var >= VAR_FLOOR]`` (None for the mean prediction), ``1[|Delta| <=
    b]`` (None without a bound) and the integration's ``A^T``, ``S^T``."""

    eps: Tensor | None
    sd: Tensor | None
    var_on: Tensor | None
    inside: Tensor | None
    A: Tensor
    S: Tensor


def sample_clip_integrate_forward(
    state: Tensor,
    mean: Tensor,
    var: Tensor,
    eps: Tensor | None,
    bound: Tensor | None,
    dt: float,
    layout: StateLayout,
) -> tuple[Tensor, SampleClipIntegrateSaved]:
    """``Delta = clip(mean + sqrt(max(var, VAR_FLOOR)) eps, -b, b)``, ``x+ = x A^T + Delta S^T``
    (+ the oscillators' constant offset; eq. 5.9, :func:`speed_integration`), and what its
    backward needs (the sampling step's protocol, with
    :func:`sample_clip_integrate_backward`). ``eps = None``: ``Delta = mean``; ``bound = None``:
    no clip."""
    A, S, z = integration_matrices(dt, layout, state.dtype, state.device)
    if eps is None:
        delta, sd, var_on = mean, None, None
    else:
        var_on = var >= VAR_FLOOR
        sd = var.clamp_min(VAR_FLOOR).sqrt()
        delta = torch.addcmul(mean, sd, eps)
    inside = None
    if bound is not None:
        b = bound.to(delta.dtype)
        inside = (delta >= -b) & (delta <= b)
        delta = torch.clamp(delta, -b, b)
    lead, n = state.shape[:-1], state.shape[-1]
    nxt = torch.addmm(state.reshape(-1, n) @ A, delta.reshape(-1, S.shape[0]), S)
    if z is not None:
        nxt = nxt + z
    return nxt.reshape(*lead, n), SampleClipIntegrateSaved(eps, sd, var_on, inside, A, S)


def sample_clip_integrate_backward(
    saved: SampleClipIntegrateSaved, g: Tensor, need_var: bool = True
) -> tuple[Tensor, Tensor, Tensor | None]:
    """``(dJ/dx, dJ/dmean, dJ/dvar)`` from ``g = dJ/dx+``: ``g_x = g A``,
    ``g_Delta = (g S) 1[|Delta| <= b]``, ``g_mean = g_Delta``,
    ``g_var = g_Delta eps / (2 sqrt(var)) 1[var >= VAR_FLOOR]`` (the subgradients torch's
    ``clamp`` and ``sqrt`` use; None for the mean prediction or unless ``need_var``)."""
    eps, sd, var_on, inside, A, S = saved
    g2 = g.reshape(-1, g.shape[-1])
    g_state = (g2 @ A.T).reshape(g.shape)
    g_delta = (g2 @ S.T).reshape(*g.shape[:-1], S.shape[0])
    if inside is not None:
        g_delta = g_delta * inside
    g_var = None
    if eps is not None and need_var:
        g_var = g_delta * eps / (2.0 * sd) * var_on
    return g_state, g_delta, g_var


class _SampleClipIntegrate(torch.autograd.Function):
    """:func:`sample_clip_integrate_forward` and :func:`sample_clip_integrate_backward` as one
    autograd node."""

    @staticmethod
    def forward(ctx, state, mean, var, eps, bound, dt, layout):  # noqa: D102
        nxt, saved = sample_clip_integrate_forward(state, mean, var, eps, bound, dt, layout)
        ctx.save_for_backward(*saved)
        return nxt

    @staticmethod
    def backward(ctx, g):  # noqa: D102
        saved = SampleClipIntegrateSaved(*ctx.saved_tensors)
        grads = sample_clip_integrate_backward(saved, g, ctx.needs_input_grad[2])
        return (*grads, None, None, None, None)


def make_kernel_factory(
    kernel: str,
    input_dim: int,
    joint_inputs: JointSpaceInputs | None = None,
    min_lengthscale: float | None = None,
    mpk_degree: int = 2,
) -> Callable[[torch.Size], nn.Module]:
    """Kernel factory for ``GPRegressor``: ``k = k_RBF (+ k_MP^(p))``, eq. (5.10), or the
    rigid-body kernel (module glossary).

    ``kernel`` is ``"rbf+mpk"`` (RBF with ARD and output scale, plus an MPK of degree
    ``p = mpk_degree``), ``"rbf"`` (RBF only) or ``"rigid_body"`` (needs ``joint_inputs``,
    whose columns it reads; ``input_dim`` must be its ``dim``). The MPK of degree ``p``
    spans the monomials of degree ``<= p`` of the ``d`` GP inputs: ``p = 2`` (the thesis's
    cart-pole) adds the ``(d + 1)(d + 2) / 2`` quadratic features, ``p = 1`` (the MC-PILCO
    reference's UR5 task) only the ``d + 1`` affine ones, which is what a rigid arm's
    velocity change is in the torque at a fixed configuration; the rollout's cost of the
    MPK part grows with that feature count. ``min_lengthscale``: a lower bound ``l_min``
    on the RBF lengthscales (standardised inputs; None: only ``l > 0``). On noise-free
    simulated data the marginal likelihood can shrink a lengthscale towards a delta kernel
    (``1/l^2`` of ``1e12``), which predicts nothing away from the data and whose matmul
    form ``(X/l^2)^T x^ - 1/2 ||x^/l||^2 - ...`` cancels terms of ``1e13``: in float32 the
    particle rollout then overflows.
    """
    if kernel not in KERNEL_CHOICES:
        raise ValueError(f"kernel must be one of {KERNEL_CHOICES}, got {kernel!r}")
    check_mpk_degree(mpk_degree)
    if kernel == "rigid_body":
        if joint_inputs is None or joint_inputs.dim != input_dim:
            raise ValueError("the rigid_body kernel needs the task's JointSpaceInputs")

        def rigid_factory(batch_shape: torch.Size) -> nn.Module:
            from mcpilco.models.kernels import RigidBodyDynamicsKernel

            return RigidBodyDynamicsKernel(
                joint_inputs.joint_types,
                num_affine=len(joint_inputs.w_idx),
                batch_shape=batch_shape,
            )

        return rigid_factory

    def factory(batch_shape: torch.Size) -> nn.Module:
        import gpytorch

        bound = {}
        if min_lengthscale is not None:
            bound["lengthscale_constraint"] = gpytorch.constraints.GreaterThan(min_lengthscale)
        rbf = gpytorch.kernels.ScaleKernel(
            gpytorch.kernels.RBFKernel(ard_num_dims=input_dim, batch_shape=batch_shape, **bound),
            batch_shape=batch_shape,
        )
        if kernel == "rbf":
            return rbf
        from mcpilco.models.kernels import MPKernel

        return rbf + MPKernel(degree=mpk_degree, ard_num_dims=input_dim, batch_shape=batch_shape)

    return factory


def check_mpk_degree(mpk_degree: int) -> None:
    """Raise a ValueError naming ``mpk_degree`` unless it is an integer >= 1."""
    if isinstance(mpk_degree, bool) or not isinstance(mpk_degree, int) or mpk_degree < 1:
        raise ValueError(f"mpk_degree must be an integer >= 1, got {mpk_degree!r}")


class GPDynamicsModel:
    """Fits the ``Delta`` GPs of a task by marginal likelihood and builds particle dynamics.

    Args:
        task: the :class:`~mcpilco.envs.tasks.spec.TaskSpec` (state layout, action size,
            control period ``T_s``).
        kernel: one of :data:`KERNEL_CHOICES` (``"rigid_body"`` needs the task's ``joints``,
            with one action per joint).
        max_points: subset-of-data size (greedy, by posterior variance) when more
            transitions are available.
        adam_iters, adam_lr, lbfgs_iters: marginal-likelihood optimisation budget per fit.
        sample_noise: see :class:`SpeedIntegrationDynamics`.
        delta_clip_factor: ``c_clip``; the particle dynamics clip ``|Delta|`` at ``c_clip``
            times the largest ``|Delta|`` in the training data (None: no clipping).
        warm_start: start each :meth:`fit` from the previous hyperparameters instead of the
            kernel's initial values. Off by default, as in the MC-PILCO reference code: a
            warm start keeps the optimum of the first, poorer data, and a fresh fit predicts
            the next trial better.
        noise_min: lower bound of each GP's noise variance, as a fraction of its output's
            variance (:class:`~mcpilco.models.gp.GPRegressor`).
        min_lengthscale: lower bound of the RBF lengthscales on standardised inputs
            (:func:`make_kernel_factory`); None: none.
        mpk_degree: degree ``p`` of the MPK of ``"rbf+mpk"`` (:func:`make_kernel_factory`).
    """

    def __init__(
        self,
        task: Any,
        kernel: str = "rbf+mpk",
        max_points: int | None = 300,
        adam_iters: int = 200,
        adam_lr: float = 0.05,
        lbfgs_iters: int = 50,
        sample_noise: bool = False,
        delta_clip_factor: float | None = 3.0,
        warm_start: bool = False,
        noise_min: float = 1e-8,
        min_lengthscale: float | None = None,
        mpk_degree: int = 2,
    ) -> None:
        self.task = task
        self.noise_min = float(noise_min)
        if min_lengthscale is not None and not min_lengthscale > 0:
            raise ValueError(f"min_lengthscale must be > 0, got {min_lengthscale}")
        self.layout = StateLayout.from_task(task)
        if kernel not in KERNEL_CHOICES:
            raise ValueError(f"kernel must be one of {KERNEL_CHOICES}, got {kernel!r}")
        self.kernel = kernel
        self.delta_clip_factor = delta_clip_factor
        self.joint_inputs = JointSpaceInputs(task) if kernel == "rigid_body" else None
        self.input_names = (
            task.gp_input_names() if self.joint_inputs is None else self.joint_inputs.names
        )
        self.kernel_factory = make_kernel_factory(
            kernel, len(self.input_names), self.joint_inputs, min_lengthscale, mpk_degree
        )
        self.dt = float(task.dt)
        self.max_points = max_points
        self.adam_iters = int(adam_iters)
        self.adam_lr = float(adam_lr)
        self.lbfgs_iters = int(lbfgs_iters)
        self.sample_noise = bool(sample_noise)
        self.warm_start = bool(warm_start)
        self.gp_ = None
        self.delta_max_: Tensor | None = None

    def _new_gp(self):
        from mcpilco.models.gp import GPRegressor

        return GPRegressor(
            self.kernel_factory,
            standardize_x=self.joint_inputs is None,  # the rigid-body kernel takes raw q
            input_names=self.input_names,
            output_names=self.task.gp_output_names(),
            noise_min=self.noise_min,
        )

    def fit(self, states, actions, next_states) -> GPDynamicsModel:
        """Fit the GPs on all transitions (hyperparameters from their initial values, or
        from the previous fit with ``warm_start``)."""
        X, Y = transitions_to_dataset(states, actions, next_states, self.layout, self.joint_inputs)
        self.delta_max_ = Y.abs().amax(dim=0)
        if self.gp_ is None or not self.warm_start:
            self.gp_ = self._new_gp()
        self.gp_.fit(
            X,
            Y,
            adam_iters=self.adam_iters,
            adam_lr=self.adam_lr,
            lbfgs_iters=self.lbfgs_iters,
            max_points=self.max_points,
        )
        return self

    def _check_fitted(self) -> None:
        if self.gp_ is None:
            raise RuntimeError("GPDynamicsModel is not fitted: call fit(states, actions, ...)")

    def particle_dynamics(
        self, dtype: torch.dtype = torch.float32, fused: bool = True
    ) -> SpeedIntegrationDynamics:
        """Particle dynamics from the GP's cached predictor (dense tensors, ``dtype``).

        ``fused=True`` replaces the predictor by the equivalent
        :class:`~mcpilco.models.gp.fused.FusedRBFMPKPredictor` (fewer, larger
        ops; same posterior) when the kernel allows it.
        """
        self._check_fitted()
        if self.joint_inputs is not None and dtype != torch.float64:
            # the rigid-body posterior works on raw inputs (products of velocities, torques):
            # in float32 its cached solve misses the UR10 task's position changes by 35-51 mrad
            # (float64: 0.1-0.4), so it is evaluated in float64 and its outputs cast back
            pred = _CastPredictor(self.gp_.cached_predictor(torch.float64, validate=False), dtype)
        else:
            pred = self.gp_.cached_predictor(dtype=dtype, validate=False)
        if fused and self.joint_inputs is None:  # the rigid-body posterior has no fused form
            from mcpilco.models.gp.fused import FusedRBFMPKPredictor

            pred = FusedRBFMPKPredictor.from_cached(pred) or pred
        bound = None
        if self.delta_clip_factor is not None:
            dmax = self.delta_max_
            if dmax is None:
                dmax = torch.as_tensor(self.gp_.train_y_).abs().amax(dim=0)
            bound = (self.delta_clip_factor * dmax).to(dtype)
        return SpeedIntegrationDynamics(
            pred,
            self.dt,
            self.layout,
            noise_variance=pred.noise_variance,
            sample_noise=self.sample_noise,
            delta_bound=bound,
            joint_inputs=self.joint_inputs,
        )

    @torch.no_grad()
    def posterior_dtype_error(self, dtype: torch.dtype) -> float:
        """How far the particle dynamics' posterior mean at ``dtype`` is from the float64
        one, on the GP's own training inputs ``x_i``::

            e = max_j sqrt(mean_i (mu_j^dtype(x_i) - mu_j^f64(x_i))^2) / std_i(y_ij)

        (``j`` the outputs, ``y`` the training targets). The mean is ``k(x, X) alpha``
        with ``alpha = K^-1 y``; on noise-free data (a simulator without measurement
        noise) ``K`` is close to singular, ``alpha`` is large with alternating signs, and
        in float32 the sum cancels into round-off: the rollout then follows a model that
        is not the fitted one. 0 at float64."""
        self._check_fitted()
        if dtype == torch.float64:
            return 0.0
        x = torch.as_tensor(self.gp_.train_x_, dtype=torch.float64)
        ref = self.particle_dynamics(torch.float64).delta_model(x)[0]
        low = self.particle_dynamics(dtype).delta_model(x.to(dtype))[0].to(torch.float64)
        spread = torch.as_tensor(self.gp_.train_y_, dtype=torch.float64).std(dim=0)
        rms = ((low - ref) ** 2).mean(dim=0).sqrt() / spread.clamp_min(1e-300)
        return float(rms.max()) if torch.isfinite(rms).all() else math.inf

    @torch.no_grad()
    def one_step_rmse(self, states, actions, next_states) -> np.ndarray:
        """RMSE of the posterior mean of ``Delta`` on the given transitions, per output (m,)."""
        self._check_fitted()
        X, Y = transitions_to_dataset(states, actions, next_states, self.layout, self.joint_inputs)
        mean, _ = self.gp_.predict(X)
        return torch.sqrt(((mean - Y) ** 2).mean(0)).cpu().numpy()

    def save(self, path) -> None:
        self._check_fitted()
        self.gp_.save(path)

    def load(self, path) -> GPDynamicsModel:
        from mcpilco.models.gp import GPRegressor

        self.gp_ = GPRegressor.load(path, self.kernel_factory)
        self.delta_max_ = None  # set again by the next fit (or taken from the GP's targets)
        return self
