"""Data sanity before any fit: plausible ranges, degrees, coarse sampling, minimum rows."""

from __future__ import annotations

import numpy as np
import pytest

from mcpilco.models.diagnosis.data import MIN_FIT_ROWS, as_trajectories, require_rows
from mcpilco.models.robot_data import make_dataset


def _motion(n=500, dt=0.01, freq=1.0):
    t = np.arange(n) * dt
    q = np.stack([0.5 * np.sin(freq * t), 0.3 * np.cos(0.7 * freq * t)], 1)
    qd = np.stack([0.5 * freq * np.cos(freq * t), -0.21 * freq * np.sin(0.7 * freq * t)], 1)
    return {"t": t, "q": q, "qd": qd, "tau": np.cos(t)[:, None].repeat(2, 1)}


def test_consistent_data_passes():
    ds = make_dataset(_motion())
    assert "warnings" not in ds.metadata


def test_degrees_are_detected_by_the_integral_of_qd():
    arrays = _motion()
    arrays["q"] = np.degrees(arrays["q"])
    with pytest.raises(ValueError, match="'q1' .* factor 57.3; q1 looks like degrees"):
        make_dataset(arrays)
    arrays = _motion()
    arrays["qd"] = np.degrees(arrays["qd"])
    with pytest.raises(ValueError, match="qd1 looks like degrees per second"):
        make_dataset(arrays)


def test_implausible_value_is_named():
    arrays = _motion()
    arrays["tau"][123, 1] = 1e300
    with pytest.raises(ValueError, match="column 'tau2' holds 1e\\+300 at row 123"):
        make_dataset(arrays)


def test_coarse_sampling_for_a_computed_derivative_warns_and_is_kept():
    arrays = _motion(n=200, dt=0.5, freq=5.0)  # 0.6 samples per half swing
    del arrays["qd"]
    with pytest.warns(RuntimeWarning, match="qd1 computed from q1 changes sign every"):
        ds = make_dataset(arrays)
    traj = as_trajectories(ds)
    assert any("sample faster" in w for w in traj.warnings)


def test_minimum_rows_name_the_number_needed():
    traj = as_trajectories(make_dataset(_motion(n=30)))
    with pytest.raises(ValueError, match=f"the fit needs at least {MIN_FIT_ROWS} rows, got 30"):
        require_rows(traj, MIN_FIT_ROWS, "the fit")
