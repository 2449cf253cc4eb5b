"""Shared fixtures: which headless OpenGL backend works here, and running console scripts
as commands."""

from __future__ import annotations

import importlib.metadata
import os
import subprocess
import sys
from collections.abc import Callable, Iterator, Sequence

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


def _command_main(name: str) -> Callable[..., int]:
    """The ``main`` that console script ``name`` (e.g. ``mcpilco-train``) runs, read from the
    installed distribution's entry points, so that tests drive the command a user types and
    never import from ``mcpilco.scripts``."""
    for entry in importlib.metadata.entry_points(group="console_scripts"):
        if entry.name == name and entry.value.startswith("mcpilco."):
            return entry.load()
    raise LookupError(f"no console script {name!r} is installed (pip install -e .)")


def run_command(name: str, argv: Sequence[str]) -> int:
    """Run console script ``name`` in this process with arguments ``argv``; its exit status
    (``SystemExit`` from argparse or the script is caught and its code returned)."""
    try:
        status = _command_main(name)(list(argv))
    except SystemExit as stop:
        status = stop.code if isinstance(stop.code, int) else (0 if stop.code is None else 2)
    return 0 if status is None else int(status)


@pytest.fixture
def command() -> Callable[[str, Sequence[str]], int]:
    """``command(name, argv)``: run a console script in-process, return its exit status."""
    return run_command


@pytest.fixture
def one_torch_thread() -> Iterator[None]:
    """One torch thread for the test (tiny GP fits would only oversubscribe the cores); the
    count before it restored after."""
    import torch

    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


@pytest.fixture(autouse=True, scope="session")
def _signing_key_in_a_temporary_folder(tmp_path_factory) -> Iterator[None]:
    """Signed run files (``mcpilco.models.files.sign_file``) use a key made for the test
    session, never the user's own key in ``~/.config``; subprocesses inherit it."""
    key = tmp_path_factory.mktemp("signing") / "file_key"
    old = os.environ.get("MCPILCO_KEY_FILE")
    os.environ["MCPILCO_KEY_FILE"] = str(key)
    yield
    if old is None:
        os.environ.pop("MCPILCO_KEY_FILE", None)
    else:
        os.environ["MCPILCO_KEY_FILE"] = old
