"""Start an episode from a given state: set named entries of an env's state after its reset.

Evaluation episodes of a task (``TaskSpec.eval_init``) start from a named initial
distribution, e.g. a pendulum hanging at rest, that an env's own reset does not draw. The
entries are named as the env's state is kept:

* :class:`mcpilco.envs.dmc.DMControlEnv`: its physics names, ``qpos[joint]`` and
  ``qvel[joint]`` (:attr:`~mcpilco.envs.dmc.DMControlEnv.physics_names`);
* a Gymnasium MuJoCo env (``set_state(qpos, qvel)``): ``qpos[k]`` and ``qvel[k]``, ``k`` the
  index in ``data.qpos`` / ``data.qvel``;
* a classic-control env that keeps its state in an array ``state`` (``Pendulum-v1``,
  ``CartPole-v1``, ``Acrobot-v1``, ``MountainCarContinuous-v0``): ``state[k]``.

The entries not named keep the reset's draw. The observation is then recomputed by the env
(its ``_get_obs()`` where it has one, else the state itself); the reset's ``info`` is kept
(a DMControlEnv's ``info["physics"]`` is refreshed).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = ["set_env_state"]

_ENTRY = re.compile(r"^(state|qpos|qvel)\[(\d+)\]$")  # state[k], qpos[k], qvel[k]


def _entries(values: Mapping[str, float], kinds: tuple[str, ...], what: str) -> dict:
    """``{(kind, k): value}`` of entries named ``kind[k]``; ValueError for any other name."""
    out = {}
    for name, v in values.items():
        m = _ENTRY.match(str(name))
        if m is None or m.group(1) not in kinds:
            allowed = " or ".join(f"{k}[index]" for k in kinds)
            raise ValueError(f"task.eval_init.{name}: {what} takes entries named {allowed}")
        out[(m.group(1), int(m.group(2)))] = float(v)
    return out


def set_env_state(
    env: Any, values: Mapping[str, float], obs: np.ndarray, info: dict[str, Any]
) -> tuple[np.ndarray, dict[str, Any]]:
    """Set the named entries ``values`` of ``env``'s state just after ``env.reset`` (which
    returned ``obs``, ``info``); returns the observation and ``info`` of the state set
    (module docstring).

    Raises:
        ValueError: the env keeps no state this module can set, or an entry name or index
            does not exist in it (the message names the ``task.eval_init`` field).
    """
    base = env.unwrapped
    if hasattr(base, "set_physics_state") and hasattr(base, "physics_names"):  # DMControlEnv
        return base.set_physics_state(values)
    if hasattr(base, "set_state") and hasattr(base, "data"):  # Gymnasium MuJoCo
        entries = _entries(values, ("qpos", "qvel"), type(base).__name__)
        qpos, qvel = np.array(base.data.qpos), np.array(base.data.qvel)
        for (kind, k), v in entries.items():
            arr = qpos if kind == "qpos" else qvel
            if k >= arr.size:
                raise ValueError(f"task.eval_init.{kind}[{k}]: {kind} has {arr.size} entries")
            arr[k] = v
        base.set_state(qpos, qvel)
    elif isinstance(getattr(base, "state", None), np.ndarray | tuple | list):  # classic
        entries = _entries(values, ("state",), type(base).__name__)
        state = np.array(base.state, dtype=np.float64)
        for (_, k), v in entries.items():
            if k >= state.size:
                raise ValueError(f"task.eval_init.state[{k}]: the state has {state.size} entries")
            state[k] = v
        base.state = state
    else:
        raise ValueError(
            f"task.eval_init: {type(base).__name__} keeps no state that can be set (a "
            "dm-control env, a Gymnasium MuJoCo env or a classic-control env with a 'state' "
            "array can); remove eval_init to evaluate from the env's own reset"
        )
    get_obs = getattr(base, "_get_obs", None)
    new_obs = get_obs() if callable(get_obs) else np.array(base.state, dtype=np.float64)
    return np.asarray(new_obs).astype(np.asarray(obs).dtype), info
