"""Property-based fuzzing (Hypothesis) of the loaders, the GP core, the task specifications and
a console script.

Every call ends in a result or a clear error (``ValueError`` / ``TypeError`` with a
message); a result never holds NaN or inf. The fast part runs in the default suite (few
examples, a deadline per example); the same properties with many examples are marked slow.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mcpilco.models.gp import GPRegressor
from mcpilco.models.robot_data import from_frame, load_dataset
from tests.conftest import run_command
from tests.models.gp.conftest import rbf_factory

FAST = settings(
    max_examples=15,
    deadline=5000,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)  # default suite: a few examples per property, fixed seed
LONG = settings(
    max_examples=300,
    deadline=20000,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)  # slow suite
EXAMPLE_DIR = Path(__file__).resolve().parents[1] / "models/diagnosis/examples/scara_coulomb2"

# floats as a user's data brings them: ordinary, tiny, huge, NaN and inf
values = st.one_of(
    st.floats(-10, 10),
    st.sampled_from([0.0, 1e-300, -1e-300, 1e151, -1e200, 1e300, np.nan, np.inf, -np.inf]),
    st.floats(allow_nan=True, allow_infinity=True),
)


def _clear(err: Exception) -> None:
    """A clear error: ValueError / TypeError with a message of a few words."""
    assert isinstance(err, ValueError | TypeError), repr(err)
    assert len(str(err).split()) >= 3, repr(err)


# ---------------------------------------------------------------------------- GP core
@st.composite
def gp_data(draw):
    n = draw(st.integers(1, 10))
    d = draw(st.integers(1, 3))
    m = draw(st.integers(1, 2))
    base = np.random.default_rng(draw(st.integers(0, 2**16)))
    X = base.uniform(-2, 2, (n, d))
    Y = np.sin(X.sum(1, keepdims=True)) + 0.1 * base.standard_normal((n, m))
    for _ in range(draw(st.integers(0, 3))):  # a few cells replaced by fuzzed values
        target = draw(st.sampled_from(["X", "Y"]))
        arr = X if target == "X" else Y
        arr[draw(st.integers(0, n - 1)), draw(st.integers(0, arr.shape[1] - 1))] = draw(values)
    return X, Y


def check_gp(data) -> None:
    X, Y = data
    gp = GPRegressor(rbf_factory(X.shape[1]))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            gp.fit(X, Y, adam_iters=5, lbfgs_iters=2)
    except (ValueError, TypeError) as err:
        _clear(err)
        return
    outputs = [
        *gp.predict(X),
        gp.predict_mean(X),
        *gp.loo_residuals(),
        gp.log_marginal_likelihood(),
        gp.noise_variance,
        gp.prior_variance(X),
    ]
    for out in outputs:
        assert torch.isfinite(out).all(), (X, Y, out)


@FAST
@given(gp_data())
def test_gp_core_gives_finite_results_or_clear_errors(data):
    check_gp(data)


@pytest.mark.slow
@LONG
@given(gp_data())
def test_gp_core_fuzz_long(data):
    check_gp(data)


# ---------------------------------------------------------------------------- loaders
@st.composite
def robot_frames(draw):
    """Frames of the robot schema: a smooth 1-2 joint motion, then fuzzed cells, dropped
    columns, shuffled or duplicated rows, or q in degrees."""
    n = draw(st.integers(0, 40))
    joints = draw(st.integers(1, 2))
    t = np.arange(n) * draw(st.sampled_from([0.001, 0.01, 0.5]))
    cols: dict[str, np.ndarray] = {"t": t}
    for j in range(1, joints + 1):
        cols[f"q{j}"] = np.sin(2 * t + j)
        if draw(st.booleans()):
            cols[f"qd{j}"] = 2 * np.cos(2 * t + j)
        cols[f"tau{j}"] = np.cos(t + j)
    df = pd.DataFrame(cols)
    for _ in range(draw(st.integers(0, 3))):
        if n and df.shape[1]:
            df.iloc[draw(st.integers(0, n - 1)), draw(st.integers(0, df.shape[1] - 1))] = draw(
                values
            )
    edit = draw(st.sampled_from(["none", "shuffle", "duplicate", "drop", "degrees"]))
    if edit == "shuffle" and n > 1:
        df = df.sample(frac=1.0, random_state=draw(st.integers(0, 99)))
    elif edit == "duplicate" and n > 0:
        df = pd.concat([df, df.iloc[: draw(st.integers(1, n))]]).sort_values("t", kind="stable")
    elif edit == "drop":
        df = df.drop(columns=[draw(st.sampled_from(list(df.columns)))])
    elif edit == "degrees":
        for c in df.columns:
            if c.startswith("q") and not c.startswith("qd"):
                df[c] = np.degrees(df[c])
    return df, edit


def check_frame(frame) -> None:
    df, edit = frame
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ds = from_frame(df, source="fuzz")
    except (ValueError, TypeError) as err:
        _clear(err)
        return
    for name in ("t", "q", "qd", "qdd", "tau"):
        assert np.isfinite(getattr(ds, name)).all(), name
    if edit == "duplicate" or (edit == "shuffle" and len(df) > 1):
        raise AssertionError(f"{edit} rows accepted")  # time must increase strictly
    has_qd = any(str(c).startswith("qd") for c in df.columns)
    if edit == "degrees" and has_qd and len(df) > 20 and np.ptp(df["t"]) > 1:
        raise AssertionError("q in degrees with qd in rad/s accepted")


@FAST
@given(robot_frames())
def test_loader_gives_finite_data_or_clear_errors(frame):
    check_frame(frame)


@pytest.mark.slow
@LONG
@given(robot_frames())
def test_loader_fuzz_long(frame):
    check_frame(frame)


@FAST
@given(st.binary(max_size=300), st.sampled_from([".csv", ".parquet"]))
def test_file_loader_on_arbitrary_bytes(tmp_path_factory, content, suffix):
    path = tmp_path_factory.mktemp("fuzz") / f"data{suffix}"
    path.write_bytes(content)
    try:
        load_dataset(path)
    except (ValueError, TypeError) as err:
        _clear(err)
        assert str(path) in str(err)


# ---------------------------------------------------------------------------- a CLI
@FAST
@given(st.binary(max_size=200), st.integers(0, 3))
def test_diagnose_cli_on_damaged_training_files(tmp_path_factory, content, rows):
    """Garbage, empty or tiny training files: exit 2 with one line naming the file."""
    folder = tmp_path_factory.mktemp("cli")
    train = folder / "train.csv"
    if rows:
        pd.read_parquet(EXAMPLE_DIR / "train_1.parquet").head(rows).to_csv(train, index=False)
    else:
        train.write_bytes(content)
    argv = ["--model", str(EXAMPLE_DIR / "robot.xml"), "--train", str(train)]
    argv += ["--test", str(EXAMPLE_DIR / "test_1.parquet"), "--no-plots", "--no-rerun"]
    argv += ["--out", str(folder / "out")]
    import contextlib
    import io

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = run_command("mcpilco-diagnose", argv)
    lines = err.getvalue().strip().splitlines()
    assert code == 2 and len(lines) == 1 and "train.csv" in lines[0], err.getvalue()


# -------------------------------------------------------------------------- task specs
NAMES = ["x", "x_dot", "theta", "theta_dot", "q"]
junk = st.one_of(
    st.none(), st.integers(-3, 5), st.text(max_size=4), values, st.lists(st.integers(-1, 6))
)


@st.composite
def task_dicts(draw):
    """A valid task file with 0-3 of its fields broken: deleted, replaced by junk of any type,
    or given fuzzed numbers, duplicate or unknown names."""
    n = draw(st.integers(1, 5))
    names = NAMES[:n]
    angles = draw(st.lists(st.sampled_from(names), unique=True, max_size=2))
    pairs = [[names[0], names[1]]] if n >= 2 and names[1] not in angles else []
    d = {
        "env_id": "fuzz",
        "state_names": list(names),
        "angles": angles,
        "pairs": pairs,
        "action_low": [-1.0],
        "action_high": [1.0],
        "dt": 0.05,
        "horizon": 10,
        "init_std": 0.01,
        "cost": {"terms": [{"state": names[-1], "target": 1.0, "length_scale": 0.5}]},
        "success": {"window": 5, "bounds": {names[0]: {"target": 0.0, "tol": 0.1}}},
    }
    broken = {
        "state_names": st.lists(st.sampled_from(NAMES + ["", "x"]), max_size=6),
        "angles": st.lists(st.sampled_from(NAMES + ["phi"]), max_size=3),
        "pairs": st.lists(st.lists(st.sampled_from(NAMES + [None]), max_size=3), max_size=3),
        "action_low": st.lists(values, max_size=2),
        "action_high": st.lists(values, max_size=2),
        "dt": values,
        "horizon": st.one_of(st.integers(-2, 100), values),
        "init_std": st.one_of(values, st.lists(values, max_size=5)),
        "cost": st.fixed_dictionaries(
            {
                "terms": st.lists(
                    st.fixed_dictionaries(
                        {"state": st.sampled_from(NAMES + ["z"]), "length_scale": values},
                        optional={"target": values, "angle_mode": st.sampled_from(["wrap", "x"])},
                    ),
                    max_size=3,
                )
            }
        ),
        "success": st.fixed_dictionaries(
            {},
            optional={
                "window": st.one_of(st.none(), st.integers(-1, 200)),
                "info_key": st.sampled_from(["success", None]),
                "bounds": st.dictionaries(
                    st.sampled_from(NAMES + ["q"]),
                    st.fixed_dictionaries({"tol": values}, optional={"target": values}),
                    max_size=2,
                ),
            },
        ),
    }
    for key in draw(st.lists(st.sampled_from(sorted(broken)), max_size=3)):
        how = draw(st.integers(0, 2))
        if how == 0:
            d.pop(key, None)
        else:
            d[key] = draw(junk if how == 1 else broken[key])
    return d


def _check_task(d) -> None:
    from mcpilco.envs.tasks.spec import TaskSpec, TaskSpecError

    try:
        task = TaskSpec.from_dict(d)
    except TaskSpecError as err:  # names the field: "task.<field>: ..."
        _clear(err)
        assert str(err).startswith("task"), str(err)
        return
    # a spec that validates is usable: finite bounds, a positive period and a cost in [0, 1)
    assert all(np.isfinite(task.action_low)) and task.dt > 0 and task.horizon >= 1
    x = np.zeros((3, task.state_dim))
    c = task.cost(x)
    assert np.all((c >= 0) & (c < 1))


@FAST
@given(task_dicts())
def test_task_specs_validate_or_fail_clearly(d):
    _check_task(d)


@pytest.mark.slow
@LONG
@given(task_dicts())
def test_task_specs_validate_or_fail_clearly_long(d):
    _check_task(d)
