"""Robustness figures of the package: bad inputs by kind, random (fuzzed) inputs, and runs
killed with SIGKILL.

For every input the outcome is one of :data:`OUTCOMES`: ``result`` (finite answer on sound
input), ``clear error`` (commands: exit status 2 and a message without a traceback; library
calls: ``ValueError``/``TypeError`` with a message), ``crash`` (a traceback, another
exception or exit status) or ``silent wrong`` (an answer, exit 0 or a NaN, on input that
cannot support one).

* :func:`diagnose_cases`, :func:`train_cases`, :func:`lock_case`: bad files, arguments,
  folders and checkpoints given to ``mcpilco-diagnose`` and ``mcpilco-train``, each run as
  the command in its own process (:func:`run_case`);
* :func:`fuzz_counts`: random GP data, robot-log frames and file bytes given to the library;
* :func:`kill_runs`: a small ``mcpilco-train`` run is killed with SIGKILL after a given time,
  then continued with ``--resume`` (``--overwrite`` when no trial had finished), and the
  finished trials lost are counted;
* :func:`hostile_results`: the hostile inputs of every entry point
  (:mod:`mcpilco.experiments.infra.hostile_inputs`), counted per threat class by outcome (holes,
  hangs, tracebacks, silent wrong answers, unclear errors).

:func:`run_robustness` runs them all; :func:`write_result` writes ``robustness.json`` and
the tables of :func:`markdown` in ``robustness.md``.
"""

from __future__ import annotations

import importlib.metadata
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
import warnings
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from mcpilco.experiments import results as result_files
from mcpilco.experiments.results import Headline, Result, ResultLayout
from mcpilco.models.files import write_atomic

__all__ = [
    "OUTCOMES",
    "TRAIN_ARGS",
    "classify_exit",
    "command_line",
    "diagnose_cases",
    "fuzz_counts",
    "hostile_results",
    "hostile_table",
    "kill_runs",
    "lock_case",
    "markdown",
    "outcome_lines",
    "run_case",
    "run_robustness",
    "train_cases",
    "write_result",
]

# the SCARA example of the diagnosis (robot.xml, train_1.parquet, test_1.parquet)
EXAMPLE = Path(__file__).resolve().parents[1] / "models/diagnosis/examples/scara_coulomb2"
TRAIN_ARGS = [
    "--trials",
    "2",
    "--particles",
    "20",
    "--opt-steps",
    "10",
    "--max-points",
    "60",
    "--threads",
    "1",
    "--no-progress",
    "--no-rrd",
]  # a small mcpilco-train run (3 trials)
CASE_TIMEOUT_S = 600  # seconds a refused command may take before it counts as a crash


def command_line(name: str) -> list[str]:
    """The command line that runs console script ``name`` (e.g. ``mcpilco-train``) of the
    installed package with this interpreter: ``python -m <its module>``."""
    for entry in importlib.metadata.entry_points(group="console_scripts"):
        if entry.name == name and entry.value.startswith("mcpilco."):
            return [sys.executable, "-m", entry.module]
    raise LookupError(f"no console script {name!r} is installed (pip install -e .)")


def _command_env() -> dict[str, str]:
    return {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}


def classify_exit(code: int, stderr: str) -> tuple[str, str]:
    """(outcome, message) of a command on bad input that ended with status ``code``: exit 2
    with a message and no traceback is a clear error (its last line the message), exit 0
    is silently wrong, anything else a crash."""
    lines = stderr.strip().splitlines()
    if code == 2 and lines and "Traceback" not in stderr:
        return "clear error", lines[-1][:200]
    if code == 0:
        return "silent wrong", "exit 0"
    return "crash", f"exit {code}: {lines[-1] if lines else ''}"[:200]


def run_case(name: str, argv: Sequence[str]) -> tuple[str, str]:
    """Run console script ``name`` with ``argv`` in its own process; its
    :func:`classify_exit` outcome and message (a command still running after
    :data:`CASE_TIMEOUT_S` is a crash)."""
    try:
        done = subprocess.run(
            [*command_line(name), *argv],
            capture_output=True,
            text=True,
            env=_command_env(),
            timeout=CASE_TIMEOUT_S,
        )
    except subprocess.TimeoutExpired:
        return "crash", f"still running after {CASE_TIMEOUT_S} s"
    return classify_exit(done.returncode, done.stderr)


