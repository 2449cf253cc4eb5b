"""Nominal arms of :mod:`mcpilco.envs.arms` as the rigid-body model of a collision detector."""

from __future__ import annotations

import dataclasses

from mcpilco.envs import arms
from mcpilco.envs.arm_builder import arm_to_xml
from mcpilco.models.collision import InputError

# The nominal arms a detector can be trained with when no robot file is given.
NOMINAL_ARMS = {"ur10": arms.ur10, "scara": arms.scara}


def nominal_model(robot: str = "ur10") -> str:
    """MJCF text of a nominal arm of :mod:`mcpilco.envs.arms` for the rigid-body features
    (no joint limits, no friction: the estimators learn the friction)."""
    if robot not in NOMINAL_ARMS:
        raise InputError(f"--robot must be one of {sorted(NOMINAL_ARMS)}, got {robot!r}")
    arm = NOMINAL_ARMS[robot]()
    joints = tuple(dataclasses.replace(j, range=None) for j in arm.joints)
    return arm_to_xml(dataclasses.replace(arm, joints=joints).without_friction())
