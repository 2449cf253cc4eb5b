"""Hostile inputs of every entry point, by threat class, and how the package answers them.

Each :class:`HostileCase` builds crafted files or arguments for one console script
(``mcpilco-train``, ``mcpilco-diagnose``, ``mcpilco-detect-collisions``,
``mcpilco-bench-collision``, ``mcpilco-compare``) and says which words the refusal must name
(the field, the file, the flag). :func:`run_case` runs the command in this process, next to
a folder ``outside/`` that holds a file the input tries to reach (``victim.txt``), and
classifies the answer into one of :data:`OUTCOMES`:

``refused``
    exit status 2, the last line of stderr an ``error:`` line holding every expected word,
    no traceback, and nothing under ``outside/`` changed (the wanted answer);
``hole``
    a file under ``outside/`` appeared, changed or vanished (code ran, or a write or delete
    left the run folder), whatever the exit status;
``hang``
    still running after the case's time limit (``SIGALRM`` stops it);
``traceback``
    an exception escaped the command, or an exit status other than 0 and 2;
``silent wrong answer``
    exit status 0 on an input that cannot support an answer;
``unclear error``
    exit status 2 with a line that misses an expected word (or shows a traceback).

The threat classes (:data:`THREATS`) are what an input tries; the cases are generated over
them from tables (YAML forms, number fields with values out of range, crafted checkpoints,
detector files, robot files with includes, logs, run folders with links and manifests).
``tests/test_hostile_inputs.py`` runs every case and asserts ``refused``;
``mcpilco.scripts.bench_robustness`` counts the outcomes per class.
"""

from __future__ import annotations

import contextlib
import copy
import importlib.metadata
import io
import json
import os
import pathlib
import signal
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "OUTCOMES",
    "THREATS",
    "HostileCase",
    "hostile_cases",
    "run_case",
]

THREATS: dict[str, str] = {
    "code execution": "a file or value that would run code when it is read",
    "writes outside the folder": "a link, manifest or include that reaches a file elsewhere",
    "hang": "input that makes a naive reader block or expand without end",
    "traceback": "input that a naive reader fails on with an exception",
    "silent wrong answer": "input that a naive reader accepts and computes a wrong answer from",
    "unclear error": "input whose refusal must name the field, file or flag to fix",
}
"""Threat classes of the hostile inputs: what each input tries."""
OUTCOMES = ("refused", "hole", "hang", "traceback", "silent wrong answer", "unclear error")
"""How the package answered a hostile input (module docstring); ``refused`` is wanted."""
CASE_LIMIT_S = 60.0  # seconds a case may run before it counts as a hang
ROOT = Path(__file__).resolve().parents[2]  # the package's source tree (named <package>)
EXAMPLE = ROOT / "models/diagnosis/examples/scara_coulomb2"
VICTIM_TEXT = "precious data of someone else\n"  # content of outside/victim.txt
ENV = "mcpilco/CartpoleSwingUp-v0"  # env of the training cases
SMALL_RUN = [
    "--trials",
    "1",
    "--particles",
    "10",
    "--max-points",
    "30",
    "--opt-steps",
    "2",
    "--threads",
    "1",
    "--no-progress",
    "--no-rrd",
]  # a small mcpilco-train run


@dataclass(frozen=True)
class HostileCase:
    """One hostile input: ``build(work, outside)`` writes its files under ``work`` (and may
    point them at ``outside``) and returns the command's arguments.

    Attributes:
        threat: its class (:data:`THREATS`).
        entry: the console script run.
        name: what the input is.
        build: the function that makes the input.
        expect: words the refusal line must hold (case-insensitive).
        slow: the command builds an env, a model or a run before refusing (seconds).
    """

    threat: str
    entry: str
    name: str
    build: Callable[[Path, Path], list[str]]
    expect: tuple[str, ...] = ()
    slow: bool = False

    @property
    def id(self) -> str:
        return f"{self.entry}: {self.name}"


