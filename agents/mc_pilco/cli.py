"""MC-PILCO from the command line: a config from options, the checks before a run, the run.

``mcpilco-train`` parses its arguments and calls these: :func:`config_from_options` builds
the :class:`~mcpilco.agents.mc_pilco.loop.MCPilcoConfig` the same way for every caller (the
env's config file and preset, then ``key=value`` overrides, then a task file, then explicit
options), :func:`check_config` refuses a config that cannot run before any work is done, and
:func:`train` runs it.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from mcpilco.agents.mc_pilco.loop import (
    DEFAULT_ENV_ID,
    MCPilcoConfig,
    RunSummary,
    check_compile_toolchain,
    load_config,
    make_env,
    parse_set,
    run_mcpilco,
)

__all__ = ["check_config", "config_from_options", "load_task_file", "train"]


def load_task_file(path: str | Path) -> dict[str, Any]:
    """The mapping of a YAML task file (validated later, by :class:`TaskSpec`).

    Raises:
        ValueError: the file cannot be read, is not YAML, is empty or not a mapping
            (:func:`~mcpilco.envs.yaml_files.read_yaml`); the message names the file.
    """
    from mcpilco.envs.yaml_files import read_yaml

    return read_yaml(path, "--task file")


def config_from_options(
    env_id: str = DEFAULT_ENV_ID,
    preset: str | None = "default",
    set_items: list[str] | None = None,
    task_file: str | Path | None = None,
    **options: Any,
) -> MCPilcoConfig:
    """The config of ``env_id``: its config file and ``preset``, then ``set_items``
    (``["opt.max_steps=500", ...]``, :func:`~mcpilco.agents.mc_pilco.loop.parse_set`), then
    the task of ``task_file``, then ``options`` (:meth:`MCPilcoConfig.with_overrides`
    keywords; a None option keeps the value before it). Validated by :class:`MCPilcoConfig`.

    Raises:
        ValueError: an unknown preset or field, a value out of range, an unreadable task file.
    """
    overrides = parse_set(set_items)
    if task_file is not None:
        overrides["task"] = load_task_file(task_file)
    config = load_config(env_id, preset=preset, overrides=overrides)
    return config.with_overrides(**options)


def check_config(config: MCPilcoConfig, build_env: bool = True) -> None:
    """Refuse, before any work, a config that cannot run here: an unknown env id or task,
    spaces or horizon that do not match the task (with ``build_env``: the env is made and
    closed), a device this machine lacks, ``compile_rollout`` without a C++ compiler.

    Raises:
        ValueError: naming what is wrong.
    """
    from mcpilco.models.device import resolve_device

    task = config.task_spec()
    if build_env:
        make_env(config.env_id, task.horizon, task, config.env_kwargs).close()
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
    (:func:`~mcpilco.agents.mc_pilco.loop.run_mcpilco`; call :func:`check_config` first to
    refuse a config that cannot run before anything is written). The process keeps the
    memory it frees (:func:`~mcpilco.models.device.retain_host_memory`), so that the
    rollout's freed blocks cause no page faults on reuse."""
    from mcpilco.models.device import retain_host_memory

    retain_host_memory()
    return run_mcpilco(
        config,
        out_dir,
        resume=resume,
        progress=progress,
        log=log,
        write_rrd=write_rrd,
        overwrite=overwrite,
    )
