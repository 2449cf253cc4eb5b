"""The robot dataset schema: round trips, validation errors that name the culprit, and the
derivative filter on known functions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mcpilco.models.robot_data import (
    column_names,
    differentiate,
    from_frame,
    load_dataset,
    make_dataset,
    save_dataset,
)


def frame(n_rows: int = 50, n: int = 2, dt: float = 0.008) -> pd.DataFrame:
    t = np.arange(n_rows) * dt
    cols = {"t": t}
    for j in range(1, n + 1):
        cols[f"q{j}"] = np.sin(j * t)
        cols[f"qd{j}"] = j * np.cos(j * t)
        cols[f"qdd{j}"] = -(j**2) * np.sin(j * t)
        cols[f"tau{j}"] = 0.5 * t + j
        cols[f"i{j}"] = 0.1 * t - j
    cols["contact"] = (t > 0.2).astype(int)
    return pd.DataFrame(cols)


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_round_trip_keeps_values_order_and_metadata(tmp_path, suffix: str) -> None:
    df = frame()
    ds = from_frame(df)
    path = save_dataset(ds, tmp_path / f"d{suffix}", metadata={"robot": "test"})
    back = load_dataset(path, n_joints=2)
    np.testing.assert_array_equal(back.q, df[["q1", "q2"]].to_numpy())
    np.testing.assert_array_equal(back.tau, df[["tau1", "tau2"]].to_numpy())
    np.testing.assert_array_equal(back.contact, df["contact"].to_numpy())
    assert back.metadata["robot"] == "test" and back.metadata["computed"] == []
    assert back.metadata["units"]["i"] == "A"
    cols = list(pd.read_csv(path).columns) if suffix == ".csv" else list(back.to_frame().columns)
    expected = [c for c in column_names(2) if c in df.columns]
    assert cols == expected


def test_missing_column_is_named() -> None:
    df = frame().drop(columns=["qd2"])
    with pytest.raises(ValueError, match="'qd2'"):
        from_frame(df)
    with pytest.raises(ValueError, match="'t'"):
        from_frame(frame().drop(columns=["t"]))
    with pytest.raises(ValueError, match="tau1"):
        from_frame(frame().drop(columns=["tau1", "tau2", "i1", "i2"]))


def test_nan_row_names_row_and_column() -> None:
    df = frame()
    df.loc[17, "i2"] = np.nan
    with pytest.raises(ValueError, match=r"row 17 .*'i2'"):
        from_frame(df)


def test_time_not_increasing_names_the_row() -> None:
    df = frame()
    df.loc[23, "t"] = df.loc[22, "t"]
    with pytest.raises(ValueError, match="row 23"):
        from_frame(df)


def test_joint_count_mismatch(tmp_path) -> None:
    path = save_dataset(from_frame(frame(n=3)), tmp_path / "d.csv")
    with pytest.raises(ValueError, match="3 joints .* 6 were expected"):
        load_dataset(path, n_joints=6)
    df = frame(n=2)
    df["tau3"] = 0.0
    with pytest.raises(ValueError, match="'tau3'"):
        from_frame(df)


def test_derivatives_are_computed_when_absent() -> None:
    df = frame(n_rows=400).drop(columns=["qd1", "qd2", "qdd1", "qdd2"])
    ds = from_frame(df)
    t = ds.t
    inner = slice(10, -10)
    np.testing.assert_allclose(ds.qd[inner, 1], 2 * np.cos(2 * t[inner]), atol=1e-6)
    np.testing.assert_allclose(ds.qdd[inner, 1], -4 * np.sin(2 * t[inner]), atol=1e-4)
    assert ds.metadata["computed"] == ["qd", "qdd"]
    # non-uniform time: second-order central differences are exact on a quadratic
    t = np.cumsum(np.random.default_rng(0).uniform(0.005, 0.01, 30))
    np.testing.assert_allclose(differentiate(t**2, t), 2 * t, atol=1e-10)


def test_make_dataset_from_rollout_style_arrays() -> None:
    n, rows = 3, 20
    arrays = {
        "t": np.arange(rows) * 0.008,
        **{k: np.ones((rows, n)) for k in ("q", "qd", "qdd", "i")},
        "contact": np.zeros(rows, dtype=int),
        "f_ext": np.zeros((rows, 3)),
    }
    ds = make_dataset(arrays)
    assert (
        ds.n_joints == 3 and ds.tau is None and set(ds.extras) == {"f_ext_x", "f_ext_y", "f_ext_z"}
    )
    with pytest.raises(ValueError, match="'i' must have shape"):
        make_dataset({**arrays, "i": np.ones((rows, 2))})


EXAMPLE = Path(__file__).resolve().parents[2] / "models" / "diagnosis" / "examples"


@pytest.mark.parametrize("name", ["train_1", "test_1"])
def test_committed_example_files_read_and_write_unchanged(tmp_path, name: str) -> None:
    """The shipped diagnosis example: the loaded log's frame is the file's table (pyarrow's
    own reader is the truth), and writing it again as Parquet and CSV reads back the same
    columns and values with the stored metadata."""
    import pyarrow.parquet as pq

    path = EXAMPLE / "scara_coulomb2" / f"{name}.parquet"
    table = pq.read_table(path).to_pandas()
    log = load_dataset(path)
    assert log.n_segments == 1 and log.output == "tau" and log.y is log.tau
    pd.testing.assert_frame_equal(log.to_frame(), table[list(log.to_frame().columns)])
    for suffix in (".parquet", ".csv"):
        back = load_dataset(save_dataset(log, tmp_path / f"{name}{suffix}"))
        pd.testing.assert_frame_equal(back.to_frame(), log.to_frame(), check_exact=True)
        stored = {k: v for k, v in log.metadata.items() if k not in ("source", "units")}
        assert {k: back.metadata[k] for k in stored} == stored


def test_one_container_stacks_selects_and_splits_logs() -> None:
    """Two files stacked (the diagnosis's view): each segment selected back is that file's
    rows with every group it had; a time split cuts every segment at the fraction."""
    from mcpilco.models.diagnosis.data import as_trajectories

    a, b = from_frame(frame(40), source="a"), from_frame(frame(60), source="b")
    both = as_trajectories([a, b])
    assert both.n_segments == 2 and both.names == ["a", "b"]
    assert both.segments == [(0, 40), (40, 100)]
    second = both.select([1])
    assert second.names == ["b"] and second.segment.tolist() == [0] * 60
    for g in ("t", "q", "qd", "qdd", "tau", "i", "contact"):
        np.testing.assert_array_equal(getattr(second, g), getattr(b, g))
    np.testing.assert_array_equal(second.y, b.tau)
    first, last = both.split_time(0.7)
    assert first.n_samples == 28 + 42 and last.n_samples == 12 + 18
    assert first.segments == [(0, 28), (28, 70)] and last.names == ["a", "b"]
    np.testing.assert_array_equal(last.i[:12], a.i[28:])
    assert as_trajectories(both) is both  # prepared once
