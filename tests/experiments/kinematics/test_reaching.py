"""MC-PILCO reaching on the marker camera against the gradient controller, at tiny sizes
(:mod:`mcpilco.experiments.kinematics.reaching`)."""

import numpy as np

from mcpilco.agents.mc_pilco.optimize import PolicyOptConfig
from mcpilco.agents.mc_pilco.reaching import ReachingConfig
from mcpilco.experiments.kinematics.parts import (
    controller_part,
    reaching_problem,
    true_structure,
    ur10_datasets,
)
from mcpilco.experiments.kinematics.reaching import (
    mcpilco_reaching_part,
    reaching_markdown,
    summarise_reaching,
)
from mcpilco.experiments.results import read_result


def test_both_agents_get_the_same_targets_and_mcpilco_learns_from_its_trials():
    data = ur10_datasets(0, 96)
    structure = true_structure(data["env"])
    problem = reaching_problem(data, structure, 30, "random", 0)
    ctrl = controller_part(data, structure, 30, 1, 0, False, steps=5, starts=1, hold=1,
                           fk_model="chain")  # fmt: skip
    np.testing.assert_array_equal(ctrl["targets"], problem["targets"])
    opt = PolicyOptConfig(max_steps=3, min_steps=0, cuda_graph=False)
    cfg = ReachingConfig(horizon=4, particles=2, num_basis=5, opt=opt)
    res = mcpilco_reaching_part(data, structure, 30, 1, 0, cfg, hold=1)
    np.testing.assert_array_equal(res["targets"], problem["targets"])
    r0, r1 = res["rounds"]
    assert r0["n_data"] == 30 and r1["n_data"] > 30  # the trials' frames joined the data
    assert len(r0["position_error_norm_true"]) == 5
    assert np.isfinite(r0["orientation_error_true"]).all()
    summary = summarise_reaching([dict(mcpilco=res, controller=ctrl)])
    assert summary["mcpilco"][1]["targets"] == 5
    assert "gradient controller" in reaching_markdown(dict(summary=summary))


def _rows(errors):
    """Seed rows whose trials reached the given (position, angle) errors, 5 targets each."""
    return {
        "rounds": [
            {"position_error_norm_true": [p] * 5, "orientation_error_true": [a] * 5}
            for p, a in errors
        ]
    }


def fake_seed(seed, **_):
    """A seed's rows with trial errors known in advance: the study only pools them."""
    mc = _rows([(0.1, 0.5), (0.002 * (seed + 1), 0.01)])
    ctrl = _rows([(0.02, 0.1), (0.009, 0.06)])
    return dict(seed=seed, identification_correct=seed != 2, mcpilco=mc, controller=ctrl)


def test_study_pools_seeds_and_targets_and_writes_its_report(tmp_path, monkeypatch):

    from mcpilco.experiments.infra.sweep import SweepRunner
    from mcpilco.experiments.kinematics import reaching as reaching_bench

    monkeypatch.setattr(reaching_bench, "reaching_seed", fake_seed)
    study = reaching_bench.reaching_study(
        [0, 1, 2], tmp_path, "cmd", SweepRunner(progress=False), tmp_path / "runs"
    )
    mc, ctrl = study["summary"]["mcpilco"], study["summary"]["controller"]
    assert [t["targets"] for t in mc] == [15, 15]
    assert mc[1]["position_median"] == 0.004  # seeds 0, 1, 2: 2, 4, 6 mm
    assert mc[1]["reached"] == 15 and mc[0]["reached"] == 0
    assert ctrl[1]["reached"] == 0  # 9 mm but 0.06 rad: outside 0.05 rad
    assert study["identification_correct"] == 2
    saved = read_result(tmp_path / "kinematics_reaching.json").payload()
    assert saved["summary"] == study["summary"]
    assert "| 2 | MC-PILCO" in (tmp_path / "kinematics_reaching.md").read_text()
    assert (tmp_path / "kinematics_reaching.png").stat().st_size > 0
