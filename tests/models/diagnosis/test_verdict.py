"""Verdict semantics: a missing effect against a refinement inside a learned start's span."""

from mcpilco.models.diagnosis import (
    CoulombFriction,
    GIPStart,
    Payload,
    RBFStart,
    ViscousFriction,
)
from mcpilco.models.diagnosis.search import Candidate, Diagnosis


def _cand(effect, delta, significant, in_span, held=-3.0):
    return Candidate(
        effect=effect,
        delta=delta,
        best_delta=delta,
        n_variants=1,
        estimates=[],
        outputs=[1],
        heldout_delta_pct=held,
        significant=significant,
        in_start_span=in_span,
    )


def _diag(cands):
    return Diagnosis("v0", cands, threshold=5.0, min_heldout_gain=1.0, indistinct_nats=2.0)


def test_in_span_refinement_is_not_the_missing_effect():
    pay = _cand(Payload(), 11.0, True, True)
    weak = _cand(ViscousFriction(joint=2), 1.0, False, False)
    d = _diag([pay, weak])
    assert d.best is None and d.refinement is pay and d.lead is pay
    text = d.verdict()
    assert "no significant missing effect" in text and "in the start model's span" in text
    assert "in start span" in d.table() and "SIGNIFICANT" not in d.table()
    assert d.to_dict()["candidates"][0]["in_start_span"] is True


def test_missing_effect_leads_before_a_refinement():
    pay = _cand(Payload(), 30.0, True, True)
    coul = _cand(CoulombFriction(joint=1, eps=0.01), 12.0, True, False)
    d = _diag([pay, coul])
    assert d.best is coul and d.lead is coul and d.refinement is pay
    assert d.verdict().startswith(f"v0: missing effect: {coul.effect.title} on joint 1")


def test_only_a_gip_start_spans_effects():
    assert GIPStart("RRPR").spans(Payload())
    assert not GIPStart("RRPR").spans(ViscousFriction(joint=1))
    assert not RBFStart("RRPR").spans(Payload())  # no finite feature space to span
