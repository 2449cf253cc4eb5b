"""MC-PILCO reaching on the marker camera against the gradient controller, at tiny sizes
(:mod:`mcpilco.experiments.reaching_bench`)."""

import numpy as np

from mcpilco.agents.mc_pilco.optimize import PolicyOptConfig
from mcpilco.agents.mc_pilco.reaching import ReachingConfig
from mcpilco.experiments.kinematics_parts import (
    controller_part,
    reaching_problem,
    true_structure,
    ur10_datasets,
)
from mcpilco.experiments.reaching_bench import (
    mcpilco_reaching_part,
    reaching_markdown,
    summarise_reaching,
)


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
