"""Waypoints of the marker-camera UR10 (:mod:`mcpilco.experiments.kinematics.trajectories`)."""

import numpy as np
import pytest

from mcpilco.experiments.kinematics.trajectories import UR10_HOME, ur10_waypoints


def test_waypoint_rejection_sampling_keeps_accepted_draws_and_gives_up_clearly():
    rng = np.random.default_rng(0)
    wp = ur10_waypoints(rng, 1.0, count=5, accept=lambda q: q[0] > 0.0)
    assert wp.shape == (5, 6) and (wp[:, 0] > 0).all()
    assert np.abs(wp - UR10_HOME).max() <= 1.0
    with pytest.raises(ValueError, match="waypoints accepted"):
        ur10_waypoints(rng, 1.0, count=2, accept=lambda q: False, max_draws=50)
