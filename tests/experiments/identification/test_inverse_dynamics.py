"""The inverse-dynamics benchmark's data: perturbed kinematics and sinusoid references."""

from __future__ import annotations

import numpy as np

from mcpilco.experiments.identification import inverse_dynamics as bench


def test_perturbation_stays_in_the_thesis_ranges() -> None:
    rng = np.random.default_rng(0)
    nominal = bench.scara_with_tool()
    real = bench.perturb_kinematics(nominal, rng)
    for a, b in zip(nominal.joints, real.joints, strict=True):
        assert abs(a.a - b.a) <= 0.05 and abs(a.d - b.d) <= 0.05
        assert abs(a.alpha - b.alpha) <= np.radians(5) + 1e-12
        assert abs(a.theta - b.theta) <= np.radians(5) + 1e-12
        assert b.range is None
    ref = bench.sinusoid_reference(nominal, rng, n_sinusoids=200)
    assert ref.omegas.shape == (4, 200) and np.abs(ref.omegas).max() <= 2.0