# ------------------------------------------------------------------------ payloads
class _Payload:
    """Unpickling it would create ``marker`` (code run from a data file)."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple:
        return (pathlib.Path.touch, (pathlib.Path(self.marker),))


def _torch_save(obj: Any, path: Path) -> None:
    import torch

    torch.save(obj, path)


def _yaml_bomb(levels: int = 9, width: int = 9) -> str:
    """A flow-style alias bomb: ``width^levels`` strings once expanded."""
    lines = ["a0: &a0 [" + ", ".join(["lol"] * width) + "]"]
    for k in range(1, levels):
        lines.append(f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * width) + "]")
    return "\n".join(lines) + "\n"


def _inline_bomb(levels: int = 9, width: int = 9) -> str:
    """The alias bomb as one flow mapping (a ``--set`` value)."""
    parts = ["a0: &a0 [" + ", ".join(["lol"] * width) + "]"]
    for k in range(1, levels):
        parts.append(f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * width) + "]")
    return "{" + ", ".join(parts) + "}"


def _task() -> dict[str, Any]:
    from mcpilco.envs.tasks import task_data

    return copy.deepcopy(task_data(ENV))


def _write_task(path: Path, data: Any) -> Path:
    import yaml

    path.write_text(yaml.safe_dump(data) if not isinstance(data, str) else data)
    return path


def _set_path(data: dict[str, Any], dotted: str, value: Any) -> dict[str, Any]:
    node: Any = data
    *parents, leaf = dotted.split(".")
    for p in parents:
        node = node[int(p)] if isinstance(node, list) else node[p]
    if isinstance(node, list):
        node[int(leaf)] = value
    else:
        node[leaf] = value
    return data


# ------------------------------------------------------------------------ mcpilco-train
def _train(*argv: str) -> Callable[[Path, Path], list[str]]:
    # the case's arguments last: they win over the small run's
    return lambda work, outside: [*SMALL_RUN, "--env", ENV, "--out", str(work / "run"), *argv]


def _yaml_cases() -> list[HostileCase]:
    """YAML in ``--set`` values, task files and the comparison's overrides."""
    deep = "[" * 5000 + "]" * 5000
    tag = "!!python/object/apply:os.system ['touch {marker}']"
    cases = []
    for value, threat, name, expect in (
        (_inline_bomb(), "hang", "alias bomb", ("--set cost_length_scales", "aliases")),
        ("&a [*a, *a]", "hang", "recursive alias", ("--set cost_length_scales", "recursive")),
        (deep, "traceback", "5000 nested lists", ("--set cost_length_scales", "deeper")),
        ("1" * 5000, "traceback", "an integer of 5000 digits", ("--set cost_length_scales",)),
        ("\x00", "traceback", "a NUL character", ("--set cost_length_scales", "not allowed")),
        (
            "{a: 1, a: 2}",
            "silent wrong answer",
            "a key given twice",
            ("--set cost_length_scales", "twice"),
        ),
        (
            "{max_steps: 3",
            "unclear error",
            "unclosed mapping",
            ("--set cost_length_scales", "line 1"),
        ),
    ):
        cases.append(
            HostileCase(
                threat,
                "mcpilco-train",
                f"--set {name}",
                _train("--set", f"cost_length_scales={value}"),
                expect,
            )
        )
    cases.append(
        HostileCase(
            "code execution",
            "mcpilco-train",
            "--set with a Python tag",
            lambda w, o: _train("--set", "seed=" + tag.format(marker=o / "pwned"))(w, o),
            ("--set seed", "tag"),
        )
    )
    for flag in ("--mcpilco-set", "--pilco-set"):
        for value, threat, name, expect in (
            (_inline_bomb(), "hang", "alias bomb", (flag, "aliases")),
            (deep, "traceback", "5000 nested lists", (flag, "deeper")),
        ):
            cases.append(
                HostileCase(
                    threat,
                    "mcpilco-compare",
                    f"{flag} {name}",
                    lambda w, o, f=flag, v=value: [
                        f,
                        f"x={v}",
                        "--runs-dir",
                        str(w / "runs"),
                        "--out",
                        str(w / "out"),
                        "--collect-only",
                    ],
                    expect,
                )
            )
    cases.append(
        HostileCase(
            "traceback",
            "mcpilco-compare",
            "--sb3-hp 5000 nested lists",
            lambda w, o: [
                "--sb3-hp",
                f"sac.net_arch={deep}",
                "--runs-dir",
                str(w / "runs"),
                "--out",
                str(w / "out"),
                "--collect-only",
            ],
            ("--sb3-hp sac.net_arch", "deeper"),
        )
    )
    cases.append(
        HostileCase(
            "traceback",
            "mcpilco-compare",
            "--inputs JSON nested 100000 levels",
            lambda w, o: (
                w.joinpath("c.json").write_text("[" * 100000 + "]" * 100000),
                [
                    "--inputs",
                    str(w / "c.json"),
                    "--runs-dir",
                    str(w / "runs"),
                    "--out",
                    str(w / "out"),
                    "--collect-only",
                ],
            )[1],
            ("c.json",),
        )
    )
    files: list[tuple[str, str, Callable[[Path, Path], str], tuple[str, ...]]] = [
        ("hang", "alias bomb", lambda w, o: _yaml_bomb(), ("aliases",)),
        (
            "traceback",
            "5000 nested mappings",
            lambda w, o: "a: " + "{b: " * 5000 + "1" + "}" * 5000,
            ("deeper",),
        ),
        (
            "code execution",
            "a Python tag",
            lambda w, o: "env_id: " + tag.format(marker=o / "pwned"),
            ("tag",),
        ),
        (
            "code execution",
            "a Python name tag",
            lambda w, o: "env_id: !!python/name:os.system",
            ("tag",),
        ),
        ("silent wrong answer", "an empty file", lambda w, o: "", ("empty",)),
        ("silent wrong answer", "only a comment", lambda w, o: "# nothing\n", ("empty",)),
        ("unclear error", "a list, not a mapping", lambda w, o: "- 1\n- 2\n", ("mapping",)),
        ("hang", "2 MB of YAML", lambda w, o: "x: " + "a" * (2 << 20), ("larger than",)),
        ("traceback", "bytes that are not UTF-8", lambda w, o: "\udcff", ("utf-8",)),
    ]
    for threat, name, text, expect in files:

        def build(w: Path, o: Path, text: Callable = text) -> list[str]:
            body = text(w, o)
            path = w / "task.yaml"
            if body == "\udcff":
                path.write_bytes(b"env_id: \xff\xfe\n")
            else:
                path.write_text(body)
            return _train("--task", str(path))(w, o)

        cases.append(
            HostileCase(
                threat, "mcpilco-train", f"task file: {name}", build, ("task.yaml", *expect)
            )
        )

    def fifo(w: Path, o: Path) -> list[str]:
        os.mkfifo(w / "task.yaml")
        return _train("--task", str(w / "task.yaml"))(w, o)

    cases.append(
        HostileCase(
            "hang", "mcpilco-train", "task file: a FIFO", fifo, ("task.yaml", "not a regular file")
        )
    )
    cases.append(
        HostileCase(
            "hang",
            "mcpilco-train",
            "task file: /dev/zero",
            _train("--task", "/dev/zero"),
            ("/dev/zero", "not a regular file"),
        )
    )
    cases.append(
        HostileCase(
            "unclear error",
            "mcpilco-train",
            "task file: a folder",
            lambda w, o: _train("--task", str(w))(w, o),
            ("folder",),
        )
    )
    return cases


