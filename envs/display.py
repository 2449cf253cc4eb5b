"""Whether ``render_mode="human"`` can work here: a display, and a window GLFW can open.

``"human"`` rendering opens a GLFW window. On a machine without a display that call can
abort the whole Python process, so the envs offer ``"human"`` only where a display is
configured (:func:`render_modes`), and an env asked for ``"human"`` first tries to open a
window in a separate process (:func:`can_open_window`) and raises a ``ValueError`` that says
what to use instead when it cannot (:func:`check_render_mode`).
"""

from __future__ import annotations

import functools
import os
import subprocess
import sys

__all__ = [
    "MUJOCO_OFFSCREEN_MODES",
    "can_open_window",
    "check_render_mode",
    "display_configured",
    "render_modes",
]

MUJOCO_OFFSCREEN_MODES = ("rgb_array", "depth_array")  # modes MuJoCo renders without a window
DISPLAY_VARIABLES = ("DISPLAY", "WAYLAND_DISPLAY")  # environment variables naming a display
WINDOW_PROBE_TIMEOUT_S = 20.0  # seconds the window probe may take before it counts as failed
_PROBE = (
    "import sys, glfw\n"
    "ok = glfw.init()\n"
    "if ok:\n"
    "    glfw.window_hint(glfw.VISIBLE, 0)\n"
    "    w = glfw.create_window(16, 16, 'probe', None, None)\n"
    "    ok = bool(w)\n"
    "    glfw.terminate()\n"
    "sys.exit(0 if ok else 1)\n"
)  # a child process that opens (and closes) an invisible GLFW window


def display_configured() -> bool:
    """Whether ``DISPLAY`` or ``WAYLAND_DISPLAY`` names a display."""
    return any(os.environ.get(v) for v in DISPLAY_VARIABLES)


@functools.cache
def _probe_window(display: tuple[str, ...]) -> bool:
    """Open a GLFW window in a child process (an abort there cannot stop this process)."""
    try:
        done = subprocess.run(
            [sys.executable, "-c", _PROBE],
            capture_output=True,
            timeout=WINDOW_PROBE_TIMEOUT_S,
            check=False,
        )
    except (OSError, subprocess.TimeoutExpired):
        return False
    return done.returncode == 0


def can_open_window() -> bool:
    """Whether a GLFW window opens on the configured display (probed once per display)."""
    if not display_configured():
        return False
    return _probe_window(tuple(os.environ.get(v, "") for v in DISPLAY_VARIABLES))


def render_modes(*offscreen: str) -> list[str]:
    """The render modes an env offers: ``"human"`` (where a display is configured), then
    the ``offscreen`` modes."""
    return (["human"] if display_configured() else []) + list(offscreen)


def check_render_mode(render_mode: str | None, offscreen: tuple[str, ...]) -> None:
    """Raise ``ValueError`` for a ``render_mode`` the env cannot honour here.

    Args:
        render_mode: what the user asked for (None: no rendering).
        offscreen: the env's offscreen modes (``"rgb_array"``, ...), always available.
    """
    if render_mode is None or render_mode in offscreen:
        return
    if render_mode != "human":
        raise ValueError(
            f"render_mode must be one of {['human', *offscreen]} or None, got {render_mode!r}"
        )
    if not can_open_window():
        why = (
            "no display is configured (DISPLAY and WAYLAND_DISPLAY are unset)"
            if not display_configured()
            else "GLFW cannot open a window on the configured display"
        )
        raise ValueError(
            f"render_mode='human' needs a window, but {why}; use render_mode="
            f"{offscreen[0]!r} (images returned by render()) or run on a machine with a display"
        )