def diagnose_cases(tmp: Path) -> list[dict[str, Any]]:
    """Bad training / test / model / output inputs of mcpilco-diagnose (each must be refused)."""
    tr = pd.read_parquet(EXAMPLE / "train_1.parquet")
    files: dict[str, Callable[[Path], None]] = {
        "3-row training file": lambda p: tr.head(3).to_csv(p, index=False),
        "q in degrees": lambda p: tr.assign(
            **{f"q{j}": np.degrees(tr[f"q{j}"]) for j in (1, 2)}
        ).to_csv(p, index=False),
        "qd in deg/s": lambda p: tr.assign(qd1=np.degrees(tr["qd1"])).to_csv(p, index=False),
        "one torque of 1e300": lambda p: tr.assign(
            tau1=tr["tau1"].where(tr.index != 500, 1e300)
        ).to_csv(p, index=False),
        "a NaN value": lambda p: tr.assign(q2=tr["q2"].where(tr.index != 9, np.nan)).to_csv(
            p, index=False
        ),
        "shuffled rows": lambda p: tr.sample(frac=1.0, random_state=0).to_csv(p, index=False),
        "duplicated rows": lambda p: (
            pd.concat([tr, tr.head(50)]).sort_values("t", kind="stable").to_csv(p, index=False)
        ),
        "empty file": lambda p: p.write_bytes(b""),
        "garbage bytes": lambda p: p.write_bytes(os.urandom(200)),
        "header only": lambda p: p.write_text(",".join(tr.columns) + "\n"),
        "missing file": lambda p: None,
    }
    base = ["--model", str(EXAMPLE / "robot.xml"), "--no-plots", "--no-rerun"]
    test = ["--test", str(EXAMPLE / "test_1.parquet")]
    rows = []
    for name, write in files.items():
        path = tmp / f"train_{len(rows)}.csv"
        write(path)
        argv = [*base, "--train", str(path), *test, "--out", str(tmp / "out")]
        rows.append({"tool": "diagnose", "kind": "training file", "input": name})
        rows[-1]["outcome"], rows[-1]["message"] = run_case("mcpilco-diagnose", argv)
    tr.head(3).to_csv(tmp / "test3.csv", index=False)
    (tmp / "a_file").write_text("x")
    (tmp / "empty.xml").write_text("")
    (tmp / "bad.xml").write_text("<mujoco><worldbody><body></mujoco>")
    good = ["--train", str(EXAMPLE / "train_1.parquet"), "--no-plots", "--no-rerun"]
    others = {
        ("test file", "3-row test file"): [*good, "--model", str(EXAMPLE / "robot.xml")]
        + ["--test", str(tmp / "test3.csv"), "--out", str(tmp / "out")],
        ("model", "model path is a folder"): [*good, "--model", str(tmp), *test],
        ("model", "empty MJCF"): [*good, "--model", str(tmp / "empty.xml"), *test],
        ("model", "malformed MJCF"): [*good, "--model", str(tmp / "bad.xml"), *test],
        ("output", "--out is a file"): [*good, "--model", str(EXAMPLE / "robot.xml"), *test]
        + ["--out", str(tmp / "a_file")],
    }
    for (kind, name), argv in others.items():
        outcome, message = run_case("mcpilco-diagnose", argv)
        rows.append(
            {
                "tool": "diagnose",
                "kind": kind,
                "input": name,
                "outcome": outcome,
                "message": message,
            }
        )
    return rows


