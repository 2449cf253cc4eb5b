"""Fixtures for offscreen rendering: which headless OpenGL backend works here."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

GL_PROBE = """
import mujoco
m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom size=".1"/></worldbody></mujoco>')
r = mujoco.Renderer(m, 16, 16); r.render(); r.close(); print("GL_OK")
"""


def run_python(code: str, backend: str | None) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter with ``MUJOCO_GL=backend`` (a missing backend can
    abort a process, so rendering checks run outside the test process first)."""
    env = dict(os.environ)
    if backend is not None:
        env["MUJOCO_GL"] = backend
    return subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120
    )


def _last_line(proc: subprocess.CompletedProcess) -> str:
    return (proc.stderr.strip().splitlines() or ["?"])[-1]


@pytest.fixture(scope="session")
def gl_backend() -> str:
    """The first headless backend (``egl``, ``osmesa``) that renders a trivial model; skips
    the test when there is none."""
    errors = []
    for backend in ("egl", "osmesa"):
        proc = run_python(GL_PROBE, backend)
        if "GL_OK" in proc.stdout:
            return backend
        errors.append(f"{backend}: {_last_line(proc)}")
    pytest.skip(
        "no headless OpenGL backend (MUJOCO_GL=egl/osmesa) works here: " + "; ".join(errors)
    )


@pytest.fixture(scope="session")
def gl_in_process() -> None:
    """Skips the test unless this process's own ``MUJOCO_GL`` renders (``make test`` sets
    ``egl``), so that the test may render in-process."""
    proc = run_python(GL_PROBE, None)
    if "GL_OK" not in proc.stdout:
        pytest.skip(
            f"MUJOCO_GL={os.environ.get('MUJOCO_GL')!r} does not render here: {_last_line(proc)}"
        )
