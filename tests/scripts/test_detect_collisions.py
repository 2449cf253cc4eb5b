"""mcpilco-detect-collisions: a detector trained on a collision-free log finds a known
push in another log; bad files give clear errors (exit status 2)."""

from __future__ import annotations

import csv
import math
import re

import numpy as np
import pandas as pd
import pytest

from mcpilco.envs.arm_builder import dh_forward_kinematics
from mcpilco.envs.arm_data import PiecewiseTrajectory, QuinticMove, random_waypoints, rollout
from mcpilco.envs.arm_env import UR10_HOME, Push, UR10Env
from mcpilco.models.robot_data import save_dataset
from tests.conftest import run_command

SCHEMA = ("t", "q", "qd", "qdd", "tau", "i", "i_cmd", "e_q", "e_qd", "contact")
PUSH = (2.0, 0.5)  # onset, duration [s]


def _save(arrays: dict, path) -> None:
    save_dataset({k: arrays[k] for k in SCHEMA}, path)


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> dict:
    tmp = tmp_path_factory.mktemp("logs")
    env = UR10Env()
    home = np.array(UR10_HOME)
    half = np.array([0.6, 0.3, 0.4, 0.6, 0.6, 0.6])
    free_ref = random_waypoints(
        env.arm, np.random.default_rng(0), home, 6, bounds=np.stack([home - half, home + half], 1)
    )
    free = rollout(env, free_ref, seed=0, duration=min(free_ref.duration, 14.0))
    # push log: the arm holds the home pose; 80 N on link 4, horizontal and tangential
    p = dh_forward_kinematics(env.arm, home)[:3, 3]
    radial = p[:2] / np.linalg.norm(p[:2])
    force = 80.0 * np.array([-radial[1], radial[0], 0.0])
    push = Push(PUSH[0], PUSH[1], 4, tuple(force.tolist()), 0.05)
    hold = PiecewiseTrajectory([QuinticMove(home, home, 4.0)])
    pushed = rollout(env, hold, seed=1, pushes=[push])
    paths = {"free": tmp / "free.csv", "pushed": tmp / "pushed.csv", "dir": tmp}
    _save(free, paths["free"])
    _save(pushed, paths["pushed"])
    paths["pushed_arrays"] = pushed
    paths["detector"] = tmp / "pp.pt"
    code = run_command(
        "mcpilco-detect-collisions",
        [
            str(paths["pushed"]),
            "--train",
            str(paths["free"]),
            "--estimator",
            "PP",
            "--gp-points",
            "300",
            "--hyper-points",
            "150",
            "--adam-iters",
            "20",
            "--lbfgs-iters",
            "5",
            "--save",
            str(paths["detector"]),
            "--out-dir",
            str(tmp / "out_train"),
        ],
    )
    assert code == 0
    return paths


def test_detector_finds_the_push_and_writes_csv_and_png(logs, capsys, command) -> None:
    out = logs["dir"] / "out"
    code = command(
        "mcpilco-detect-collisions",
        [str(logs["pushed"]), "--detector", str(logs["detector"]), "--out-dir", str(out)],
    )
    assert code == 0
    assert "detection rate 1.00" in capsys.readouterr().out
    rows = list(csv.DictReader((out / "pushed_collisions.csv").open()))
    assert rows and set(rows[0]) == {"start", "end", "duration", "joint", "peak_ratio"}
    t0, t1 = PUSH[0], PUSH[0] + PUSH[1]
    hits = [r for r in rows if float(r["start"]) <= t1 + 0.25 and float(r["end"]) >= t0]
    assert hits, rows
    first = min(float(r["start"]) for r in hits)
    assert t0 <= first <= t0 + 0.1  # the ramp is 50 ms; a 80 N push is far above threshold
    assert max(float(r["peak_ratio"]) for r in hits) > 2.0
    assert (out / "pushed_collisions.png").stat().st_size > 10_000


def _broken(logs, tmp_path, change) -> str:
    df = pd.read_csv(logs["pushed"])
    df = change(df)
    path = tmp_path / "bad.csv"
    df.to_csv(path, index=False)
    return str(path)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda d: d.drop(columns=[f"i{j}" for j in range(1, 7)]), "missing motor-current"),
        (
            lambda d: d.drop(columns=[f"{g}{j}" for g in ("i", "tau") for j in range(1, 7)]),
            "'i1'..'i6'",
        ),
        (lambda d: d.assign(q3=d["q3"].where(d.index != 40, np.nan)), "NaN.*'q3'"),
        (lambda d: d.assign(t=d["t"] * 2.0), "wrong sample rate"),
        (lambda d: d.drop(index=range(100, 130)), "non-uniform sampling"),
        (
            lambda d: d.drop(columns=["q6", "qd6", "qdd6", "i6", "i_cmd6", "e_q6", "e_qd6"]),
            "joint count mismatch",
        ),
    ],  # fmt: skip
)
def test_bad_files_give_clear_errors(logs, tmp_path, capsys, command, change, message) -> None:
    bad = _broken(logs, tmp_path, change)
    code = command(
        "mcpilco-detect-collisions",
        [bad, "--detector", str(logs["detector"]), "--out-dir", str(tmp_path)],
    )
    assert code == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ")
    assert re.search(message, err), err


def test_fc_training_needs_the_controller_columns(logs, tmp_path, capsys, command) -> None:
    free = _broken(
        {"pushed": logs["free"]},
        tmp_path,
        lambda d: d.drop(columns=[f"i_cmd{j}" for j in range(1, 7)]),
    )
    code = command(
        "mcpilco-detect-collisions", [str(logs["pushed"]), "--train", free, "--estimator", "FC"]
    )
    assert code == 2
    assert "i_cmd1..i_cmd6" in capsys.readouterr().err
    assert math.isfinite(float(np.sum(logs["pushed_arrays"]["i"])))
