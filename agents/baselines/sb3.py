"""Model-free baselines: SAC, TD3 and PPO from stable-baselines3 on the registered task envs.

Glossary
--------
``n``
    environment steps of training (all parallel envs counted), budget ``steps``.
``K``
    evaluation period in env steps: after every ``K`` training steps the deterministic
    policy runs ``N_eval = 10`` episodes on a separate env (fixed reset seeds per run).
``p(T)``
    success rate of an evaluation: fraction of its episodes ending with ``info["success"]``,
    at ``T = n dt`` seconds of experience (``dt`` = control period, 0.05 s on the cartpoles).
checkpoint
    model (``.zip``), replay buffer (off-policy), ``VecNormalize`` statistics (when used)
    and the learning curve, written every ``checkpoint_every`` steps and at the end; the
    curve file is the commit point. ``resume=True`` reloads them and trains to ``steps``
    (evaluations after the checkpoint are redone; the episode in progress is dropped).

Hyper-parameters
----------------
rl-baselines3-zoo (https://github.com/DLR-RM/rl-baselines3-zoo, ``hyperparams/<algo>.yml``),
values copied into ``conf/sb3.yaml`` (:data:`HYPERPARAMS`), keyed by env id there:

* set ``"swingup"`` (the cart-poles'): the zoo's entries for
  ``InvertedPendulumSwingupBulletEnv-v0``, the zoo's cart-pole swing-up: ``sac.yml``
  (marked "Tuned"; the ``pybullet-defaults`` anchor), ``td3.yml`` (marked "Tuned"; its
  ``TimeFeatureWrapper`` from sb3-contrib is left out: our episodes have a fixed length of
  60 steps and SB3 bootstraps through time-limit truncation), ``ppo.yml``
  (``normalize: true`` = ``VecNormalize`` of observations and rewards).
* set ``"pendulum"``: the zoo's ``Pendulum-v1`` entries (``sac.yml``, ``ppo.yml`` marked
  "Tuned"; ``td3.yml`` ``Pendulum-v0``), a classic swing-up with short episodes.
* set ``"reacher"`` (``mcpilco/MarkerCameraReach-v0``): the zoo's SAC entry of
  ``ReacherBulletEnv-v0``, its arm reaching task (``sac.yml``, marked "Tuned": the
  ``pybullet-defaults``, the same values as the swing-up's).

Budgets (:data:`DEFAULT_STEPS`): 200k env steps for SAC / TD3 and 1M for PPO (the zoo trains
the swing-up for 300k / 300k / 2M steps of 1000-step episodes).
"""

from __future__ import annotations

import dataclasses
import io
import json
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.agents.baselines.common import (
    check_task_env,
    episode_steps,
    eval_seeds,
    evaluate_success,
    make_curve,
    save_curve,
    task_step_wrapper,
)
from mcpilco.agents.common.checkpoint import check_resume
from mcpilco.agents.common.trials import DEFAULT_ENV_ID, env_dt, make_env
from mcpilco.envs.tasks.spec import TaskSpec
from mcpilco.models.files import SIGNATURE_SUFFIX, read_signed, sign_file, write_atomic

ALGOS: tuple[str, ...] = ("sac", "td3", "ppo")
"""stable-baselines3 algorithms of the comparison."""

DEFAULT_STEPS: dict[str, int] = {"sac": 200_000, "td3": 200_000, "ppo": 1_000_000}
"""Default budgets in environment steps (10 000 s / 50 000 s of experience at 0.05 s)."""

HYPERPARAMS_FILE = Path(__file__).resolve().parent / "conf" / "sb3.yaml"
"""The zoo hyperparameter sets and the set of each env id."""


def _load_hyperparams() -> tuple[dict[str, dict[str, dict[str, Any]]], dict[str, str]]:
    from mcpilco.envs.yaml_files import read_yaml

    data = read_yaml(HYPERPARAMS_FILE, "SB3 hyperparameter file")
    return data["sets"], dict(data.get("envs") or {})


HYPERPARAMS, ENV_PRESETS = _load_hyperparams()
"""Zoo hyper-parameters per set and algorithm (zoo keys; see the module docstring), and the
set of each env id (:data:`HYPERPARAMS_FILE`)."""

# keys of HYPERPARAMS that are not constructor arguments of the SB3 algorithm
_RUNNER_KEYS = ("normalize", "n_envs", "noise_type", "noise_std")
CURVE_NAME = "curve.json"
RESUME_FIXED = ("algo", "env_id", "seed", "preset", "eval_every", "eval_episodes")
"""SB3Config fields that must not change when a run is resumed."""


