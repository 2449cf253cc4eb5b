"""The Volterra benchmark's library: data streams, tasks, the oracle, argument checks."""

from __future__ import annotations

import numpy as np
import pytest

from mcpilco.experiments.identification import volterra as bench
from mcpilco.models.volterra import fit_percent, lag_matrix, spinelli_system, wiener_system

pytestmark = pytest.mark.usefixtures("one_torch_thread")  # tiny GP fits


def test_data_generation_is_reproducible_and_consistent():
    a = bench.exp1_data(3, 1.0, 4.0, 50, 40, 4.0, config_index=1)
    b = bench.exp1_data(3, 1.0, 4.0, 50, 40, 4.0, config_index=1)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
    # noiseless test output is the system (6.36) applied to the test input; train std as asked
    np.testing.assert_allclose(a["z_test"], spinelli_system(a["u_test"]))
    assert a["u_test"].std() == pytest.approx(4.0, rel=0.3)
    # the noise is a separate stream: not a function of the input (residual of the exact
    # degree-3 least-squares fit keeps the noise variance 16)
    e = a["y_train"] - spinelli_system(a["u_train"])
    assert abs(np.corrcoef(e, a["u_train"])[0, 1]) < 0.5
    big = bench.exp1_data(0, 1.0, 4.0, 400, 10, 4.0, config_index=0)
    e = big["y_train"] - spinelli_system(big["u_train"])
    assert np.abs(e - 4.0 * big["u_train"]).max() > 1.0
    assert abs(np.corrcoef(e, big["u_train"])[0, 1]) < 0.2
    # SNR definition: 10 log10(var(z_train) / sigma_n^2)
    d = bench.exp2_data(0, 3, 20.0, 300, 50, 1.0, config_index=0)
    z_train = wiener_system(d["u_train"], 3)
    assert 10 * np.log10(z_train.var() / d["noise_std"] ** 2) == pytest.approx(20.0)
    np.testing.assert_allclose(d["z_test"], wiener_system(d["u_test"], 3))
    assert lag_matrix(d["u_train"], 70).shape == (300, 71)


def test_quick_mode_and_argument_validation(tmp_path):
    with pytest.raises(ValueError, match="experiments"):
        bench.run_benchmark(experiments=(3,), out_dir=tmp_path, progress=False)
    with pytest.raises(ValueError, match="runs"):
        bench.run_benchmark(runs=0, experiments=(1,), out_dir=tmp_path, progress=False)
    assert bench.QUICK["experiments"] == (1,)


def test_run_task_runs_each_kind_only_for_its_orders():
    """EXP2["kind_orders"] restricts MPK to r = 2, 3 (thesis figure 6.3); SED-MPK runs always."""
    tiny = {"n_train": 40, "n_test": 30, "ml_points": None, "adam_iters": 1, "lbfgs_iters": 0}
    exp2 = {**bench.EXP2, **tiny}
    assert exp2["kind_orders"] == {"mpk": [2, 3]} and "sed_mpk_tied" in exp2["kinds"]
    fits = {}
    for r in (2, 4):
        task = bench.Task(
            2, bench.config_name(r, 20.0), 0, 0, {"order": r, "snr_db": 20.0, "config_index": 0}
        )
        fits[r] = bench.run_task(task, bench.EXP1, exp2)["fit"]
    assert set(fits[2]) == {"mpk", "sed_mpk_tied"}
    assert set(fits[4]) == {"sed_mpk_tied"}
    assert all(np.isfinite(v) for f in fits.values() for v in f.values())


def test_oracle_recovers_the_system_from_noiseless_data_and_is_least_squares_with_noise():
    """Noiseless targets: the 14 true monomials fit exactly, so the test Fit is 100 %. With
    noise: the residual of the oracle's coefficients is orthogonal to the monomials (normal
    equations), and its Fit drops below 100."""
    from mcpilco.models.volterra import spinelli_monomials

    d = bench.exp1_data(1, 1.0, 4.0, 200, 100, 4.0, config_index=1)
    exact = {**d, "y_train": spinelli_system(d["u_train"])}
    assert fit_percent(d["z_test"], bench.oracle_prediction(exact)) == pytest.approx(100.0)
    phi = spinelli_monomials(d["u_train"])
    coef, *_ = np.linalg.lstsq(phi, d["y_train"], rcond=None)
    np.testing.assert_allclose(phi.T @ (d["y_train"] - phi @ coef), 0.0, atol=1e-8)
    np.testing.assert_allclose(bench.oracle_prediction(d), spinelli_monomials(d["u_test"]) @ coef)
    assert fit_percent(d["z_test"], bench.oracle_prediction(d)) < 99.9
