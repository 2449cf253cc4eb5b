"""MC-PILCO from the command line: a config from options, the checks before a run, the run.

``mcpilco-train`` parses its arguments and calls these: :func:`config_from_options` builds
the :class:`~mcpilco.agents.mc_pilco.config.MCPilcoConfig` the same way for every caller (the
env's config file and preset, then ``key=value`` overrides, then a task file, then explicit
options), :func:`check_config` refuses a config that cannot run before any work is done, and
:func:`train` runs it.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from mcpilco.agents.common.records import RunSummary
from mcpilco.agents.common.trials import DEFAULT_ENV_ID, make_env
from mcpilco.agents.mc_pilco.config import MCPilcoConfig, budget_report, load_config, parse_set
from mcpilco.agents.mc_pilco.trainer import Trainer, check_compile_toolchain

__all__ = [
    "budget_report",
    "check_config",
    "config_from_options",
    "load_task_file",
    "parse_env_kwargs",
    "train",
]


def load_task_file(path: str | Path) -> dict[str, Any]:
    """The mapping of a YAML task file (validated later, by :class:`TaskSpec`).

    Raises:
        ValueError: the file cannot be read, is not YAML, is empty or not a mapping
            (:func:`~mcpilco.envs.yaml_files.read_yaml`); the message names the file.
    """
    from mcpilco.envs.yaml_files import read_yaml

    return read_yaml(path, "--task file")


def parse_env_kwargs(text: str | Path) -> dict[str, Any]:
    """``--env-kwargs``: a YAML mapping given inline (``"{g: 9.81}"``) or as a file path.

    Raises:
        ValueError: not YAML, or not a mapping with string keys.
    """
    from mcpilco.envs.yaml_files import parse_yaml, read_yaml

    path = Path(text)
    try:
        is_file = path.is_file()
    except OSError:  # a mapping too long to be a path
        is_file = False
    try:
        if is_file:
            data = read_yaml(path, "--env-kwargs file", mapping=False)
        else:
            data = parse_yaml(str(text), "--env-kwargs")
    except OSError as err:
        raise ValueError(f"--env-kwargs {text}: {err}") from None
    if data is None:
        return {}
    if not isinstance(data, dict) or not all(isinstance(k, str) for k in data):
        raise ValueError(
            f"--env-kwargs {text}: expected a mapping of keyword arguments (e.g. '{{g: 9.81}}' "
            "or a YAML file), got {data!r}"
        )
    return data


def config_from_options(
    env_id: str = DEFAULT_ENV_ID,
    preset: str | None = "default",
    set_items: list[str] | None = None,
    task_file: str | Path | None = None,
    config_file: str | Path | None = None,
    env_kwargs: str | Path | dict[str, Any] | None = None,
    **options: Any,
) -> MCPilcoConfig:
    """The config of ``env_id``: its config file, the user's ``config_file`` (same format)
    and ``preset`` (:func:`~mcpilco.agents.mc_pilco.config.load_config`), then ``set_items``
    (``["opt.max_steps=500", ...]``, :func:`~mcpilco.agents.mc_pilco.config.parse_set`), then
    the task of ``task_file``, the keyword arguments of ``gym.make`` in ``env_kwargs`` (a
    mapping, or :func:`parse_env_kwargs`'s text; merged over the config's ``env_kwargs``),
    then ``options`` (:meth:`MCPilcoConfig.with_overrides` keywords; a None option keeps
    the value before it). Validated by :class:`MCPilcoConfig`. ``env_id`` may name the
    module that registers it (``"pkg.module:MyEnv-v0"``).

    Raises:
        ValueError: an unknown preset or field, a value out of range, an unreadable task,
            config or env-kwargs file.
    """
    overrides = parse_set(set_items)
    if task_file is not None:
        overrides["task"] = load_task_file(task_file)
    if env_kwargs is not None:
        kwargs = env_kwargs if isinstance(env_kwargs, dict) else parse_env_kwargs(env_kwargs)
        overrides["env_kwargs"] = {**(overrides.get("env_kwargs") or {}), **kwargs}
    config = load_config(env_id, preset=preset, overrides=overrides, config_file=config_file)
    return config.with_overrides(**options)


def check_config(config: MCPilcoConfig, build_env: bool = True) -> None:
    """Refuse, before any work, a config that cannot run here: an unknown env id or task,
    spaces or horizon that do not match the task, states the env does not observe, a
    success set every sampled reset already lies in (with ``build_env``: the env is made,
    reset a few times by :meth:`~mcpilco.envs.tasks.spec.TaskSpec.check_reset` and
    closed), a device this machine lacks, ``compile_rollout`` without a C++ compiler.

    Raises:
        ValueError: naming what is wrong.
    """
    from mcpilco.models.device import resolve_device

    task = config.task_spec()
    if build_env:
        env = make_env(config.env_id, task.horizon, task, config.env_kwargs)
        try:
            task.check_reset(env, seed=config.seed)
        finally:
            env.close()
    device = resolve_device(config.device)
    if config.compile_rollout:
        check_compile_toolchain(device, config.rollout_backend)


def train(
    config: MCPilcoConfig,
    out_dir: str | Path,
    *,
    resume: bool = False,
    overwrite: bool = False,
    progress: bool = True,
    write_rrd: bool = True,
    log: Callable[[str], None] | None = print,
) -> RunSummary:
    """Run (or resume) ``config`` in ``out_dir``
    (:class:`~mcpilco.agents.mc_pilco.trainer.Trainer`; call :func:`check_config` first to
    refuse a config that cannot run before anything is written). The process keeps the
    memory it frees (:func:`~mcpilco.models.device.retain_host_memory`), so that the
    rollout's freed blocks cause no page faults on reuse."""
    from mcpilco.models.device import retain_host_memory

    retain_host_memory()
    return Trainer(
        config,
        out_dir,
        resume=resume,
        progress=progress,
        log=log,
        write_rrd=write_rrd,
        overwrite=overwrite,
    ).run()