@dataclass
class SB3Config:
    """One stable-baselines3 run.

    Attributes:
        algo: ``"sac"``, ``"td3"`` or ``"ppo"``.
        env_id: registered env with a task (``info["success"]`` at the episode end).
        steps: training budget in env steps (None: :data:`DEFAULT_STEPS`).
        eval_every: ``K``, env steps between evaluations.
        eval_episodes: episodes per evaluation (10).
        checkpoint_every: env steps between checkpoints (None: every 10 evaluations).
        preset: a set of :data:`HYPERPARAMS` (``"swingup"``, ``"pendulum"``,
            ``"reacher"``); None: the env's set in :data:`HYPERPARAMS_FILE`, or SB3's
            defaults for an env without one.
        overrides: hyper-parameters replacing the set's (zoo keys, e.g.
            ``{"learning_starts": 100}``).
        seed: seeds the algorithm, the training envs and the evaluation reset seeds.
        torch_threads: ``torch.set_num_threads`` (None: leave as is).
    """

    algo: str
    env_id: str = DEFAULT_ENV_ID
    steps: int | None = None
    eval_every: int = 2_000
    eval_episodes: int = 10
    checkpoint_every: int | None = None
    preset: str | None = None
    overrides: dict[str, Any] = field(default_factory=dict)
    seed: int = 0
    torch_threads: int | None = None

    def __post_init__(self) -> None:
        if self.algo not in ALGOS:
            raise ValueError(f"unknown SB3 algorithm {self.algo!r}; valid: {', '.join(ALGOS)}")
        if self.preset is None:
            self.preset = ENV_PRESETS.get(self.env_id, "sb3-defaults")
        if self.preset not in HYPERPARAMS and self.preset != "sb3-defaults":
            raise ValueError(
                f"unknown hyper-parameter preset {self.preset!r}; valid: {', '.join(HYPERPARAMS)}"
            )
        if self.steps is None:
            self.steps = DEFAULT_STEPS[self.algo]
        for name in ("steps", "eval_every", "eval_episodes"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        if self.checkpoint_every is None:
            self.checkpoint_every = 10 * self.eval_every
        if int(self.checkpoint_every) != self.checkpoint_every or self.checkpoint_every < 1:
            raise ValueError(
                f"checkpoint_every must be a positive integer, got {self.checkpoint_every!r}"
            )

    def hyperparams(self) -> dict[str, Any]:
        """The preset's zoo hyper-parameters with ``overrides`` applied."""
        hp = json.loads(json.dumps(HYPERPARAMS.get(self.preset, {}).get(self.algo, {})))
        hp.update(self.overrides)
        return hp

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SB3Config:
        """Inverse of :meth:`to_dict`; unknown fields are an error that names them."""
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"unknown SB3 config fields {unknown} (fields: {sorted(known)})")
        return cls(**d)


# ------------------------------------------------------------------------ construction
def _algo_class(algo: str):
    from stable_baselines3 import PPO, SAC, TD3

    return {"sac": SAC, "td3": TD3, "ppo": PPO}[algo]


def _split_hyperparams(cfg: SB3Config, action_dim: int) -> tuple[dict[str, Any], dict[str, Any]]:
    """(constructor kwargs of the SB3 algorithm, runner options) from the zoo keys."""
    hp = cfg.hyperparams()
    runner = {k: hp.pop(k) for k in _RUNNER_KEYS if k in hp}
    if "train_freq" in hp and isinstance(hp["train_freq"], list):
        hp["train_freq"] = tuple(hp["train_freq"])
    noise = runner.get("noise_type")
    if noise is not None:
        from stable_baselines3.common.noise import NormalActionNoise

        if noise != "normal":
            raise ValueError(f"noise_type {noise!r} is not supported (only 'normal')")
        std = float(runner.get("noise_std", 0.1))
        hp["action_noise"] = NormalActionNoise(np.zeros(action_dim), std * np.ones(action_dim))
    return hp, runner