# task fields: (dotted path in the shipped task, value, threat)
TASK_FIELDS: list[tuple[str, Any, str]] = [
    ("dt", 1.0e308, "silent wrong answer"),
    ("dt", float("nan"), "silent wrong answer"),
    ("dt", float("inf"), "silent wrong answer"),
    ("dt", -0.05, "silent wrong answer"),
    ("dt", "fast", "unclear error"),
    ("dt", True, "silent wrong answer"),
    ("horizon", 10**12, "traceback"),
    ("horizon", 1.5, "unclear error"),
    ("horizon", -3, "unclear error"),
    ("action_low.0", float("-inf"), "silent wrong answer"),
    ("action_high.0", 1e300, "silent wrong answer"),
    ("init_std", -1.0, "silent wrong answer"),
    ("init_std", float("nan"), "silent wrong answer"),
    ("init_mean.0", float("nan"), "silent wrong answer"),
    ("cost.terms.0.length_scale", 1e-320, "silent wrong answer"),
    ("cost.terms.0.length_scale", float("inf"), "silent wrong answer"),
    ("cost.terms.0.length_scale", 0, "silent wrong answer"),
    ("cost.terms.0.target", True, "silent wrong answer"),
    ("cost.terms.0.target", float("nan"), "silent wrong answer"),
    ("success.window", 10**15, "traceback"),
    ("action_repeat", 10**9, "traceback"),
]


def _field_name(dotted: str) -> str:
    """``cost.terms.0.length_scale`` -> ``cost.terms[0].length_scale`` (as messages name it)."""
    out = ""
    for part in dotted.split("."):
        out += f"[{part}]" if part.isdigit() else (f".{part}" if out else part)
    return out


def _task_number_cases() -> list[HostileCase]:
    cases = []
    for dotted, value, threat in TASK_FIELDS:

        def build(w: Path, o: Path, dotted: str = dotted, value: Any = value) -> list[str]:
            data = _set_path(_task(), dotted, value)
            return _train("--task", str(_write_task(w / "task.yaml", data)))(w, o)

        field = "task." + _field_name(dotted)
        cases.append(
            HostileCase(threat, "mcpilco-train", f"task {field} = {value!r}", build, (field,))
        )
    for text, field in (
        ("success: {window: 10, bounds: {x: {tol: 0}}}", "success.bounds.x.tol"),
        ("success: {tracking_rms: {x: .nan}}", "success.tracking_rms.x"),
        ("limits: {x: [.nan, 1]}", "limits.x"),
    ):

        def build(w: Path, o: Path, text: str = text) -> list[str]:
            import yaml

            base = yaml.safe_dump(
                {k: v for k, v in _task().items() if k not in ("success", "limits")}
            )
            return _train("--task", str(_write_task(w / "task.yaml", base + text + "\n")))(w, o)

        cases.append(
            HostileCase(
                "silent wrong answer", "mcpilco-train", f"task {text}", build, (f"task.{field}",)
            )
        )
    return cases


# --set values: (item, expected field, threat)
SET_VALUES: list[tuple[str, str, str]] = [
    ("num_particles=1e9", "num_particles", "traceback"),
    ("num_particles=-1", "num_particles", "unclear error"),
    ("num_particles=1.5", "num_particles", "silent wrong answer"),
    ("num_particles=true", "num_particles", "silent wrong answer"),
    ("num_particles=many", "num_particles", "unclear error"),
    ("gp_noise_min=.nan", "gp_noise_min", "silent wrong answer"),
    ("gp_noise_min=-1e-4", "gp_noise_min", "silent wrong answer"),
    ("gp_noise_min=[1]", "gp_noise_min", "unclear error"),
    ("gp_min_lengthscale=1e-320", "gp_min_lengthscale", "silent wrong answer"),
    ("seed=true", "seed", "silent wrong answer"),
    ("seed=-1", "seed", "unclear error"),
    ("seed=1e30", "seed", "traceback"),
    ("horizon=0", "horizon", "unclear error"),
    ("horizon=1e12", "horizon", "traceback"),
    ("num_trials=1e7", "num_trials", "hang"),
    ("max_points=5", "max_points", "unclear error"),
    ("max_points=1e9", "max_points", "traceback"),
    ("num_basis=1e9", "num_basis", "traceback"),
    ("num_candidates=1e6", "num_candidates", "traceback"),
    ("torch_threads=0", "torch_threads", "traceback"),
    ("policy_weight_scale=.inf", "policy_weight_scale", "silent wrong answer"),
    ("sim_obs_noise_std=-1", "sim_obs_noise_std", "silent wrong answer"),
    ("init_std=.nan", "init_std", "silent wrong answer"),
    ("log_particles=-5", "log_particles", "traceback"),
    ("opt.lr=.inf", "opt.lr", "silent wrong answer"),
    ("opt.lr=0", "opt.lr", "silent wrong answer"),
    ("opt.max_steps=1e12", "opt.max_steps", "hang"),
    ("opt.dropout=1", "opt.dropout", "silent wrong answer"),
    ("opt.unknown=1", "opt", "traceback"),
    ("opt.cuda_graph=2", "opt.cuda_graph", "silent wrong answer"),
    ("cost_length_scales={x: 1e-320, theta: 1}", "cost_length_scales.x", "silent wrong answer"),
    ("cost_length_scales={x: .nan, theta: 1}", "cost_length_scales.x", "silent wrong answer"),
    ("cost_limit_widths={x: .inf}", "cost_limit_widths.x", "silent wrong answer"),
    ("compile_rollout=1", "compile_rollout", "silent wrong answer"),
    ("env_kwargs=[1, 2]", "env_kwargs", "traceback"),
    ("particles=400", "particles", "unclear error"),
    ("num_particles", "--set", "unclear error"),
    ("opt.max_steps=1", "opt", "unclear error"),  # given twice below
]


def _set_cases() -> list[HostileCase]:
    cases = []
    for item, field, threat in SET_VALUES:
        extra = ["--set", "opt=3"] if item == "opt.max_steps=1" else []
        cases.append(
            HostileCase(
                threat, "mcpilco-train", f"--set {item}", _train("--set", item, *extra), (field,)
            )
        )
    return cases