def train_cases(tmp: Path, finished: Path) -> list[dict[str, Any]]:
    """Bad arguments, folders and checkpoints of mcpilco-train (each must be refused)."""
    (tmp / "a_file").write_text("x")
    cases: dict[tuple[str, str], tuple[list[str], Callable[[Path], None] | None]] = {
        ("argument", "--seed -1"): (["--seed", "-1"], None),
        ("argument", "--trials -2"): (["--trials", "-2"], None),
        ("output", "--out is a file"): (["--out", str(tmp / "a_file")], None),
        ("run folder", "new run over a finished run"): (["--out", str(finished)], None),
        ("run folder", "--resume and --overwrite"): (
            ["--out", str(finished), "--resume", "--overwrite"],
            None,
        ),
    }
    for name, content in {
        "empty checkpoint": b"",
        "garbage checkpoint": os.urandom(300),
        "truncated checkpoint": (finished / "checkpoint.pt").read_bytes()[:2000],
        "checkpoint with code (pickle)": None,
        "no checkpoint (--resume on a new folder)": b"-",
        "missing gp_trialXX.pt": b"gp",
    }.items():

        def write(folder: Path, content: bytes | None = content) -> None:
            if content is None:
                import torch

                torch.save({"version": 3, "x": print}, folder / "checkpoint.pt")
            elif content == b"gp":
                for f in finished.iterdir():
                    if f.name != "gp_trial02.pt" and f.name != "run.lock":
                        (folder / f.name).write_bytes(f.read_bytes())
            elif content != b"-":
                (folder / "checkpoint.pt").write_bytes(content)

        cases[("checkpoint", name)] = (["--resume"], write)
    rows = []
    for k, ((kind, name), (argv, write)) in enumerate(cases.items()):
        folder = tmp / f"run_{k}"
        folder.mkdir()
        if write is not None:
            write(folder)
        if "--out" not in argv:
            argv = [*argv, "--out", str(folder)]
        outcome, message = run_case("mcpilco-train", [*argv, *TRAIN_ARGS])
        rows.append(
            {"tool": "train", "kind": kind, "input": name, "outcome": outcome, "message": message}
        )
    return rows


def _train_process(out: Path, *extra: str) -> subprocess.Popen:
    """A small ``mcpilco-train`` run (:data:`TRAIN_ARGS`) in ``out``, started in the
    background."""
    cmd = [*command_line("mcpilco-train"), *TRAIN_ARGS, "--out", str(out), *extra]
    return subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_command_env()
    )


def lock_case(tmp: Path) -> dict[str, Any]:
    """Two processes on one folder: the second must fail at once with a clear message."""
    first = _train_process(tmp / "locked")
    time.sleep(8.0)
    t0 = time.perf_counter()
    second = _train_process(tmp / "locked", "--resume")
    _, err = second.communicate(timeout=120)
    first.send_signal(signal.SIGKILL)
    first.wait()
    ok = second.returncode == 2 and "in use by process" in err and len(err.splitlines()) == 1
    return {
        "tool": "train",
        "kind": "run folder",
        "input": "second process on the same folder",
        "outcome": "clear error" if ok else "crash",
        "message": (err.strip().splitlines() or [""])[-1][:200],
        "seconds": round(time.perf_counter() - t0, 2),
    }


def kill_runs(tmp: Path, kill_after: Sequence[float]) -> list[dict[str, Any]]:
    """SIGKILL a small run after each delay, continue it, count the finished trials lost."""
    rows = []
    for k, delay in enumerate(kill_after):
        out = tmp / f"kill_{k}"
        proc = _train_process(out)
        time.sleep(delay)
        proc.send_signal(signal.SIGKILL)
        stdout, _ = proc.communicate()
        finished = len(re.findall(r"^trial \d+ ", stdout, flags=re.M))
        resumed = _train_process(out, "--resume")
        r_out, r_err = resumed.communicate(timeout=900)
        how = "--resume"
        if resumed.returncode == 2 and "no trial of a run" in r_err:
            again = _train_process(out, "--overwrite")
            r_out, r_err = again.communicate(timeout=900)
            how, code = "--resume refused (one line), then --overwrite", again.returncode
        else:
            code = resumed.returncode
        match = re.search(r"trials 0\.\.(\d+) done", r_out)
        kept = int(match.group(1)) + 1 if match else 0
        rows.append(
            {
                "kill_after_s": delay,
                "trials_finished_before_kill": finished,
                "trials_kept": kept,
                "finished_trials_lost": max(finished - kept, 0),
                "continued_with": how,
                "continued_exit": code,
                "run_completed": code == 0 and "done in" in r_out,
            }
        )
    return rows