def _make_vec_env(cfg: SB3Config, runner: dict[str, Any], stats_path: Path | None):
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    import mcpilco.envs  # noqa: F401  (registers the ids)

    task = TaskSpec.for_env(cfg.env_id)
    venv = make_vec_env(
        cfg.env_id,
        n_envs=int(runner.get("n_envs", 1)),
        seed=cfg.seed,
        env_kwargs={"max_episode_steps": episode_steps(cfg.env_id) * task.action_repeat},
        wrapper_class=task_step_wrapper,
        wrapper_kwargs={"task": task},
    )
    if runner.get("normalize"):
        if stats_path is not None:
            from stable_baselines3.common.save_util import load_from_pkl

            # VecNormalize.load unpickles the file by name; the same, from the signed bytes
            data = read_signed(stats_path, "SB3 normalisation statistics")
            stats = load_from_pkl(io.BytesIO(data))  # signed by this user's run
            if not isinstance(stats, VecNormalize):
                raise ValueError(f"{stats_path} holds no VecNormalize statistics")
            stats.set_venv(venv)
            venv = stats
            venv.training = True
        else:
            venv = VecNormalize(venv, norm_obs=True, norm_reward=True)
    return venv


CHECKPOINT_PATTERNS = (
    "model_*.zip",
    "replay_*.pkl",
    "vecnormalize_*.pkl",
    "*.zip.sig",
    "*.pkl.sig",
)  # the files of an SB3 run's checkpoints (with their signatures), rotated on each save
_CHECKPOINT_NAME = {
    "model": re.compile(r"model_\d+\.zip"),
    "replay": re.compile(r"replay_\d+\.pkl"),
    "vecnormalize": re.compile(r"vecnormalize_\d+\.pkl"),
}  # the names checkpoint() gives, the only ones a resumed run reads


def check_checkpoint_names(ckpt: Any, curve_path: Path) -> None:
    """Refuse a ``curve.json`` checkpoint entry that names anything but the run's own
    checkpoint files (``model_<n>.zip`` ... in the run folder: no path, no other file).

    Raises:
        ValueError: naming the entry and the file.
    """
    if not isinstance(ckpt, dict) or not isinstance(ckpt.get("steps"), int):
        raise ValueError(f"{curve_path}: its checkpoint entry is not a checkpoint of this run")
    for key, value in ckpt.items():
        if key == "steps" or value is None:
            continue
        rule = _CHECKPOINT_NAME.get(key)
        if rule is None or not isinstance(value, str) or not rule.fullmatch(value):
            raise ValueError(
                f"{curve_path}: checkpoint.{key} = {str(value)[:80]!r} is not a checkpoint file "
                "of this run folder; start the run again without resuming"
            )


def policy_act(model, vec_normalize=None) -> Callable[[np.ndarray], np.ndarray]:
    """Deterministic action of an SB3 model for one raw observation (normalised if needed)."""

    def act(obs: np.ndarray) -> np.ndarray:
        o = np.asarray(obs, dtype=np.float32)
        if vec_normalize is not None:
            o = vec_normalize.normalize_obs(o)
        action, _ = model.predict(o, deterministic=True)
        return np.asarray(action, dtype=np.float64)

    return act