def _train_flag_cases() -> list[HostileCase]:
    cases = []
    for argv, flag, threat in (
        (["--particles", "1000000000"], "num_particles", "traceback"),
        (["--particles", "1e9"], "--particles", "unclear error"),
        (["--particles", "nan"], "--particles", "unclear error"),
        (["--trials", "-2"], "--trials", "unclear error"),
        (["--seed", "-1"], "--seed", "unclear error"),
        (["--threads", "0"], "--threads", "unclear error"),
        (["--horizon", "100000000000"], "horizon", "traceback"),
        (["--max-points", "3"], "max_points", "unclear error"),
        (["--env", "NoSuchEnv-v0"], "NoSuchEnv-v0", "unclear error"),
        (["--resume", "--overwrite"], "--resume", "unclear error"),
    ):
        cases.append(HostileCase(threat, "mcpilco-train", " ".join(argv), _train(*argv), (flag,)))
    cases.append(
        HostileCase(
            "traceback",
            "mcpilco-train",
            "render_mode human without a display",
            _train("--set", "env_kwargs={render_mode: human}"),
            ("render_mode",),
            slow=False,
        )
    )
    return cases


# ------------------------------------------------------------------------ run folders
def _manifest(work: Path, files: list[Any]) -> None:
    run = work / "run"
    run.mkdir(exist_ok=True)
    (run / "manifest.json").write_text(
        json.dumps({"format": "mcpilco.run_folder/1", "files": files})
    )
    (run / "checkpoint.pt").write_bytes(b"x")


def _run_folder_cases() -> list[HostileCase]:
    cases = []

    def link(name: str, *flags: str) -> Callable[[Path, Path], list[str]]:
        def build(w: Path, o: Path) -> list[str]:
            (w / "run").mkdir()
            (w / "run" / name).symlink_to(o / "victim.txt")
            return _train(*flags)(w, o)

        return build

    for name, flags in (
        ("run.lock", ()),
        ("run.lock", ("--resume",)),
        ("checkpoint.pt", ("--resume",)),
        ("checkpoint.pt.tmp", ("--overwrite",)),
        ("records.json.tmp", ("--overwrite",)),
        ("manifest.json", ("--overwrite",)),
        ("gp_trial01.pt", ("--overwrite",)),
    ):
        cases.append(
            HostileCase(
                "writes outside the folder",
                "mcpilco-train",
                f"run folder: {name} a link to another file {' '.join(flags)}",
                link(name, *flags),
                (name, "symbolic link"),
            )
        )
    for entry, label in (
        ("../outside/victim.txt", "a relative path out of the folder"),
        ("ABSOLUTE", "an absolute path"),
        ("sub/../../outside/victim.txt", "a path through a subfolder"),
        ("..", "the parent folder"),
        (17, "a number"),
    ):

        def build(w: Path, o: Path, entry: Any = entry) -> list[str]:
            _manifest(w, [str(o / "victim.txt") if entry == "ABSOLUTE" else entry])
            return _train("--overwrite")(w, o)

        cases.append(
            HostileCase(
                "writes outside the folder",
                "mcpilco-train",
                f"manifest lists {label}, --overwrite",
                build,
                ("manifest.json",),
            )
        )

    def deep_manifest(w: Path, o: Path) -> list[str]:
        (w / "run").mkdir()
        (w / "run" / "manifest.json").write_text("[" * 100000 + "]" * 100000)
        return _train()(w, o)

    cases.append(
        HostileCase(
            "traceback", "mcpilco-train", "manifest nested 100000 levels", deep_manifest, ("run",)
        )
    )

    def fifo_lock(w: Path, o: Path) -> list[str]:
        (w / "run").mkdir()
        os.mkfifo(w / "run" / "run.lock")
        return _train()(w, o)

    cases.append(
        HostileCase(
            "hang",
            "mcpilco-train",
            "run.lock is a FIFO",
            fifo_lock,
            ("run.lock", "not a regular file"),
        )
    )
    return cases


# ------------------------------------------------------------------------ checkpoints
def _checkpoint(work: Path) -> dict[str, Any]:
    """A checkpoint of the small run's config whose trial 0 finished (no GP yet)."""
    import torch

    from mcpilco.agents.common.checkpoint import CHECKPOINT_VERSION, rng_state
    from mcpilco.agents.mc_pilco.cli import config_from_options

    config = config_from_options(
        ENV, num_trials=1, num_particles=10, max_points=30, opt_steps=2, torch_threads=1
    )
    rng = np.random.default_rng(0)
    return {
        "version": CHECKPOINT_VERSION,
        "config": config.to_dict(),
        "next_trial": 1,
        "episodes": [{"obs": np.zeros((11, 5)), "actions": np.zeros((10, 1))}],
        "records": [{"index": 0, "kind": "exploration"}],
        "arrays": [{"index": 0}],
        "policy": {"w": torch.zeros(3)},
        "policy_settings": {},
        "population": {},
        "optimizer": None,
        "gp_file": None,
        "rng": rng_state(rng),
    }


