"""The loop on data with hidden effects
(:mod:`mcpilco.experiments.diagnosis.hidden_effects`, SCARA).

Single random effects (seeded: random key, joint, magnitude): the true effect on the true
joint is the verdict, and adding it brings the held-out RMSE of the affected joints within
1.5x the true noise std. The control case reports no significant effect. Statistics over
many cases: ``mcpilco-bench-diagnosis``.
"""

import numpy as np
import pytest

from mcpilco.experiments.diagnosis.hidden_effects import make_case
from mcpilco.models.diagnosis import (
    CoulombFriction,
    DiagnosisModel,
    GIPStart,
    NominalStart,
    add_effect,
    as_trajectories,
    auto_improve,
    diagnose,
    heldout_rmse,
)

DURATION = 12.0


def _affected(case) -> list[int]:
    out = set()
    for e in case.effects:
        if e["joint"] is None:
            out |= {j for j, s in enumerate(e["size_over_noise"]) if s >= 1.0}
        else:
            out.add(e["joint"] - 1)
    return sorted(out)


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_single_random_effect_ranks_first_and_error_falls(seed):
    case = make_case("scara", None, n_effects=1, seed=seed, duration=DURATION)
    test = as_trajectories(case.datasets("test"))
    model = DiagnosisModel(NominalStart(case.nominal_xml)).fit(case.datasets("train"))
    d = diagnose(model, test)
    assert d.best is not None, d.table()
    assert d.best.label == case.truth()[0], d.table()
    new = add_effect(model, d.best.effect)
    rmse = heldout_rmse(new, test)
    j = _affected(case)
    assert np.all(rmse[j] <= 1.5 * case.noise_std[j]), (rmse / case.noise_std, case.effects)


def test_control_case_reports_no_significant_effect():
    case = make_case("scara", [], seed=11, duration=DURATION)
    model = DiagnosisModel(NominalStart(case.nominal_xml)).fit(case.datasets("train"))
    d = diagnose(model, case.datasets("test"))
    assert d.best is None
    assert "no significant missing effect" in d.verdict()


def test_python_add_api_versions_and_parameter():
    case = make_case("scara", ["coulomb:2"], seed=5, duration=DURATION)
    v0 = DiagnosisModel(NominalStart(case.nominal_xml)).fit(case.datasets("train"))
    v1 = add_effect(v0, CoulombFriction(joint=2))
    assert (v0.version, v1.version) == (0, 1) and v0.effects == ()
    (p,) = v1.parameters()
    true_fc = case.effects[0]["parameter"]
    assert abs(p["value"] - true_fc) < 0.1 * true_fc and p["unit"] == "N·m"


@pytest.mark.slow
def test_two_effects_at_once_nominal_start():
    case = make_case("scara", ["viscous:1", "cogging:3"], seed=6, duration=DURATION)
    test = as_trajectories(case.datasets("test"))
    model = DiagnosisModel(NominalStart(case.nominal_xml)).fit(case.datasets("train"))
    versions, diags = auto_improve(model, test)
    added = {e.label for e in versions[-1].effects}
    assert set(case.truth()) <= added, [d.verdict() for d in diags]
    rmse = heldout_rmse(versions[-1], test)
    assert np.all(rmse[[0, 2]] <= 1.5 * case.noise_std[[0, 2]])


@pytest.mark.slow
def test_gip_start_finds_coulomb_and_error_falls():
    case = make_case("scara", ["coulomb:2"], seed=2, duration=20.0)
    test = as_trajectories(case.datasets("test"))
    start = GIPStart(case.joint_types, adam_iters=40, lbfgs_iters=15)
    model = DiagnosisModel(start, max_points=300).fit(case.datasets("train"))
    versions, diags = auto_improve(model, test, max_steps=3)
    assert versions[1].effects[0].label == "coulomb:2"
    rmse = heldout_rmse(versions[-1], test)
    assert rmse[1] <= 1.5 * case.noise_std[1]