def hostile_results(tmp: Path) -> list[dict[str, Any]]:
    """The outcome of every hostile case (:func:`~.hostile_inputs.run_case`, in this
    process, each in its own folder under ``tmp``)."""
    from mcpilco.experiments.infra.hostile_inputs import hostile_cases, run_case

    return [run_case(c, tmp / f"hostile_{k}") for k, c in enumerate(hostile_cases())]


def hostile_table(rows: Sequence[dict[str, Any]]) -> list[str]:
    """Markdown lines: hostile cases counted per threat class by outcome, then every case
    that was not refused."""
    from mcpilco.experiments.infra.hostile_inputs import OUTCOMES as HOSTILE
    from mcpilco.experiments.infra.hostile_inputs import THREATS

    md = ["| threat class | cases | " + " | ".join(HOSTILE) + " |"]
    md.append("|" + "---|" * (2 + len(HOSTILE)))
    for threat in [*THREATS, "all"]:
        mine = [r for r in rows if threat in ("all", r["threat"])]
        counts = Counter(r["outcome"] for r in mine)
        cells = " | ".join(str(counts.get(o, 0)) for o in HOSTILE)
        md.append(f"| {threat} | {len(mine)} | {cells} |")
    entries = Counter(r["entry"] for r in rows)
    md += ["", "Cases per entry point: " + ", ".join(f"{e} {n}" for e, n in entries.items())]
    failed = [r for r in rows if r["outcome"] != "refused"]
    if failed:
        md += ["", "| case | outcome | message |", "|---|---|---|"]
        for r in failed:
            message = r["message"].replace("|", "\\|")
            md.append(f"| {r['entry']}: {r['input']} | {r['outcome']} | {message} |")
    return md


def fuzz_counts(seed: int, n: int) -> list[dict[str, Any]]:
    """Outcomes of random GP data, robot frames and file bytes (``n`` inputs per kind)."""
    import torch

    from mcpilco.models.gp import GPRegressor
    from mcpilco.models.robot_data import from_frame

    rng = np.random.default_rng(seed)
    special = [np.nan, np.inf, -np.inf, 1e300, -1e200, 1e151, 1e-300, 0.0]

    def rbf(batch: Any) -> Any:
        import gpytorch

        return gpytorch.kernels.ScaleKernel(
            gpytorch.kernels.RBFKernel(batch_shape=batch), batch_shape=batch
        )

    def fuzz(arr: np.ndarray) -> np.ndarray:
        for _ in range(rng.integers(0, 3)):
            arr[rng.integers(arr.shape[0]), rng.integers(arr.shape[1])] = rng.choice(special)
        return arr

    counts: dict[str, Counter] = {k: Counter() for k in ("GP core", "loader", "file bytes")}
    for _ in range(n):
        rows = int(rng.integers(1, 12))
        X = rng.uniform(-2, 2, (rows, int(rng.integers(1, 4))))
        Y = np.sin(X.sum(1, keepdims=True)) + 0.1 * rng.standard_normal((rows, 1))
        X, Y = (fuzz(X), Y) if rng.random() < 0.5 else (X, fuzz(Y))
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                gp = GPRegressor(rbf).fit(X, Y, adam_iters=5, lbfgs_iters=2)
            outs = [*gp.predict(X), *gp.loo_residuals(), gp.log_marginal_likelihood()]
            finite = all(bool(torch.isfinite(o).all()) for o in outs)
            counts["GP core"]["result" if finite else "silent wrong"] += 1
        except (ValueError, TypeError):
            counts["GP core"]["clear error"] += 1
        except Exception:  # noqa: BLE001
            counts["GP core"]["crash"] += 1
    for _ in range(n):
        rows = int(rng.integers(0, 60))
        t = np.arange(rows) * rng.choice([0.001, 0.01, 0.5])
        df = pd.DataFrame({"t": t, "q1": np.sin(2 * t), "qd1": 2 * np.cos(2 * t), "tau1": t})
        if rows:
            df = pd.DataFrame(fuzz(df.to_numpy().copy()), columns=df.columns)
        edit = rng.choice(["none", "shuffle", "duplicate", "degrees"])
        if edit == "shuffle" and rows > 1:
            df = df.sample(frac=1.0, random_state=0)
        elif edit == "duplicate" and rows:
            df = pd.concat([df, df.head(1)]).sort_values("t", kind="stable")
        elif edit == "degrees":
            df["q1"] = np.degrees(df["q1"])
        bad_edit = (edit in ("shuffle", "duplicate") and rows > 1) or (
            edit == "degrees" and rows > 20 and float(np.ptp(t)) > 1
        )
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                ds = from_frame(df, source="fuzz")
            finite = all(np.isfinite(getattr(ds, g)).all() for g in ("t", "q", "qd", "qdd"))
            counts["loader"]["result" if finite and not bad_edit else "silent wrong"] += 1
        except (ValueError, TypeError):
            counts["loader"]["clear error"] += 1
        except Exception:  # noqa: BLE001
            counts["loader"]["crash"] += 1
    with tempfile.TemporaryDirectory() as folder_name:
        _fuzz_files(rng, n, Path(folder_name), counts["file bytes"])
    return [{"kind": k, "inputs": sum(c.values()), **dict(c)} for k, c in counts.items()]


