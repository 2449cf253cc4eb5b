"""Particle RMSE of the RBF+MPK and the RBF-only GP (thesis Fig. 5.5), the ``rmse`` and
``rmse_runs`` parts of ``mcpilco-bench-mcpilco``.

Both GPs are fitted on the same data; ``M`` particles are rolled out through each under a
fixed learned swing-up policy from the real initial state, and the RMSE of theta between the
particles and the real trajectory of that policy is taken per time step (root mean over the
particles) and over the horizon. :func:`particle_rmse` fits on random-exploration data,
:func:`particle_rmse_on_run` on a finished run's own data before its last trial.
:func:`model_particles` (a GP of any kernel label of :data:`KERNEL_ARGS` fitted and rolled
out on any task) is the shared step; the tracking bench's kernel comparison uses it too.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.agents.mc_pilco import DEFAULT_ENV_ID, MCPilcoConfig, TaskSpec
from mcpilco.experiments.mcpilco.timing import exploration_data

__all__ = [
    "KERNEL_ARGS",
    "find_swingup_policy",
    "model_particles",
    "group_rmse_runs",
    "particle_rmse",
    "particle_rmse_on_run",
    "plot_rmse",
    "plot_rmse_runs",
    "summarise_rmse",
    "summarise_rmse_runs",
    "swingup_runs",
]


def find_swingup_policy(runs_dir: Path) -> Path:
    """The checkpoint of the first run under ``runs_dir`` (sorted) whose last trial swung the
    pole up; its policy is the fixed "learned policy that correctly executes the swing-up" of
    thesis Fig. 5.5."""
    found = swingup_runs(runs_dir)
    if found:
        return found[0]
    raise FileNotFoundError(
        f"no run under {runs_dir} ends with a successful swing-up; run the 'runs' part first "
        "or pass --rmse-policy CHECKPOINT"
    )


KERNEL_ARGS: dict[str, dict[str, Any]] = {
    "rbf+mpk": {"kernel": "rbf+mpk", "mpk_degree": 2},
    "rbf+mpk1": {"kernel": "rbf+mpk", "mpk_degree": 1},
    "rbf": {"kernel": "rbf"},
    "rigid_body": {"kernel": "rigid_body"},
}  # kernel labels of the comparisons -> GPDynamicsModel arguments


def model_particles(
    task: TaskSpec,
    data: tuple,
    policy,
    x0: np.ndarray,
    horizon: int,
    kernel: str,
    num_particles: int,
    seed: int,
    **fit_kwargs: Any,
) -> np.ndarray:
    """The particles ``(M, H + 1, n)`` of a GP with kernel label ``kernel``
    (:data:`KERNEL_ARGS`) fitted on ``data = (s, a, s')`` with ``fit_kwargs``
    (:class:`~mcpilco.agents.mc_pilco.GPDynamicsModel` arguments), rolled out under
    ``policy`` (evaluation mode) from the real state ``x0`` for ``horizon`` steps,
    random numbers from ``seed``."""
    import torch

    from mcpilco.agents.mc_pilco import (
        GPDynamicsModel,
        MCPilcoLoss,
        SaturatingCost,
        make_policy_module,
    )

    model = GPDynamicsModel(task, **KERNEL_ARGS[kernel], **fit_kwargs).fit(*data)
    torch.manual_seed(seed)
    loss = MCPilcoLoss(
        make_policy_module(policy),
        model.particle_dynamics(),
        SaturatingCost.from_task(task),
        horizon,
        num_particles,
        task.init_mean,
    )
    policy.eval()
    with torch.no_grad():
        x = torch.as_tensor(np.asarray(x0), dtype=torch.float32).expand(num_particles, -1)
        return loss.rollout(initial_state=x.clone()).states.numpy()


def _theta_rmse_both_kernels(
    data: tuple,
    policy,
    real: np.ndarray,
    num_particles: int,
    seed: int,
    keep_particles: bool = False,
    **fit_kwargs: Any,
) -> dict[str, Any]:
    """Fit an RBF+MPK and an RBF-only GP on ``data = (s, a, s')``, roll ``M`` particles out
    through each under ``policy`` from ``real[0]``; per kernel the RMSE of theta against
    ``real[1:, 2]`` over particles and steps (``kernel``), per step (``kernel_per_step``)
    and, with ``keep_particles``, the first 100 particles' theta (``kernel_particles``)."""
    out: dict[str, Any] = {}
    task = TaskSpec.for_env(DEFAULT_ENV_ID)
    for kernel in ("rbf+mpk", "rbf"):
        parts = model_particles(
            task, data, policy, real[0], len(real) - 1, kernel, num_particles, seed, **fit_kwargs
        )
        err = parts[:, 1:, 2] - real[None, 1:, 2]
        out[kernel] = float(np.sqrt(np.mean(err**2)))
        out[f"{kernel}_per_step"] = np.sqrt(np.mean(err**2, axis=0)).tolist()
        if keep_particles:
            out[f"{kernel}_particles"] = parts[:100, :, 2].tolist()
    return out


def particle_rmse(
    seed: int,
    policy_ckpt: Path,
    num_particles: int = 400,
    env_id: str = DEFAULT_ENV_ID,
    explore_hold: int = 1,
) -> dict:
    """Thesis Fig. 5.5: RBF+MPK and RBF-only GPs fitted on the same 3 s of random exploration
    (seed ``seed``, actions held ``explore_hold`` steps); ``M`` particles rolled out through
    each under a fixed learned swing-up policy, from the real initial state; per time step,
    the RMSE of theta between the particles and the real trajectory of that policy (root mean
    over particles), and its mean over the 60 steps."""
    import torch

    from mcpilco.agents.common.checkpoint import load_checkpoint
    from mcpilco.agents.common.trials import make_env, run_episode
    from mcpilco.agents.mc_pilco import SquashedRBFPolicy
    from mcpilco.agents.mc_pilco.policy import policy_act

    torch.set_num_threads(1)
    s, a, s1, _ = exploration_data(env_id, 60, 100 + seed, explore_hold)  # 3 s
    ckpt = load_checkpoint(policy_ckpt)
    task = TaskSpec.for_env(env_id)
    policy = SquashedRBFPolicy(**ckpt["policy_settings"])
    policy.load_state_dict(ckpt["policy"])
    env = make_env(env_id, task.horizon, task)
    real = run_episode(env, policy_act(policy), 5000 + seed, task.horizon, task)["states"]
    env.close()
    out: dict[str, Any] = {"seed": seed, "real_success_theta_end": float(real[-1, 2])}
    first = seed == 0  # the plot shows the particles of seed 0
    out.update(_theta_rmse_both_kernels((s, a, s1), policy, real, num_particles, seed, first))
    if first:
        out["real_theta"] = real[:, 2].tolist()
    return out


def particle_rmse_on_run(ckpt_path: Path, num_particles: int = 400) -> dict[str, Any]:
    """Thesis Fig. 5.5 on a finished run's own data: RBF+MPK and RBF-only GPs fitted (with
    the run's GP settings) on every transition before its last trial; ``M`` particles under
    the policy of that trial from its real initial state, against its real trajectory (the
    noise-free states the env recorded). The run's last trial must have swung up."""
    import torch

    from mcpilco.agents.common.checkpoint import load_checkpoint
    from mcpilco.agents.common.trials import transitions
    from mcpilco.agents.mc_pilco import SquashedRBFPolicy

    torch.set_num_threads(1)
    ckpt = load_checkpoint(ckpt_path)
    cfg = MCPilcoConfig.from_dict(ckpt["config"])
    episodes, arrays = ckpt["episodes"], ckpt["arrays"]
    if len(episodes) < 2 or not ckpt["records"][-1]["success"]:
        raise ValueError(f"{ckpt_path}: needs a run whose last policy trial swung up")
    policy = SquashedRBFPolicy(**ckpt["policy_settings"])
    policy.load_state_dict(ckpt["policy"])
    real = np.asarray(arrays[-1]["real"])
    out: dict[str, Any] = {
        "run": str(ckpt_path),
        "env_id": cfg.env_id,
        "run_kernel": cfg.kernel,
        "n_data": int(sum(len(e["actions"]) for e in episodes[:-1])),
    }
    out.update(
        _theta_rmse_both_kernels(
            transitions(episodes[:-1]),
            policy,
            real,
            num_particles,
            cfg.seed,
            max_points=cfg.max_points,
            adam_iters=cfg.gp_adam_iters,
            lbfgs_iters=cfg.gp_lbfgs_iters,
        )
    )
    return out


def swingup_runs(runs_dir: Path) -> list[Path]:
    """Checkpoints under ``runs_dir`` (sorted) whose last trial swung the pole up."""
    from mcpilco.agents.common.checkpoint import load_checkpoint

    found = []
    for ckpt_path in sorted(Path(runs_dir).glob("**/checkpoint.pt")):
        ckpt = load_checkpoint(ckpt_path)
        if len(ckpt["records"]) > 1 and ckpt["records"][-1]["success"]:
            found.append(ckpt_path)
    return found


def group_rmse_runs(per_run: list[dict]) -> dict[str, list[dict]]:
    """``particle_rmse_on_run`` results by the kernel the run learned with and its env (runs
    on different envs are never pooled), keys sorted."""
    groups: dict[str, list[dict]] = {}
    for r in per_run:
        groups.setdefault(f"{r['run_kernel']} on {r['env_id']}", []).append(r)
    return dict(sorted(groups.items()))


def summarise_rmse_runs(per_run: list[dict]) -> dict[str, dict]:
    """Per group (:func:`group_rmse_runs`): runs, mean / median RMSE of both GPs, and the
    number of runs where the RBF+MPK particles are closer (lower RMSE)."""
    groups: dict[str, dict] = {}
    for kern, rows in group_rmse_runs(per_run).items():
        g: dict[str, Any] = {"runs": len(rows)}
        for k in ("rbf+mpk", "rbf"):
            vals = [r[k] for r in rows]
            g[k] = {"mean": float(np.mean(vals)), "median": float(np.median(vals))}
        g["mpk_better"] = int(sum(r["rbf+mpk"] < r["rbf"] for r in rows))
        groups[kern] = g
    return groups


def summarise_rmse(per_seed: list[dict]) -> dict[str, Any]:
    """:func:`particle_rmse` over seeds: per kernel the mean, standard deviation and median
    RMSE, and the number of seeds where the RBF+MPK particles are closer (lower RMSE)."""
    rm: dict[str, Any] = {"seeds": len(per_seed), "per_seed": per_seed}
    for k in ("rbf+mpk", "rbf"):
        vals = [p[k] for p in per_seed]
        rm[k] = {
            "mean": float(np.mean(vals)),
            "std": float(np.std(vals)),
            "median": float(np.median(vals)),
        }
    rm["mpk_better"] = int(sum(p["rbf+mpk"] < p["rbf"] for p in per_seed))
    return rm


def plot_rmse(rm: dict, path: Path) -> None:
    """Thesis Fig. 5.5: theta particles of both models against the real trajectory (seed 0),
    and the per-step RMSE (median over seeds) of both."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    first = rm["per_seed"][0]
    t = np.arange(len(first["real_theta"])) * 0.05
    fig, axes = plt.subplots(3, 1, figsize=(7, 8), sharex=True)
    for ax, k in zip(axes[:2], ("rbf+mpk", "rbf"), strict=True):
        ax.plot(t, np.asarray(first[f"{k}_particles"]).T, color="tab:blue", alpha=0.12, lw=0.7)
        ax.plot(t, first["real_theta"], "o", color="black", ms=2.5, label="real")
        ax.set_ylabel("theta [rad]")
        ax.set_title(f"GP kernel {k}: particles vs real (exploration seed 0)")
        ax.set_ylim(-2 * np.pi, 2 * np.pi)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper left", fontsize=8)
    for k, col in (("rbf+mpk", "tab:blue"), ("rbf", "tab:red")):
        per = np.median([p[f"{k}_per_step"] for p in rm["per_seed"]], axis=0)
        axes[2].semilogy(t[1:], per, color=col, label=k)
    axes[2].set_ylabel("RMSE theta [rad]")
    axes[2].set_xlabel("time [s]")
    axes[2].set_title(f"median over {rm['seeds']} exploration seeds")
    axes[2].legend(fontsize=8)
    axes[2].grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_rmse_runs(per_run: list[dict], path: Path) -> None:
    """Part ``rmse_runs``: per time step, the median over runs of the theta RMSE of both GPs,
    one panel per kernel the runs learned with."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = group_rmse_runs(per_run)
    fig, axes = plt.subplots(1, len(groups), figsize=(6 * len(groups), 3.6), squeeze=False)
    for ax, (g, rows) in zip(axes[0], groups.items(), strict=True):
        for k, col in (("rbf+mpk", "tab:blue"), ("rbf", "tab:red")):
            per = np.median([r[f"{k}_per_step"] for r in rows], axis=0)
            ax.plot(np.arange(1, len(per) + 1) * 0.05, per, color=col, label=f"GP {k}")
        ax.set_title(f"{len(rows)} runs learned with {g}\n(GPs fitted on their data)", fontsize=10)
        ax.set_xlabel("time [s]")
        ax.set_ylabel("median RMSE theta [rad]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