CHECKPOINT_EDITS: list[tuple[str, Callable[[dict[str, Any], Path], Any], str, str]] = [
    (
        "next_trial 10**6",
        lambda c, o: c.update(next_trial=10**6),
        "next_trial",
        "silent wrong answer",
    ),
    ("next_trial 0", lambda c, o: c.update(next_trial=0), "next_trial", "traceback"),
    ("next_trial a string", lambda c, o: c.update(next_trial="1"), "next_trial", "traceback"),
    (
        "records for 3 trials",
        lambda c, o: c.update(records=[{"index": i} for i in range(3)]),
        "records",
        "silent wrong answer",
    ),
    ("records not mappings", lambda c, o: c.update(records=[1]), "records", "traceback"),
    (
        "episodes hold NaN",
        lambda c, o: c["episodes"][0]["obs"].__setitem__((0, 0), np.nan),
        "episodes",
        "silent wrong answer",
    ),
    ("episodes a number", lambda c, o: c.update(episodes=3), "episodes", "traceback"),
    (
        "gp_file outside the folder",
        lambda c, o: c.update(gp_file="../outside/victim.pt"),
        "gp_file",
        "writes outside the folder",
    ),
    (
        "gp_file an absolute path",
        lambda c, o: c.update(gp_file=str(o / "victim.txt")),
        "gp_file",
        "writes outside the folder",
    ),
    ("rng states of floats", lambda c, o: c["rng"].update(torch=np.zeros(3)), "rng", "traceback"),
    ("rng missing", lambda c, o: c.pop("rng"), "rng", "traceback"),
    ("config not a mapping", lambda c, o: c.update(config=[1]), "config", "traceback"),
    (
        "config without num_trials",
        lambda c, o: c["config"].pop("num_trials"),
        "num_trials",
        "traceback",
    ),
    ("version a string", lambda c, o: c.update(version="3"), "version", "traceback"),
    ("policy of other shapes", lambda c, o: None, "policy", "traceback"),
    ("policy not tensors", lambda c, o: c.update(policy={"w": [1, 2]}), "policy", "traceback"),
    ("optimizer a list", lambda c, o: c.update(optimizer=[1]), "optimizer", "traceback"),
    ("a list, not a mapping", lambda c, o: None, "checkpoint", "traceback"),
]


def _checkpoint_cases() -> list[HostileCase]:
    cases = []
    for name, edit, expect, threat in CHECKPOINT_EDITS:

        def build(w: Path, o: Path, name: str = name, edit: Callable = edit) -> list[str]:
            from mcpilco.models.torch_files import atomic_torch_save

            run = w / "run"
            run.mkdir()
            ckpt = _checkpoint(w)
            edit(ckpt, o)
            if name == "a list, not a mapping":
                ckpt = [ckpt]
            atomic_torch_save(ckpt, run / "checkpoint.pt")
            return _train("--resume")(w, o)

        cases.append(
            HostileCase(
                threat,
                "mcpilco-train",
                f"checkpoint: {name}",
                build,
                ("checkpoint.pt", expect),
                slow=False,
            )
        )

    def code(w: Path, o: Path) -> list[str]:
        (w / "run").mkdir()
        _torch_save({"version": 3, "x": _Payload(o / "pwned")}, w / "run" / "checkpoint.pt")
        return _train("--resume")(w, o)

    def pickle_file(w: Path, o: Path) -> list[str]:
        import pickle

        (w / "run").mkdir()
        (w / "run" / "checkpoint.pt").write_bytes(pickle.dumps(_Payload(o / "pwned")))
        return _train("--resume")(w, o)

    cases.append(
        HostileCase(
            "code execution",
            "mcpilco-train",
            "checkpoint: torch file with code",
            code,
            ("checkpoint.pt", "could run code"),
            slow=False,
        )
    )
    cases.append(
        HostileCase(
            "code execution",
            "mcpilco-train",
            "checkpoint: a plain pickle",
            pickle_file,
            ("checkpoint.pt",),
            slow=False,
        )
    )
    return cases


# ------------------------------------------------------------------------ detector files
def _detector_payload() -> dict[str, Any]:
    import torch

    return {
        "format": "mcpilco.collision.CollisionDetector/1",
        "rule": "max",
        "false_alarm_rate": 0.0,
        "persistence": 1,
        "sample_time": 0.008,
        "scale": torch.ones(6, dtype=torch.float64),
        "estimator": torch.zeros(10, dtype=torch.uint8),
    }


DETECTOR_EDITS: list[tuple[str, Callable[[dict[str, Any]], Any], str, str]] = [
    ("a list", lambda d: None, "format", "traceback"),
    ("another format tag", lambda d: d.update(format="x"), "collision-detector", "traceback"),
    ("rule unknown", lambda d: d.update(rule="min"), "rule", "traceback"),
    (
        "false_alarm_rate nan",
        lambda d: d.update(false_alarm_rate=float("nan")),
        "false_alarm_rate",
        "silent wrong answer",
    ),
    ("persistence 0", lambda d: d.update(persistence=0), "persistence", "silent wrong answer"),
    ("persistence a string", lambda d: d.update(persistence="2"), "persistence", "traceback"),
    ("sample_time -1", lambda d: d.update(sample_time=-1.0), "sample_time", "silent wrong answer"),
    ("scale NaN", lambda d: d["scale"].fill_(float("nan")), "scale", "silent wrong answer"),
    ("scale 2-D", lambda d: d.update(scale=d["scale"].reshape(2, 3)), "scale", "traceback"),
    ("estimator not bytes", lambda d: d.update(estimator=d["scale"]), "estimator", "traceback"),
    ("estimator garbage bytes", lambda d: None, "estimator", "traceback"),
]


