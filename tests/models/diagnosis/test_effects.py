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
    lib = default_library(3, rigid_body=False)
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


# ------------------------------------------------------------------ GIP span (independent)
def _gip_features(jt: str, q, qd, qdd):
    """Explicit GIP function space (thesis eq. 3.8/3.11), written out monomial by monomial:
    per revolute joint the monomials of degree <= 2 in (cos q, sin q), per prismatic joint
    1, q, q^2, their products over joints, times [1, qdd_i, qd_i qd_j (i <= j)]."""
    n = len(jt)
    pos = np.ones((q.shape[0], 1))
    for b, t in enumerate(jt):
        if t == "R":
            c, s = np.cos(q[:, b]), np.sin(q[:, b])
            mono = np.stack([np.ones_like(c), c, s, c * c, c * s, s * s], axis=1)
        else:
            mono = np.stack([np.ones_like(q[:, b]), q[:, b], q[:, b] ** 2], axis=1)
        pos = (pos[:, :, None] * mono[:, None, :]).reshape(q.shape[0], -1)
    vel = [np.ones(q.shape[0])] + [qdd[:, i] for i in range(n)]
    vel += [qd[:, i] * qd[:, j] for i in range(n) for j in range(i, n)]
    vel = np.stack(vel, axis=1)
    return (pos[:, :, None] * vel[:, None, :]).reshape(q.shape[0], -1)


def _in_span(cols, feats) -> bool:
    coef, *_ = np.linalg.lstsq(feats, cols, rcond=None)
    return bool(np.linalg.norm(cols - feats @ coef) <= 1e-8 * np.linalg.norm(cols))


_TWO_LINK = """<mujoco model="two_link">
  <option gravity="0 0 -9.81"/>
  <worldbody>
    <body name="l1">
      <joint name="j1" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0.4 0 0" size="0.03" mass="1.2"/>
      <body name="l2" pos="0.4 0 0">
        <joint name="j2" type="slide" axis="1 0 0"/>
        <geom type="box" size="0.1 0.02 0.03" pos="0.1 0.01 0" mass="0.7"/>
      </body>
    </body>
  </worldbody>
</mujoco>"""


def test_in_gip_span_matches_the_explicit_gip_feature_space():
    """Each effect's claim agrees with a least-squares fit on the written-out GIP features
    (216 monomials, 1500 random states), for a revolute and a prismatic joint."""
    from mcpilco.models.diagnosis import (
        Armature,
        Spring,
        StribeckFriction,
        TorqueOffset,
        ViscousFriction,
    )
    from mcpilco.models.diagnosis.start_models import _Robot

    rng = np.random.default_rng(0)
    jt = "RP"
    q, qd, qdd = (rng.uniform(-2, 2, (1500, 2)) for _ in range(3))
    robot = _Robot(_TWO_LINK)
    assert robot.joint_types == jt
    ctx = FeatureContext(
        q=q,
        qd=qd,
        qdd=qdd,
        base=np.zeros_like(q),
        joint_types=jt,
        regressor=lambda: robot.regressor(q, qd, qdd),
        rigid=robot.rigid_body(),
    )
    feats = _gip_features(jt, q, qd, qdd)
    effects = [
        TorqueOffset(joint=1),
        Armature(joint=1),
        Armature(joint=2),
        Spring(joint=1),
        Spring(joint=2),
        Cogging(joint=1, order=2),
        Cogging(joint=1, order=3),
        ViscousFriction(joint=2),
        CoulombFriction(joint=1, eps=0.01),
        StribeckFriction(joint=1),
        Payload(),
    ]
    for e in effects:
        e = e.variants()[0].calibrate(ctx)
        for out in e.outputs(2):
            cols = e.columns(ctx, out)
            assert _in_span(cols, feats) == e.in_gip_span(jt), (e.label, out)
    assert Payload().in_gip_span(jt) and not Spring(joint=1).in_gip_span(jt)
