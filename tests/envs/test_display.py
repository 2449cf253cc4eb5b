"""Headless rendering: "human" is not offered without a display and is a clear error, and
gymnasium's check_env with its render check completes (no abort of the process)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from mcpilco.envs import display

# a child process: check_env with the default render check on the cart-pole, headless
_CHECK_ENV = (
    "import gymnasium as gym, mcpilco.envs\n"
    "from gymnasium.utils.env_checker import check_env\n"
    "env = gym.make('mcpilco/CartpoleSwingUp-v0')\n"
    "check_env(env.unwrapped)\n"
    "print('ok', env.unwrapped.metadata['render_modes'])\n"
)


@pytest.fixture
def headless(monkeypatch):
    for var in display.DISPLAY_VARIABLES:
        monkeypatch.delenv(var, raising=False)


def test_human_is_not_offered_and_is_a_clear_error_headless(headless):
    from mcpilco.envs.arm_env import SCARAEnv
    from mcpilco.envs.cartpole import CartpoleSwingUpEnv

    assert display.render_modes("rgb_array") == ["rgb_array"]
    with pytest.raises(ValueError, match="render_mode='human' needs a window.*rgb_array"):
        CartpoleSwingUpEnv(render_mode="human")
    with pytest.raises(ValueError, match="DISPLAY and WAYLAND_DISPLAY are unset"):
        SCARAEnv(render_mode="human")
    with pytest.raises(ValueError, match="render_mode must be one of"):
        CartpoleSwingUpEnv(render_mode="vr")


def test_a_display_that_cannot_open_a_window_is_a_clear_error(monkeypatch):
    monkeypatch.setenv("DISPLAY", ":12345")  # no X server there
    display._probe_window.cache_clear()
    assert display.render_modes("rgb_array") == ["human", "rgb_array"]
    with pytest.raises(ValueError, match="GLFW cannot open a window"):
        display.check_render_mode("human", ("rgb_array",))


def test_check_env_with_render_check_completes_headless():
    env = {k: v for k, v in __import__("os").environ.items() if k not in display.DISPLAY_VARIABLES}
    env["MUJOCO_GL"] = "egl"
    done = subprocess.run(
        [sys.executable, "-c", _CHECK_ENV], capture_output=True, text=True, env=env, timeout=300
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "ok ['rgb_array', 'depth_array']" in done.stdout