def _fuzz_files(rng: np.random.Generator, n: int, folder: Path, counts: Counter) -> None:
    """``n`` files of random bytes (``.csv`` and ``.parquet`` alternately) given to
    :func:`~mcpilco.models.robot_data.load_dataset`; an error must name the file."""
    from mcpilco.models.robot_data import load_dataset

    for k in range(n):
        path = folder / f"f{k}{'.csv' if k % 2 else '.parquet'}"
        path.write_bytes(rng.bytes(int(rng.integers(0, 300))))
        try:
            load_dataset(path)
            counts["silent wrong"] += 1
        except (ValueError, TypeError) as err:
            counts["clear error" if str(path) in str(err) else "crash"] += 1
        except Exception:  # noqa: BLE001
            counts["crash"] += 1
        path.unlink()


OUTCOMES = ("result", "clear error", "crash", "silent wrong")  # columns of the tables


def markdown(result: dict[str, Any]) -> str:
    """The tables of ``result``: hostile inputs counted per threat class
    (:func:`hostile_table`), inputs counted by tool and kind (fuzzed inputs included), each
    case with its message, killed runs."""
    md = [*hostile_table(result.get("hostile", [])), ""] if result.get("hostile") else []
    md += ["| tool | kind of input | inputs | " + " | ".join(OUTCOMES) + " |"]
    md.append("|" + "---|" * (3 + len(OUTCOMES)))
    groups: dict[tuple[str, str], Counter] = {}
    for c in result["cases"]:
        groups.setdefault((c["tool"], c["kind"]), Counter())[c["outcome"]] += 1
    for (tool, kind), counts in groups.items():
        cells = " | ".join(str(counts.get(o, 0)) for o in OUTCOMES)
        md.append(f"| {tool} | {kind} | {sum(counts.values())} | {cells} |")
    for row in result["fuzz"]:
        cells = " | ".join(str(row.get(o, 0)) for o in OUTCOMES)
        md.append(f"| fuzz | {row['kind']} | {row['inputs']} | {cells} |")
    md += ["", "| input | outcome | message |", "|---|---|---|"]
    for c in result["cases"]:
        message = c["message"].replace("|", "\\|")
        md.append(f"| {c['tool']}: {c['input']} | {c['outcome']} | {message} |")
    md += [
        "",
        "| killed after | trials finished | trials kept | finished trials lost | continued with "
        "| run completed |",
        "|---|---|---|---|---|---|",
    ]
    for k in result["kills"]:
        md.append(
            f"| {k['kill_after_s']:g} s | {k['trials_finished_before_kill']} | "
            f"{k['trials_kept']} | {k['finished_trials_lost']} | {k['continued_with']} | "
            f"{'yes' if k['run_completed'] else 'no'} |"
        )
    return "\n".join(md) + "\n"


