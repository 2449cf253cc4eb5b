"""Add a named effect to a diagnosis model: the next version, with its shape values scanned.

``add_effect(model, CoulombFriction(joint=2))`` is the loop's step 4 for an effect a user
names. An effect with unscanned shape values (Coulomb smoothing ``eps``, cogging order, delay,
...) is first scored over its scan variants against ``model`` by
:func:`~mcpilco.models.diagnosis.search.score_effect`, which keeps the variant of largest
log-evidence and refines its continuous shape values
(:func:`~mcpilco.models.diagnosis.search.refine_shape`); the complete effect is then added by
:meth:`~mcpilco.models.diagnosis.model.DiagnosisModel.with_effect` and refitted, a learned start
model backfitted once. The function sits above both modules (it needs the model and the
search), so that the model never imports the search.
"""

from __future__ import annotations

from mcpilco.models.diagnosis.effects import Effect
from mcpilco.models.diagnosis.model import DiagnosisModel
from mcpilco.models.diagnosis.search import score_effect


def add_effect(model: DiagnosisModel, effect: Effect) -> DiagnosisModel:
    """The next version of ``model`` with ``effect`` added and refitted (module docstring).

    Args:
        model: a diagnosis model; fitted when ``effect`` has unscanned shape values.
        effect: the effect to add, e.g. ``CoulombFriction(joint=2)``.

    Raises:
        ValueError: ``effect`` acts on a joint the model does not have, or is already in it.
        RuntimeError: shape values to scan and ``model`` not fitted.
    """
    effect.outputs(model.n_joints)  # a joint outside the model: ValueError naming it
    if not effect.is_complete():
        effect = score_effect(model, effect, refine=True).effect
    return model.with_effect(effect, backfit=True)
