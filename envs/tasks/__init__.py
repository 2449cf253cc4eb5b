"""Task specifications of the registered environments, as plain data (YAML, no torch).

A task file declares what a model-based agent needs to know about an env: state names and
how the state is read from an observation (derived states), angle coordinates,
position/velocity pairs, action bounds, control period, horizon, initial-state distribution,
the env's reset options, cost and success test.
It loads as a :class:`~mcpilco.envs.tasks.spec.TaskSpec` (:mod:`.spec`, no torch either).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

TASK_DIR = Path(__file__).resolve().parent
"""Folder of the shipped task files."""

TASK_FILES: dict[str, str] = {
    "mcpilco/CartpoleSwingUp-v0": "cartpole_swingup.yaml",
    "mcpilco/DMCCartpoleSwingUp-v0": "dmc_cartpole_swingup.yaml",
    "dm_control/cartpole-swingup-v0": "dmc_cartpole_swingup_suite.yaml",
    "dm_control/pendulum-swingup-v0": "dmc_pendulum_swingup.yaml",
    "InvertedDoublePendulum-v5": "inverted_double_pendulum_v5.yaml",
    "InvertedPendulum-v5": "inverted_pendulum_v5.yaml",
    "Pendulum-v1": "pendulum_v1.yaml",
    "mcpilco/UR10-v0": "ur10_tracking.yaml",
    "mcpilco/MarkerCameraReach-v0": "marker_camera_reaching.yaml",
}
"""Env id -> task file in :data:`TASK_DIR`."""


def task_ids() -> list[str]:
    """The env ids that ship a task specification."""
    return sorted(TASK_FILES)


def task_data(env_id: str) -> dict[str, Any]:
    """The task specification of ``env_id`` as a plain dict (parsed YAML).

    Raises:
        KeyError: no task ships for ``env_id`` (the message lists those that do).
    """
    from mcpilco.envs.yaml_files import read_yaml

    if env_id not in TASK_FILES:
        raise KeyError(
            f"no task specification ships for {env_id!r}; tasks exist for "
            f"{', '.join(task_ids())} (write a task file for your env and pass it with --task; "
            "the MC-PILCO docs list its fields)"
        )
    return read_yaml(TASK_DIR / TASK_FILES[env_id], "task file")