def _detector_cases() -> list[HostileCase]:
    cases = []
    for name, edit, expect, threat in DETECTOR_EDITS:

        def build(w: Path, o: Path, name: str = name, edit: Callable = edit) -> list[str]:
            d = _detector_payload()
            edit(d)
            _torch_save([d] if name == "a list" else d, w / "det.pt")
            return [str(w / "log.csv"), "--detector", str(w / "det.pt")]

        cases.append(
            HostileCase(
                threat, "mcpilco-detect-collisions", f"detector: {name}", build, ("det.pt", expect)
            )
        )
    for name, content, expect in (
        ("empty file", b"", "empty"),
        ("garbage bytes", b"\x89garbage" * 10, "damaged"),
    ):

        def build(w: Path, o: Path, content: bytes = content) -> list[str]:
            (w / "det.pt").write_bytes(content)
            return [str(w / "log.csv"), "--detector", str(w / "det.pt")]

        cases.append(
            HostileCase(
                "traceback",
                "mcpilco-detect-collisions",
                f"detector: {name}",
                build,
                ("det.pt", expect),
            )
        )

    def code(w: Path, o: Path) -> list[str]:
        _torch_save({"format": "x", "e": _Payload(o / "pwned")}, w / "det.pt")
        return [str(w / "log.csv"), "--detector", str(w / "det.pt")]

    cases.append(
        HostileCase(
            "code execution",
            "mcpilco-detect-collisions",
            "detector: torch file with code",
            code,
            ("det.pt", "run code"),
        )
    )

    def estimator(edit: Callable[[dict[str, Any], Path], None]) -> Callable:
        def build(w: Path, o: Path) -> list[str]:
            import torch

            est = {
                "format": "mcpilco.collision.CurrentEstimator/1",
                "name": "PP",
                "model_text": (EXAMPLE / "robot.xml").read_text(),
                "config": {},
                "inputs": {g: torch.zeros(20, 4, dtype=torch.float64) for g in ("q", "qd", "qdd")},
                "targets": torch.zeros(20, 4, dtype=torch.float64),
                "state_dict": {},
            }
            edit(est, o)
            buf = io.BytesIO()
            torch.save(est, buf)
            d = _detector_payload()
            d["estimator"] = torch.frombuffer(bytearray(buf.getvalue()), dtype=torch.uint8)
            _torch_save(d, w / "det.pt")
            return [str(w / "log.csv"), "--detector", str(w / "det.pt")]

        return build

    for name, edit, expect, threat in (
        (
            "estimator with an include of another file",
            lambda e, o: e.update(
                model_text=e["model_text"].replace(
                    "<worldbody>", f'<include file="{o / "victim.txt"}"/><worldbody>'
                )
            ),
            "include",
            "writes outside the folder",
        ),
        (
            "estimator inputs with NaN",
            lambda e, o: e["targets"].fill_(float("nan")),
            "NaN",
            "silent wrong answer",
        ),
        (
            "estimator of unknown name",
            lambda e, o: e.update(name="XX"),
            "estimator name",
            "traceback",
        ),
        (
            "estimator config with other keys",
            lambda e, o: e.update(config={"evil": 1}),
            "config",
            "traceback",
        ),
        (
            "estimator inputs of other shapes",
            lambda e, o: e.update(targets=e["targets"][:3]),
            "shape",
            "traceback",
        ),
    ):
        cases.append(
            HostileCase(
                threat,
                "mcpilco-detect-collisions",
                f"detector: {name}",
                estimator(edit),
                ("det.pt", expect),
                slow=True,
            )
        )
    return cases


# ------------------------------------------------------------------------ diagnosis
def _diagnose(model: str | Path, train: str | Path, *extra: str) -> list[str]:
    return [
        "--model",
        str(model),
        "--train",
        str(train),
        "--test",
        str(EXAMPLE / "test_1.parquet"),
        "--no-plots",
        "--no-rerun",
        *extra,
    ]


def _robot_cases() -> list[HostileCase]:
    source = (EXAMPLE / "robot.xml").read_text()
    cases = []

    def model_with(include: Callable[[Path, Path], str], *extra: str) -> Callable:
        def build(w: Path, o: Path) -> list[str]:
            (w / "robot").mkdir()
            text = source.replace("<worldbody>", include(w, o) + "<worldbody>", 1)
            (w / "robot" / "robot.xml").write_text(text)
            return _diagnose(
                w / "robot" / "robot.xml",
                EXAMPLE / "train_1.parquet",
                *extra,
                "--out",
                str(w / "out"),
            )

        return build

    def linked(w: Path, o: Path) -> str:
        (w / "robot" / "inc.xml").symlink_to(o / "victim.txt")
        return '<include file="inc.xml"/>'

    def cycle(w: Path, o: Path) -> str:
        (w / "robot" / "inc.xml").write_text('<mujoco><include file="inc.xml"/></mujoco>')
        return '<include file="inc.xml"/>'

    def not_mujoco(w: Path, o: Path) -> str:
        (w / "robot" / "inc.xml").write_text("<robot/>")
        return '<include file="inc.xml"/>'

    for name, include, expect, threat in (
        (
            "include of an absolute path",
            lambda w, o: f'<include file="{o / "victim.txt"}"/>',
            "outside",
            "writes outside the folder",
        ),
        (
            "include of ../",
            lambda w, o: '<include file="../../outside/victim.txt"/>',
            "outside",
            "writes outside the folder",
        ),
        (
            "include of /etc/passwd",
            lambda w, o: '<include file="/etc/passwd"/>',
            "outside",
            "writes outside the folder",
        ),
        ("include through a link", linked, "outside", "writes outside the folder"),
        ("include of itself", cycle, "cycle", "hang"),
        ("include of a URDF", not_mujoco, "<mujoco>", "traceback"),
        (
            "include of a missing file",
            lambda w, o: '<include file="none.xml"/>',
            "none.xml",
            "traceback",
        ),
        ("include without a file", lambda w, o: "<include/>", "file attribute", "traceback"),
    ):
        cases.append(
            HostileCase(
                threat,
                "mcpilco-diagnose",
                f"robot file: {name}",
                model_with(include),
                ("robot.xml", expect),
            )
        )

    def fifo(w: Path, o: Path) -> list[str]:
        os.mkfifo(w / "robot.xml")
        return _diagnose(w / "robot.xml", EXAMPLE / "train_1.parquet", "--out", str(w / "out"))

    cases.append(
        HostileCase("hang", "mcpilco-diagnose", "robot file: a FIFO", fifo, ("robot.xml",))
    )
    return cases