# -------------------------------------------------------------------------- callback
def _success_callback_class():
    from stable_baselines3.common.callbacks import BaseCallback

    class SuccessEvalCallback(BaseCallback):
        """Evaluate the success rate every ``K`` env steps; checkpoint; progress bar.

        Args:
            eval_env: a separate ``gym.make`` env of the same id.
            eval_every: ``K``.
            seeds: reset seeds of the evaluation episodes (fixed for the run).
            horizon: steps per evaluation episode.
            dt: control period (experience ``T = n dt``).
            points: the learning curve so far (appended to in place).
            on_eval: called after each evaluation with the new point.
            on_checkpoint: called with the step count when a checkpoint is due.
            checkpoint_every: env steps between checkpoints.
            total_steps: the budget (progress bar length).
            progress: show a tqdm bar.
            vec_normalize: the training ``VecNormalize`` (its statistics normalise the
                evaluation observations), or None.
        """

        def __init__(
            self,
            eval_env,
            eval_every: int,
            seeds: list[int],
            horizon: int,
            dt: float,
            task: Any,
            points: list[dict[str, Any]],
            on_eval: Callable[[dict[str, Any]], None] | None = None,
            on_checkpoint: Callable[[int], None] | None = None,
            checkpoint_every: int | None = None,
            total_steps: int | None = None,
            progress: bool = False,
            vec_normalize=None,
        ) -> None:
            super().__init__(verbose=0)
            self.eval_env = eval_env
            self.eval_every = int(eval_every)
            self.seeds = list(seeds)
            self.horizon = int(horizon)
            self.dt = float(dt)
            self.task = task
            self.points = points
            self.on_eval = on_eval
            self.on_checkpoint = on_checkpoint
            self.checkpoint_every = checkpoint_every
            self.total_steps = total_steps
            self.progress = progress
            self.vec_normalize = vec_normalize
            self._bar = None
            self._next_eval = 0
            self._next_ckpt = 0
            self.eval_seconds = 0.0

        def _on_training_start(self) -> None:
            n = self.model.num_timesteps
            last = self.points[-1]["steps"] if self.points else 0
            self._next_eval = (max(n, last) // self.eval_every + 1) * self.eval_every
            if self.checkpoint_every:
                self._next_ckpt = (n // self.checkpoint_every + 1) * self.checkpoint_every
            if self.progress:
                from tqdm.auto import tqdm

                self._bar = tqdm(total=self.total_steps, initial=n, desc="env steps", unit="step")

        def evaluate(self) -> dict[str, Any]:
            """One evaluation at the current step count; appends and returns the point."""
            t0 = time.perf_counter()
            res = evaluate_success(
                self.eval_env,
                policy_act(self.model, self.vec_normalize),
                self.seeds,
                self.horizon,
                self.task,
            )
            self.eval_seconds += time.perf_counter() - t0
            res.pop("successes")
            n = int(self.model.num_timesteps)
            point = {"steps": n, "experience_s": n * self.dt}
            point.update(res)
            self.points.append(point)
            if self._bar is not None:
                self._bar.set_postfix(success=f"{point['success_rate']:.0%}")
            if self.on_eval is not None:
                self.on_eval(point)
            return point

        def _on_step(self) -> bool:
            n = self.model.num_timesteps
            if self._bar is not None:
                self._bar.update(n - self._bar.n)
            if n >= self._next_eval:
                self.evaluate()
                self._next_eval = (n // self.eval_every + 1) * self.eval_every
            if self.checkpoint_every and self.on_checkpoint is not None and n >= self._next_ckpt:
                self.on_checkpoint(n)
                self._next_ckpt = (n // self.checkpoint_every + 1) * self.checkpoint_every
            return True

        def _on_training_end(self) -> None:
            if self._bar is not None:
                self._bar.close()
                self._bar = None

    return SuccessEvalCallback


def __getattr__(name: str):
    if name == "SuccessEvalCallback":  # built lazily: importing SB3 is slow
        return _success_callback_class()
    raise AttributeError(name)


# ----------------------------------------------------------------------------- runner
def _atomic_json(path: Path, obj: Any) -> None:
    write_atomic(path, json.dumps(obj, indent=1))


def run_sb3(
    config: SB3Config,
    out_dir: str | Path,
    resume: bool = False,
    progress: bool = True,
    log: Callable[[str], None] | None = print,
) -> dict[str, Any]:
    """Train (or resume) one SB3 run with success evaluations; returns the learning curve.

    Writes ``out_dir/curve.json`` (format of :mod:`.common`, with the config, the
    hyper-parameters, the checkpoint files and cumulative wall/CPU seconds) and the
    checkpoint files ``model_<n>.zip``, ``replay_<n>.pkl``, ``vecnormalize_<n>.pkl``.
    """
    import torch

    check_task_env(config.env_id)
    if config.torch_threads is not None:
        torch.set_num_threads(int(config.torch_threads))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    curve_path = out / CURVE_NAME

    task = TaskSpec.for_env(config.env_id)
    horizon = task.horizon
    eval_env = make_env(config.env_id, horizon, task)
    dt = env_dt(eval_env, task)
    action_dim = int(np.prod(eval_env.action_space.shape))
    hp, runner = _split_hyperparams(config, action_dim)
    algo_cls = _algo_class(config.algo)

    points: list[dict[str, Any]] = []
    wall0 = cpu0 = eval0 = 0.0
    ckpt: dict[str, Any] | None = None
    if resume:
        if not curve_path.is_file():
            raise FileNotFoundError(f"no {curve_path} to resume; run without resume first")
        prev = json.loads(curve_path.read_text())
        check_resume(prev["config"], config, RESUME_FIXED)
        ckpt = prev.get("checkpoint")
        if ckpt is not None:
            points = [p for p in prev["points"] if p["steps"] <= ckpt["steps"]]
            wall0, cpu0 = float(prev["wall_s"]), float(prev["cpu_s"])
            eval0 = float(prev.get("eval_s", 0.0))
        elif log:
            log(f"{curve_path} has no checkpoint yet: starting from scratch")

    if ckpt is not None:
        check_checkpoint_names(ckpt, curve_path)
    stats = out / ckpt["vecnormalize"] if ckpt and ckpt.get("vecnormalize") else None
    venv = _make_vec_env(config, runner, stats)
    if ckpt is not None:
        # SB3's files hold pickles: read only when this user's run signed them
        data = read_signed(out / ckpt["model"], "SB3 model")
        model = algo_cls.load(io.BytesIO(data), env=venv, device="cpu")
        model._last_obs = None  # the saved env state is gone: reset on learn
        if ckpt.get("replay"):
            buffer = read_signed(out / ckpt["replay"], "SB3 replay buffer")
            model.load_replay_buffer(io.BytesIO(buffer))
        if log:
            log(f"resumed {out / ckpt['model']} at {ckpt['steps']} env steps")
    else:
        model = algo_cls("MlpPolicy", venv, seed=config.seed, device="cpu", verbose=0, **hp)

    t_wall, t_cpu = time.perf_counter(), time.process_time()
    state: dict[str, Any] = {"checkpoint": ckpt}

    def write_curve(complete: bool = False) -> None:
        curve = make_curve(
            config.algo,
            config.env_id,
            config.seed,
            dt,
            points,
            config=config.to_dict(),
            hyperparams=config.hyperparams(),
            horizon=horizon,
            budget_steps=int(config.steps),
            steps_done=int(model.num_timesteps),
            wall_s=wall0 + time.perf_counter() - t_wall,
            cpu_s=cpu0 + time.process_time() - t_cpu,
            eval_s=cb.eval_seconds,
            checkpoint=state["checkpoint"],
            complete=complete,
        )
        save_curve(curve_path, curve)

    def checkpoint(n: int) -> None:
        files = {"steps": int(n), "model": f"model_{n}.zip"}
        model.save(str(out / files["model"]))
        if hasattr(model, "save_replay_buffer"):
            files["replay"] = f"replay_{n}.pkl"
            model.save_replay_buffer(str(out / files["replay"]))
        if cb.vec_normalize is not None:
            files["vecnormalize"] = f"vecnormalize_{n}.pkl"
            cb.vec_normalize.save(str(out / files["vecnormalize"]))
        for key, name in files.items():
            if key != "steps":
                sign_file(out / name)  # read back only through read_signed
        state["checkpoint"] = files
        write_curve()  # the commit point
        keep = {v for k, v in files.items() if k != "steps"}
        keep |= {name + SIGNATURE_SUFFIX for name in keep}
        for pattern in CHECKPOINT_PATTERNS:
            for old_file in out.glob(pattern):
                if old_file.name not in keep:
                    old_file.unlink(missing_ok=True)

    def on_eval(point: dict[str, Any]) -> None:
        write_curve()
        if log:
            log(
                f"{config.algo} seed {config.seed}: {point['steps']} steps "
                f"({point['experience_s']:.0f} s of experience): success "
                f"{point['success_rate']:.0%}, cost {point['mean_cost']:.1f}"
            )

    cb = _success_callback_class()(
        eval_env,
        config.eval_every,
        eval_seeds(config.seed, config.eval_episodes),
        horizon,
        dt,
        task,
        points,
        on_eval=on_eval,
        on_checkpoint=checkpoint,
        checkpoint_every=config.checkpoint_every,
        total_steps=config.steps,
        progress=progress,
        vec_normalize=venv if runner.get("normalize") else None,
    )
    cb.eval_seconds = eval0
    try:
        remaining = int(config.steps) - int(model.num_timesteps)
        if remaining > 0:
            model.learn(total_timesteps=remaining, callback=cb, reset_num_timesteps=ckpt is None)
        if getattr(cb, "model", None) is None:  # no training left: learn() never set it
            cb.init_callback(model)
        last = points[-1]["steps"] if points else -config.eval_every
        if model.num_timesteps - last >= max(1, config.eval_every // 2):
            cb.evaluate()  # final evaluation, unless one was done within K/2 steps
        checkpoint(int(model.num_timesteps))
        write_curve(complete=True)
    finally:
        eval_env.close()
        venv.close()
    return json.loads(curve_path.read_text())


__all__ = [
    "ALGOS",
    "DEFAULT_STEPS",
    "HYPERPARAMS",
    "SB3Config",
    "policy_act",
    "run_sb3",
]
