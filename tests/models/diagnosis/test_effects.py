"""Effect library: parsing, labels, specs, sign flags."""

import numpy as np
import pytest

from mcpilco.models.diagnosis import (
    Cogging,
    CoulombFriction,
    Delay,
    Payload,
    default_library,
    parse_effect,
)
from mcpilco.models.diagnosis.effects import FeatureContext, effect_from_spec


def test_parse_and_labels():
    assert parse_effect("coulomb:2") == CoulombFriction(joint=2)
    assert parse_effect("payload") == Payload()
    assert parse_effect("cogging:3:8") == Cogging(joint=3, order=8)
    assert parse_effect("delay:1:4") == Delay(joint=1, samples=4)
    assert CoulombFriction(joint=2).label == "coulomb:2"
    e = Cogging(joint=1, order=5)
    assert effect_from_spec(e.spec()) == e


@pytest.mark.parametrize(
    "text, match",
    [
        ("friction:2", "unknown effect 'friction'"),
        ("coulomb", "give the joint"),
        ("coulomb:x", "integer"),
    ],
)
def test_parse_errors_are_clear(text, match):
    with pytest.raises(ValueError, match=match):
        parse_effect(text)


def test_joint_checks():
    with pytest.raises(ValueError, match="1-based"):
        CoulombFriction(joint=0)
    with pytest.raises(ValueError, match="model has 4"):
        CoulombFriction(joint=5).outputs(4)


def test_library_and_sign_flag():
    lib = default_library(3, with_payload=False)
    assert len(lib) == 9 * 3 and not any(isinstance(e, Payload) for e in lib)
    ctx = FeatureContext(
        q=np.zeros((5, 2)),
        qd=np.zeros((5, 2)),
        qdd=np.zeros((5, 2)),
        base=np.zeros((5, 2)),
        joint_types="RP",
    )
    (est,) = CoulombFriction(joint=2, eps=0.01).estimates(
        np.array([-1.0]), np.eye(1) * 0.01, ctx, 1
    )
    assert est.wrong_sign and est.unit == "N"
    (ok,) = CoulombFriction(joint=1, eps=0.01).estimates(np.array([-0.1]), np.eye(1), ctx, 0)
    assert not ok.wrong_sign and ok.unit == "N·m"