def _log_cases() -> list[HostileCase]:
    import pandas as pd

    def frame() -> pd.DataFrame:
        return pd.read_parquet(EXAMPLE / "train_1.parquet")

    def degrees(df: pd.DataFrame, joints: Sequence[int]) -> pd.DataFrame:
        for j in joints:
            for g in ("q", "qd", "qdd"):
                df[f"{g}{j}"] = np.degrees(df[f"{g}{j}"])
        return df

    edits: list[tuple[str, Callable[[pd.DataFrame], pd.DataFrame], str, str, str, bool]] = [
        (
            "a torque column of booleans",
            lambda d: d.assign(tau1=d["tau1"] > 0),
            "tau1",
            "silent wrong answer",
            ".parquet",
            False,
        ),
        (
            "a torque column of booleans (CSV)",
            lambda d: d.assign(tau2=d["tau2"] > 0),
            "tau2",
            "silent wrong answer",
            ".csv",
            False,
        ),
        (
            "numbers stored as text",
            lambda d: d.assign(q1=d["q1"].astype(str)),
            "q1",
            "silent wrong answer",
            ".parquet",
            False,
        ),
        (
            "a word in a numeric column",
            lambda d: d.assign(q2=d["q2"].astype(object).where(d.index != 7, "oops")),
            "q2",
            "traceback",
            ".csv",
            False,
        ),
        (
            "joint 2 in degrees (q, qd, qdd)",
            lambda d: degrees(d, [2]),
            "degrees",
            "silent wrong answer",
            ".parquet",
            True,
        ),
        (
            "joints 1, 2, 4 in degrees",
            lambda d: degrees(d, [1, 2, 4]),
            "degrees",
            "silent wrong answer",
            ".parquet",
            True,
        ),
        (
            "q in degrees only",
            lambda d: d.assign(q1=np.degrees(d["q1"])),
            "degrees",
            "silent wrong answer",
            ".parquet",
            False,
        ),
        (
            "an inf",
            lambda d: d.assign(tau1=d["tau1"].where(d.index != 3, np.inf)),
            "tau1",
            "silent wrong answer",
            ".parquet",
            False,
        ),
        (
            "a torque of 1e300",
            lambda d: d.assign(tau1=d["tau1"].where(d.index != 3, 1e300)),
            "tau1",
            "silent wrong answer",
            ".parquet",
            False,
        ),
        (
            "time running backwards",
            lambda d: d.iloc[::-1].reset_index(drop=True),
            "time",
            "silent wrong answer",
            ".parquet",
            False,
        ),
    ]
    cases = []
    for name, edit, expect, threat, suffix, slow in edits:

        def build(w: Path, o: Path, edit: Callable = edit, suffix: str = suffix) -> list[str]:
            path = w / f"train{suffix}"
            df = edit(frame())
            df.to_csv(path, index=False) if suffix == ".csv" else df.to_parquet(path)
            return _diagnose(EXAMPLE / "robot.xml", path, "--out", str(w / "out"))

        cases.append(
            HostileCase(
                threat, "mcpilco-diagnose", f"log: {name}", build, ("train", expect), slow=slow
            )
        )

    def fifo(w: Path, o: Path) -> list[str]:
        os.mkfifo(w / "train.csv")
        return _diagnose(EXAMPLE / "robot.xml", w / "train.csv", "--out", str(w / "out"))

    def sidecar(w: Path, o: Path) -> list[str]:
        frame().to_csv(w / "train.csv", index=False)
        (w / "train.csv.json").write_text("[" * 100000 + "]" * 100000)
        return _diagnose(EXAMPLE / "robot.xml", w / "train.csv", "--out", str(w / "out"))

    cases.append(HostileCase("hang", "mcpilco-diagnose", "log: a FIFO", fifo, ("train.csv",)))
    cases.append(
        HostileCase(
            "traceback",
            "mcpilco-diagnose",
            "log: sidecar JSON nested 100000 levels",
            sidecar,
            ("train.csv",),
        )
    )
    for argv, flag in (
        (["--threshold", "nan"], "--threshold"),
        (["--threshold", "-inf"], "--threshold"),
        (["--auto", "-1"], "--auto"),
        (["--auto", "1e9"], "--auto"),
        (["--max-points", "0"], "--max-points"),
        (["--gip-iters", "-5"], "--gip-iters"),
    ):
        cases.append(
            HostileCase(
                "silent wrong answer",
                "mcpilco-diagnose",
                " ".join(argv),
                lambda w, o, a=argv: _diagnose(
                    EXAMPLE / "robot.xml", EXAMPLE / "train_1.parquet", *a
                ),
                (flag,),
            )
        )
    for argv, flag in (
        (["--calibration-fraction", "nan"], "--calibration-fraction"),
        (["--calibration-fraction", "1.5"], "--calibration-fraction"),
        (["--rate-tolerance", "nan"], "--rate-tolerance"),
        (["--merge-gap", "-1"], "--merge-gap"),
        (["--false-alarm-rate", "1"], "--false-alarm-rate"),
        (["--persistence", "0"], "--persistence"),
        (["--joint", "0"], "--joint"),
        (["--gp-points", "-1"], "--gp-points"),
    ):
        cases.append(
            HostileCase(
                "silent wrong answer",
                "mcpilco-detect-collisions",
                " ".join(argv),
                lambda w, o, a=argv: [str(w / "log.csv"), "--detector", str(w / "det.pt"), *a],
                (flag,),
            )
        )
    return cases


# ------------------------------------------------------------------------ collision bench
BENCH_TINY = [
    "--train-waypoints",
    "2",
    "--test-waypoints",
    "1",
    "--final-rest",
    "0.5",
    "--push-free-minutes",
    "0.05",
    "--push-waypoints",
    "2",
    "--no-progress",
]


BENCH_TINY_OPTIONS = {
    "seed": 0,
    "train_waypoints": 2,
    "test_waypoints": 1,
    "final_rest": 0.5,
    "push_free_minutes": 0.05,
    "push_waypoints": 2,
    "scenario_force": 40.0,
}  # the data options (collision_data.DATA_OPTIONS) of BENCH_TINY


