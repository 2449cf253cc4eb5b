"""The built wheel is the product: it installs into a fresh virtual environment outside the
repository and its commands and package data work there.

The wheel is built with ``python -m build --wheel --no-isolation`` from the checkout. The fresh
venv gets the wheel with ``--no-deps``; its third-party dependencies are borrowed from the test's
own environment through a ``.pth`` line (that directory is added to ``sys.path`` without its own
``.pth`` files being processed, so the editable install of the checkout stays invisible). A check
of the wheel's own metadata then proves that every dependency it declares is satisfied there, and
every command runs from a folder outside the repository.
"""

from __future__ import annotations

import os
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.slow


def _run(cmd: list[str], cwd: Path, timeout: int = 300) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env.setdefault("MUJOCO_GL", "egl")
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, f"{' '.join(cmd)} failed:\n{proc.stdout}\n{proc.stderr}"
    return proc


@pytest.fixture(scope="module")
def wheel_venv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fresh venv outside the checkout with the freshly built wheel installed; its bin dir."""
    pytest.importorskip("build", reason="the `build` package is part of the dev extra")
    work = tmp_path_factory.mktemp("wheel")
    _run([sys.executable, "-m", "build", "--wheel", "--no-isolation", "--outdir", str(work)], ROOT)
    (wheel,) = work.glob("mcpilco-*.whl")
    env_dir = work / "venv"
    venv.create(env_dir, with_pip=False)
    python = env_dir / "bin" / "python"
    site = Path(
        _run(
            [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], work
        ).stdout.strip()
    )
    deps = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (site / "borrowed_dependencies.pth").write_text("\n".join(sorted(deps)) + "\n")
    _run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", str(wheel)],
        work,
    )
    return env_dir / "bin"


CHECK_REQUIREMENTS = """
import importlib.metadata as md
from packaging.requirements import Requirement
dist = md.distribution("mcpilco")
bad = []
for line in dist.requires or []:
    req = Requirement(line)
    if req.marker is not None and not req.marker.evaluate({"extra": ""}):
        continue  # an optional extra
    try:
        version = md.version(req.name)
    except md.PackageNotFoundError:
        bad.append(f"{req}: not installed")
        continue
    if not req.specifier.contains(version, prereleases=True):
        bad.append(f"{req}: {version} installed")
print(dist.locate_file(""), len(dist.requires or []))
assert not bad, bad
"""


def test_wheel_declares_satisfied_dependencies(wheel_venv: Path, tmp_path: Path) -> None:
    """Every dependency the wheel's metadata declares (extras aside) is met in the venv."""
    out = _run([str(wheel_venv / "python"), "-c", CHECK_REQUIREMENTS], tmp_path).stdout
    location, n_requires = out.split()
    assert str(ROOT) not in location and int(n_requires) >= 10


def test_wheel_imports_from_its_own_install(wheel_venv: Path, tmp_path: Path) -> None:
    code = (
        "import gymnasium as gym, mcpilco.envs; "
        "from mcpilco.envs.tasks.spec import TaskSpec; "
        "from mcpilco.agents.mc_pilco.config import load_config; "
        "print(mcpilco.envs.__file__); "
        "env = gym.make('mcpilco/CartpoleSwingUp-v0'); env.reset(seed=0); "
        "print(TaskSpec.for_env('mcpilco/CartpoleSwingUp-v0').state_dim); "
        "print(load_config('mcpilco/CartpoleSwingUp-v0', preset='demo').num_particles)"
    )
    out = _run([str(wheel_venv / "python"), "-c", code], tmp_path).stdout.splitlines()
    assert str(ROOT) not in out[0] and "site-packages" in out[0], out[0]
    assert out[1] == "4"  # the cart-pole's task file (package data) was found and read
    assert int(out[2]) > 0  # the cart-pole's config file (package data) was found and read


def test_wheel_ships_the_native_rollouts_sources(wheel_venv: Path, tmp_path: Path) -> None:
    """The C++ sources the native rollout compiles on first use are package data of the
    installed wheel, beside their module."""
    code = (
        "from mcpilco.agents.mc_pilco.fast import native; "
        "paths = (*native.SOURCES, native.HEADER); "
        "print(native.__file__); print(sum(p.is_file() for p in paths), len(paths))"
    )
    out = _run([str(wheel_venv / "python"), "-c", code], tmp_path).stdout.splitlines()
    assert str(ROOT) not in out[0] and "site-packages" in out[0], out[0]
    assert out[1] == "3 3"


@pytest.mark.parametrize("command", ["mcpilco-train", "mcpilco-diagnose", "mcpilco-compare"])
def test_wheel_commands_run(wheel_venv: Path, tmp_path: Path, command: str) -> None:
    out = _run([str(wheel_venv / command), "--help"], tmp_path).stdout
    assert "usage:" in out