def run_robustness(
    kill_after: Sequence[float] = (3.0, 12.0, 30.0),
    fuzz: int = 200,
    seed: int = 0,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Every part, in a temporary folder: a finished reference run of ``mcpilco-train``
    (which the checkpoint cases damage copies of), the diagnose, train and lock cases, runs
    killed after each delay of ``kill_after``, and ``fuzz`` random inputs per fuzzed kind
    (seed ``seed``). Returns ``cases``, ``fuzz``, ``kills`` and ``seconds``; the temporary
    folder's path in a message reads ``<folder>``.

    Raises:
        ValueError: the reference run failed.
    """
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        finished = tmp / "finished"
        done = _train_process(finished)
        done.communicate(timeout=900)
        if done.returncode != 0:
            raise ValueError("the reference mcpilco-train run failed; run it alone to see why")
        log("diagnose, train and lock cases")
        cases = diagnose_cases(tmp) + train_cases(tmp, finished) + [lock_case(tmp)]
        log(f"runs killed after {', '.join(f'{d:g} s' for d in kill_after)}")
        kills = kill_runs(tmp, kill_after)
        for c in cases:  # the temporary folder is no part of the figures
            c["message"] = c["message"].replace(str(tmp), "<folder>")
        log("hostile inputs")
        hostile = hostile_results(tmp)
    log(f"{fuzz} fuzzed inputs per kind")
    fuzzed = fuzz_counts(seed, fuzz)
    return {
        "cases": cases,
        "fuzz": fuzzed,
        "kills": kills,
        "hostile": hostile,
        "seconds": round(time.perf_counter() - t0, 1),
    }


def write_result(result: dict[str, Any], out_dir: Path) -> tuple[Path, Path]:
    """``robustness.json`` (``result``) and ``robustness.md`` (:func:`markdown`) in
    ``out_dir``; their paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    json_path, md_path = out_dir / "robustness.json", out_dir / "robustness.md"
    result_files.write_result(json_path, RESULT_LAYOUTS[0], result)
    write_atomic(md_path, markdown(result))
    return json_path, md_path


def outcome_lines(result: dict[str, Any]) -> list[str]:
    """Short text lines of ``result``: cases counted by tool, kind and outcome, then the
    fuzz and kill rows."""
    by = Counter((c["tool"], c["kind"], c["outcome"]) for c in result["cases"])
    by.update(("hostile", r["threat"], r["outcome"]) for r in result.get("hostile", []))
    lines = ["\t".join(map(str, (*key, count))) for key, count in sorted(by.items())]
    return lines + [str(row) for row in (*result["fuzz"], *result["kills"])]


# -- result file and headline rows of the results index -----------------------------------

RESULT_LAYOUTS = (ResultLayout("robustness", cases=("cases", "fuzz", "kills", "hostile")),)
"""The layout of ``robustness.json`` (:mod:`mcpilco.experiments.results`)."""


def _robustness_row(r: Result) -> str:
    outcomes = [c["outcome"] for c in r["cases"]]
    fuzz = sum(f["inputs"] for f in r["fuzz"])
    crash = outcomes.count("crash") + sum(f.get("crash", 0) for f in r["fuzz"])
    silent = outcomes.count("silent wrong") + sum(f.get("silent wrong", 0) for f in r["fuzz"])
    text = (
        f"{len(outcomes)} bad inputs to the console scripts and {fuzz} fuzzed inputs: "
        f"{crash} crashes, {silent} silent wrong answers"
    )
    hostile = r.payload().get("hostile") or []
    if hostile:
        refused = sum(c["outcome"] == "refused" for c in hostile)
        text += f"; {refused} of {len(hostile)} hostile inputs refused with one line"
    return text


HEADLINES = (
    Headline(
        "Robustness", "robustness.json", _robustness_row, "robustness.md", seeds=lambda r: "-"
    ),
)
"""The robustness figures' row of the results index."""