def _bench_collision_cases() -> list[HostileCase]:
    def data_file(content: Callable[[Path, dict[str, Any]], None]) -> Callable:
        def build(w: Path, o: Path) -> list[str]:
            from mcpilco.experiments.collision.data import DATA_FILE

            (w / "runs").mkdir()
            content(w / "runs" / DATA_FILE, dict(BENCH_TINY_OPTIONS))
            return [*BENCH_TINY, "--runs-dir", str(w / "runs"), "--out-dir", str(w / "out")]

        return build

    def code(path: Path, options: dict[str, Any]) -> None:
        _torch_save(
            {"options": options, "sets": _Payload(path.parents[2] / "outside" / "pwned")}, path
        )

    def plain_pickle(path: Path, options: dict[str, Any]) -> None:
        import pickle

        marker = path.parents[2] / "outside" / "pwned"
        path.write_bytes(pickle.dumps({"options": options, "sets": _Payload(marker)}))

    def wrong(path: Path, options: dict[str, Any]) -> None:
        from mcpilco.models.torch_files import atomic_torch_save

        atomic_torch_save({"options": options, "sets": {"train": [1, 2]}}, path)

    def linked(path: Path, options: dict[str, Any]) -> None:
        path.symlink_to(path.parents[2] / "outside" / "victim.txt")

    return [
        HostileCase(
            "code execution",
            "mcpilco-bench-collision",
            "data file: a torch file with code",
            data_file(code),
            ("data.pt", "run code"),
        ),
        HostileCase(
            "code execution",
            "mcpilco-bench-collision",
            "data file: a pickle with code",
            data_file(plain_pickle),
            ("data.pt",),
        ),
        HostileCase(
            "silent wrong answer",
            "mcpilco-bench-collision",
            "data file of another structure",
            data_file(wrong),
            ("data.pt", "format"),
        ),
        HostileCase(
            "writes outside the folder",
            "mcpilco-bench-collision",
            "data file a link to another file",
            data_file(linked),
            ("data.pt", "symbolic link"),
        ),
    ]


def hostile_cases() -> list[HostileCase]:
    """Every hostile case, grouped by entry point and kind of input."""
    return [
        *_yaml_cases(),
        *_task_number_cases(),
        *_set_cases(),
        *_train_flag_cases(),
        *_run_folder_cases(),
        *_checkpoint_cases(),
        *_detector_cases(),
        *_robot_cases(),
        *_log_cases(),
        *_bench_collision_cases(),
    ]


# ------------------------------------------------------------------------ running
class _TimeUp(BaseException):
    """Raised by SIGALRM when a case passes its time limit."""


@contextlib.contextmanager
def _time_limit(seconds: float) -> Iterator[None]:
    def stop(signum: int, frame: Any) -> None:
        raise _TimeUp

    old = signal.signal(signal.SIGALRM, stop)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


@contextlib.contextmanager
def _no_display() -> Iterator[None]:
    """No ``DISPLAY`` / ``WAYLAND_DISPLAY`` while a case runs (as on a compute node)."""
    saved = {k: os.environ.pop(k) for k in ("DISPLAY", "WAYLAND_DISPLAY") if k in os.environ}
    try:
        yield
    finally:
        os.environ.update(saved)


def _main(entry: str) -> Callable[..., Any]:
    for ep in importlib.metadata.entry_points(group="console_scripts"):
        if ep.name == entry and ep.value.startswith("mcpilco."):
            return ep.load()
    raise LookupError(f"no console script {entry!r} is installed (pip install -e .)")


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def run_case(
    case: HostileCase,
    folder: Path,
    limit_s: float = CASE_LIMIT_S,
    main: Callable[..., Any] | None = None,
) -> dict[str, Any]:
    """Run ``case`` in ``folder`` (created; ``input/`` for its files, ``outside/`` with the
    victim file) with ``main`` (default: the ``main`` of the console script ``case.entry``);
    its ``outcome`` (:data:`OUTCOMES`), ``message`` (the last stderr line) and ``seconds``."""
    work, outside = folder / "input", folder / "outside"
    work.mkdir(parents=True)
    outside.mkdir()
    (outside / "victim.txt").write_text(VICTIM_TEXT)
    before = _snapshot(outside)
    argv = case.build(work, outside)
    main = _main(case.entry) if main is None else main
    err, out = io.StringIO(), io.StringIO()
    outcome, code = None, None
    t0 = time.perf_counter()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out), _no_display():
            with _time_limit(limit_s):
                try:
                    status = main(list(argv))
                    code = 0 if status is None else int(status)
                except SystemExit as stop:
                    code = (
                        stop.code if isinstance(stop.code, int) else (0 if stop.code is None else 2)
                    )
    except _TimeUp:
        outcome = "hang"
    except Exception as exc:  # noqa: BLE001 - an escaped exception is the outcome
        outcome = "traceback"
        err.write(f"\n{type(exc).__name__}: {' '.join(str(exc).split())[:300]}")
    seconds = time.perf_counter() - t0
    text = err.getvalue()
    lines = [line for line in text.strip().splitlines() if line.strip()]
    message = lines[-1] if lines else ""
    if _snapshot(outside) != before:
        outcome = "hole"
    elif outcome is None:
        if code == 0:
            outcome = "silent wrong answer"
        elif code != 2:
            outcome = "traceback"
        elif "Traceback" in text or "error:" not in message:
            outcome = "unclear error"
        elif not all(word.lower() in message.lower() for word in case.expect):
            outcome = "unclear error"
        else:
            outcome = "refused"
    return {
        "threat": case.threat,
        "entry": case.entry,
        "input": case.name,
        "outcome": outcome,
        "message": message.replace(str(folder), "<folder>").replace(str(ROOT), "<package>")[:300],
        "seconds": round(seconds, 2),
    }
