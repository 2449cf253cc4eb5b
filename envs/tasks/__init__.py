"""Task specifications of the registered environments, as plain data (YAML, no torch).

A task file declares what a model-based agent needs to know about an env: state names and
how the state is read from an observation, angle coordinates, position/velocity pairs,
action bounds, control period, horizon, initial-state distribution, cost and success test.
The agent turns it into a :class:`mcpilco.agents.mc_pilco.task.TaskSpec`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

TASK_DIR = Path(__file__).resolve().parent
"""Folder of the shipped task files."""

TASK_FILES: dict[str, str] = {
    "mcpilco/CartpoleSwingUp-v0": "cartpole_swingup.yaml",
    "mcpilco/DMCCartpoleSwingUp-v0": "dmc_cartpole_swingup.yaml",
    "InvertedPendulum-v5": "inverted_pendulum_v5.yaml",
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
            f"{', '.join(task_ids())} (write one for your env: see TaskSpec)"
        )
    return read_yaml(TASK_DIR / TASK_FILES[env_id], "task file")
