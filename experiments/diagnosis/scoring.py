"""Scoring of the diagnosis benchmark: a simulated case's truth against the loop's answer.

A case's truth is a list of hidden effects (:class:`mcpilco.envs.robot_logs.HiddenEffect` as
dicts: ``kind``, ``joint``, ``value``, ``ref``). The diagnosis names candidates
(:mod:`mcpilco.models.diagnosis.effects`) as ``(key, joint)`` pairs, ``joint = None`` for a
candidate acting on every joint (the payload). Which candidates count as the correct name of
a hidden effect is the table :data:`CORRECT_CANDIDATES`; which fitted parameter is
comparable with the effect's value is :data:`PARAMETER_TRUTH`. Both are plain tables: a new
candidate (an inertial effect per link, a current-log effect) is scored by adding a row.

Scores of one case (:func:`score_case`):

* **rank** of each hidden effect: the first position (1-based) of a correct candidate in the
  first diagnosis's ranking (significant candidates first, then by evidence); **top-k**: every
  hidden effect of the library ranked within ``k + m - 1`` for ``m`` such effects (the usual
  top-k for one effect). Effects outside the library (:data:`CORRECT_CANDIDATES` row empty)
  have no correct name and no rank.
* **named**: the missing effect of the first verdict (``Diagnosis.best``) is a correct name
  of a hidden effect.
* **found** / **spurious**: the effects the loop added to the model (until none was
  significant), each matched to the truth; an added effect that matches no hidden effect is
  spurious. On a control case (no hidden effect) a named or added effect is a **false alarm**.
* **parameters**: for each hidden effect whose correct candidate was added and has a
  comparable parameter, the estimate (95% interval) against the true value: relative error
  and whether the truth lies in the interval. A candidate on every joint (the payload) is
  estimated on each output joint; the estimate with the largest ``|value| / ci95`` is taken
  (on a joint its columns barely move, the estimate is the prior's, near 0).
* **verdict**: the final verdict's category (:func:`verdict_category`) against the expected
  one: ``"unexplained"`` when a hidden effect lies outside the library, else ``"at floor"``
  ("no significant missing effect", which the loop only says at the noise floor).
  ``missed_at_floor``: the verdict says "no significant missing effect" although a hidden
  effect of the library is not in the final model.
* **below noise**: a case whose hidden effects' torque stays under :data:`VISIBLE_SIZE`
  torque-noise stds on every joint (the generator could not make it larger, e.g. a heavier
  link of an arm that barely moves it) scores no rank, name or find; its correct verdict is
  "at floor".

:func:`summarise` aggregates the scores over cases; :func:`markdown` and
:func:`plot_confusion` (truth kind against the named candidate key) write the report.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from mcpilco.models.diagnosis.search import FLOOR_FACTOR

__all__ = [
    "CORRECT_CANDIDATES",
    "PARAMETER_TRUTH",
    "CandidateMatch",
    "ParameterTruth",
    "VISIBLE_SIZE",
    "expected_verdict",
    "in_library",
    "markdown",
    "matches",
    "plot_confusion",
    "score_case",
    "summarise",
    "verdict_category",
]


VISIBLE_SIZE = 1.0
"""Smallest rms torque of a case's hidden effects, in torque-noise stds on some joint, that
is scored as a detectable effect (an effect below it is no error of the loop to miss)."""


class CandidateMatch(NamedTuple):
    """A candidate key that names a hidden effect, and where it must act.

    ``where``: ``"joint"`` (the candidate's joint is the effect's joint; for ``mass`` the
    link number), ``"arm"`` (a candidate on every joint, ``joint = None``), ``"last_link"``
    (a candidate on every joint, correct only when the effect's link is the last one).
    """

    key: str
    where: str


CORRECT_CANDIDATES: dict[str, tuple[CandidateMatch, ...]] = {
    "damping": (CandidateMatch("viscous", "joint"),),
    "frictionloss": (CandidateMatch("coulomb", "joint"), CandidateMatch("stribeck", "joint")),
    "armature": (CandidateMatch("armature", "joint"),),
    "stiffness": (CandidateMatch("spring", "joint"),),
    "mass": (CandidateMatch("payload", "last_link"), CandidateMatch("link_inertia", "joint")),
    "payload": (CandidateMatch("payload", "arm"),),
    "cogging": (CandidateMatch("cogging", "joint"),),
    "position_friction": (),
}
"""Hidden-effect kind -> the candidates that name it correctly; an empty row: outside the
library (the correct answer is an "unexplained" verdict). ``mass`` (a heavier link ``k``) is
the payload's 10 inertial parameters only on the last link; ``link_inertia`` is the key of a
per-link inertial candidate."""


class ParameterTruth(NamedTuple):
    """A fitted parameter (``name`` of candidate ``key``) comparable with a hidden effect,
    and the true value as a function of the effect's dict."""

    key: str
    name: str
    value: Callable[[Mapping[str, Any]], float]


def _value(e: Mapping[str, Any]) -> float:
    return float(e["value"])


def _added_link_mass(e: Mapping[str, Any]) -> float:
    return (float(e["value"]) - 1.0) * float(e["nominal_link_mass"])


PARAMETER_TRUTH: dict[str, tuple[ParameterTruth, ...]] = {
    "damping": (ParameterTruth("viscous", "F_v", _value),),
    "frictionloss": (
        ParameterTruth("coulomb", "F_c", _value),
        ParameterTruth("stribeck", "F_c", _value),
    ),
    "armature": (ParameterTruth("armature", "I_a", _value),),
    "stiffness": (ParameterTruth("spring", "k", _value),),
    "mass": (ParameterTruth("payload", "m", _added_link_mass),),
    "payload": (ParameterTruth("payload", "m", _value),),
    "cogging": (ParameterTruth("cogging", "A", _value),),
}
"""Hidden-effect kind -> comparable parameters: damping ``b`` = ``F_v``, frictionloss level =
Coulomb ``F_c``, armature = ``I_a``, stiffness = spring ``k``, payload mass = ``m``, a last
link ``f`` times heavier = a payload of ``(f - 1) m_link``, cogging amplitude = ``A``."""


def in_library(effect: Mapping[str, Any]) -> bool:
    """Whether some candidate names ``effect`` (its :data:`CORRECT_CANDIDATES` row is not
    empty)."""
    kind = effect["kind"]
    if kind not in CORRECT_CANDIDATES:
        raise ValueError(f"effect kind {kind!r} has no row in CORRECT_CANDIDATES")
    return bool(CORRECT_CANDIDATES[kind])


def matches(effect: Mapping[str, Any], n_joints: int, key: str, joint: int | None) -> bool:
    """Whether candidate ``(key, joint)`` is a correct name of ``effect`` on an arm of
    ``n_joints`` joints (:data:`CORRECT_CANDIDATES`)."""
    in_library(effect)
    for m in CORRECT_CANDIDATES[effect["kind"]]:
        if m.key != key:
            continue
        if m.where == "joint" and joint == effect["joint"]:
            return True
        if m.where == "arm" and joint is None:
            return True
        if m.where == "last_link" and joint is None and effect["joint"] == n_joints:
            return True
    return False


def expected_verdict(effects: Sequence[Mapping[str, Any]]) -> str:
    """``"unexplained"`` when a hidden effect lies outside the library, else ``"at floor"``."""
    return "at floor" if all(in_library(e) for e in effects) else "unexplained"


def verdict_category(text: str) -> str:
    """The category of a verdict (:meth:`~mcpilco.models.diagnosis.Diagnosis.verdict`,
    ``"<model>: <verdict>"``): ``"at floor"`` ("no significant missing effect"),
    ``"unexplained"``, ``"not enough data"``, or ``"effect named"`` (a missing effect or a
    better form of one: the loop stopped before the floor)."""
    body = text.split(": ", 1)[1] if ": " in text else text
    for prefix, category in (
        ("no significant missing effect", "at floor"),
        ("unexplained", "unexplained"),
        ("not enough data", "not enough data"),
    ):
        if body.startswith(prefix):
            return category
    return "effect named"


def _label(key: str, joint: int | None) -> str:
    return key if joint is None else f"{key}:{joint}"


def _pairs(items: Sequence[Sequence[Any]]) -> list[tuple[str, int | None]]:
    return [(str(k), None if j is None else int(j)) for k, j in items]


def score_case(
    effects: Sequence[Mapping[str, Any]],
    n_joints: int,
    ranking: Sequence[Sequence[Any]],
    named: Sequence[Any] | None,
    added: Sequence[Sequence[Any]],
    verdict: str,
    parameters: Sequence[Mapping[str, Any]] = (),
    size_over_noise: Sequence[float] | None = None,
) -> dict[str, Any]:
    """Score one case (module docstring).

    Args:
        effects: the hidden effects (dicts with ``kind``, ``joint``, ``value``; ``mass`` also
            ``nominal_link_mass``).
        n_joints: the arm's joint count.
        ranking: ``(key, joint)`` of the first diagnosis's candidates, best first.
        named: ``(key, joint)`` of the first verdict's missing effect, or None.
        added: ``(key, joint)`` of the effects in the final model.
        verdict: the final verdict's text.
        parameters: the final model's estimates, dicts with ``key``, ``joint``, ``name``,
            ``value``, ``ci95``.
        size_over_noise: per joint, the rms torque of the hidden effects over the torque
            noise; below :data:`VISIBLE_SIZE` on every joint the case is ``below_noise``: no
            rank, name or find is scored, and the expected verdict is "at floor".

    Returns:
        ``ranks``, ``top1``, ``top3`` (None without a hidden effect of the library),
        ``named_correct`` (None likewise), ``found``, ``all_found``, ``spurious``,
        ``false_alarm`` (None unless a control), ``parameters``, ``verdict_category``,
        ``expected_verdict``, ``verdict_correct``, ``missed_at_floor``, ``below_noise``.
    """
    ranking_p = _pairs(ranking)
    added_p = _pairs(added)
    below = bool(effects) and size_over_noise is not None and max(size_over_noise) < VISIBLE_SIZE
    lib = [] if below else [e for e in effects if in_library(e)]
    ranks: list[int | None] = []
    for e in lib:
        pos = [i + 1 for i, (k, j) in enumerate(ranking_p) if matches(e, n_joints, k, j)]
        ranks.append(pos[0] if pos else None)
    extra = len(lib) - 1

    def top(k: int) -> bool | None:
        if not lib:
            return None
        return all(r is not None and r <= k + extra for r in ranks)

    named_p = None if named is None else _pairs([named])[0]
    named_correct = None
    if lib:
        named_correct = named_p is not None and any(matches(e, n_joints, *named_p) for e in lib)
    found = [any(matches(e, n_joints, k, j) for k, j in added_p) for e in lib]
    spurious = [
        _label(k, j) for k, j in added_p if not any(matches(e, n_joints, k, j) for e in lib)
    ]
    params = []
    for e in lib:
        for pt in PARAMETER_TRUTH.get(e["kind"], ()):
            rows = [
                p
                for p in parameters
                if p["key"] == pt.key
                and p["name"] == pt.name
                and matches(e, n_joints, p["key"], p["joint"])
            ]
            if not rows:
                continue
            # an effect on every joint has one estimate per output: take the best determined
            best = max(rows, key=lambda p: abs(float(p["value"])) / max(float(p["ci95"]), 1e-300))
            true = pt.value(e)
            est, ci = float(best["value"]), float(best["ci95"])
            params.append(
                {
                    "effect": _label(e["kind"], e["joint"]),
                    "parameter": f"{_label(pt.key, best['joint'])} {pt.name}",
                    "true": true,
                    "estimate": est,
                    "ci95": ci,
                    "relative_error": abs(est - true) / abs(true) if true else math.inf,
                    "within_ci": abs(est - true) <= ci,
                }
            )
    category = verdict_category(verdict)
    expected = "at floor" if below else expected_verdict(effects)
    return {
        "ranks": ranks,
        "top1": top(1),
        "top3": top(3),
        "named_correct": named_correct,
        "found": found,
        "all_found": all(found) if lib else None,
        "spurious": spurious,
        "false_alarm": (named_p is not None or bool(added_p)) if not effects else None,
        "parameters": params,
        "verdict_category": category,
        "expected_verdict": expected,
        "verdict_correct": category == expected,
        "missed_at_floor": (category == "at floor" and not all(found)) if lib else None,
        "below_noise": below,
    }


# ----------------------------------------------------------------------------- summary
def _rate(flags: Sequence[Any]) -> float | None:
    vals = [bool(f) for f in flags if f is not None]
    return float(np.mean(vals)) if vals else None


def _count(flags: Sequence[Any]) -> str:
    vals = [bool(f) for f in flags if f is not None]
    return f"{sum(vals)}/{len(vals)}"


def summarise(records: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Aggregate scored records (each with ``role``, ``effects``, ``score``,
    ``ratio_before``, ``ratio_after``, ``seconds``).

    Roles: ``control`` (no effect), ``single`` (one effect of the library), ``multi``
    (several), ``off_library`` (an effect outside the library). Rates are over the cases
    where they apply; ``*_counts`` give them as ``hits/cases``. Cases whose effects are
    below the noise (``below_noise_cases``) count only for the verdict and spurious effects.
    """
    by_role: dict[str, list[Mapping[str, Any]]] = {}
    for r in records:
        by_role.setdefault(r["role"], []).append(r)
    single = by_role.get("single", [])
    multi = by_role.get("multi", [])
    ctl = by_role.get("control", [])
    off = by_role.get("off_library", [])
    below = [r for r in records if r["score"]["below_noise"]]
    single = [r for r in single if not r["score"]["below_noise"]]
    multi = [r for r in multi if not r["score"]["below_noise"]]
    lib_cases = single + multi
    top1_by_kind: dict[str, list[bool]] = {}
    for r in single:
        top1_by_kind.setdefault(r["effects"][0]["kind"], []).append(bool(r["score"]["top1"]))
    params = [p for r in records for p in r["score"]["parameters"]]
    by_param: dict[str, list[Mapping[str, Any]]] = {}
    for p in params:
        by_param.setdefault(p["parameter"].split(":")[0].split(" ")[0], []).append(p)
    after = np.array([max(r["ratio_after"]) for r in lib_cases]) if lib_cases else np.zeros(0)
    before = np.array([max(r["ratio_before"]) for r in lib_cases]) if lib_cases else np.zeros(0)
    cats: dict[str, int] = {}
    for r in records:
        c = r["score"]["verdict_category"]
        cats[c] = cats.get(c, 0) + 1
    return {
        "cases": {role: len(v) for role, v in sorted(by_role.items())},
        "below_noise_cases": [f"{r['seed']} {truth_text(r['effects'])}" for r in below],
        "top1": _rate([r["score"]["top1"] for r in single]),
        "top3": _rate([r["score"]["top3"] for r in single]),
        "top1_counts": _count([r["score"]["top1"] for r in single]),
        "top3_counts": _count([r["score"]["top3"] for r in single]),
        "top1_by_kind": {k: f"{sum(v)}/{len(v)}" for k, v in sorted(top1_by_kind.items())},
        "named_correct_counts": _count([r["score"]["named_correct"] for r in lib_cases]),
        "multi_top3_counts": _count([r["score"]["top3"] for r in multi]),
        "multi_all_found_counts": _count([r["score"]["all_found"] for r in multi]),
        "all_found_counts": _count([r["score"]["all_found"] for r in lib_cases]),
        "cases_with_spurious_effects": f"{sum(bool(r['score']['spurious']) for r in records)}"
        f"/{len(records)}",
        "false_alarm_rate": _rate([r["score"]["false_alarm"] for r in ctl]),
        "false_alarm_counts": _count([r["score"]["false_alarm"] for r in ctl]),
        "parameters_within_ci": _count([p["within_ci"] for p in params]),
        "parameter_median_relative_error": {
            k: float(np.median([p["relative_error"] for p in v]))
            for k, v in sorted(by_param.items())
        },
        "ratio_before_median": float(np.median(before)) if before.size else None,
        "ratio_after_median": float(np.median(after)) if after.size else None,
        "ratio_after_max": float(np.max(after)) if after.size else None,
        "at_floor_after_counts": f"{int(np.sum(after <= FLOOR_FACTOR))}/{after.size}",
        "verdict_correct": _rate([r["score"]["verdict_correct"] for r in records]),
        "verdict_correct_counts": _count([r["score"]["verdict_correct"] for r in records]),
        "verdict_correct_by_role": {
            role: _count([r["score"]["verdict_correct"] for r in v])
            for role, v in sorted(by_role.items())
        },
        "off_library_unexplained_counts": _count(
            [r["score"]["verdict_category"] == "unexplained" for r in off]
        ),
        "missed_at_floor_counts": _count([r["score"]["missed_at_floor"] for r in lib_cases]),
        "verdict_categories": dict(sorted(cats.items())),
        "seconds_per_case": float(np.mean([r["seconds"] for r in records])) if records else None,
        **_by_logs(records),
    }


def _by_logs(records: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Where the records say what their files log (``logs``: torque or current): the verdict
    rate of each with its 95 % Wilson interval, and the most seconds (wall, CPU) of a case."""
    from mcpilco.experiments.results import rate

    if not records or not all("logs" in r for r in records):
        return {}
    out: dict[str, Any] = {}
    for logs in sorted({r["logs"] for r in records}):
        flags = [bool(r["score"]["verdict_correct"]) for r in records if r["logs"] == logs]
        out[f"verdict_correct_{logs}_logs"] = rate(sum(flags), len(flags))
    flags = [bool(r["score"]["verdict_correct"]) for r in records]
    out["verdict_correct_rate"] = rate(sum(flags), len(flags))
    out["max_seconds_per_case"] = float(max(r["seconds"] for r in records))
    if all("cpu_seconds" in r for r in records):
        out["max_cpu_seconds_per_case"] = float(max(r["cpu_seconds"] for r in records))
    return out


# ----------------------------------------------------------------------------- report
def truth_text(effects: Sequence[Mapping[str, Any]]) -> str:
    """``"damping:2 = 0.31, mass:1 x1.40"``, or ``"none"``."""
    if not effects:
        return "none"
    parts = []
    for e in effects:
        label = "payload" if e["kind"] == "payload" else f"{e['kind']}:{e['joint']}"
        value = f"x{e['value']:.2f}" if e["kind"] == "mass" else f"= {e['value']:.3g}"
        parts.append(f"{label} {value}")
    return ", ".join(parts)


def markdown(
    records: Sequence[Mapping[str, Any]], summary: Mapping[str, Any], title: str, intro: str = ""
) -> str:
    """The report: the summary table, then one row per case, then the parameter table."""

    def cell(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.3g}"
        if isinstance(v, dict):
            return ", ".join(f"{k}: {cell(x)}" for k, x in v.items())
        return str(v)

    lines = [f"# {title}", ""]
    if intro:
        lines += [intro, ""]
    lines += ["| metric | value |", "|---|---|"]
    lines += [f"| {k} | {cell(v)} |" for k, v in summary.items()]
    lines += [
        "",
        "| seed | arm | role | truth (size / noise) | rank | named first | added "
        "| RMSE/floor before → after | final verdict | s |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in records:
        s = r["score"]
        size = f" ({max(r['size_over_noise']):.1f})" if r["effects"] else ""
        truth = truth_text(r["effects"]) + size + (" below noise" if s["below_noise"] else "")
        ranks = ", ".join("-" if k is None else str(k) for k in s["ranks"])
        named = "-" if r["named"] is None else _label(*r["named"])
        added = ", ".join(_label(k, j) for k, j in r["added"]) or "-"
        ratio = f"{max(r['ratio_before']):.2f} → {max(r['ratio_after']):.2f}"
        verdict = s["verdict_category"] + ("" if s["verdict_correct"] else " ✗")
        lines.append(
            f"| {r['seed']} | {r['arm']}{' (currents)' if r.get('logs') == 'current' else ''} "
            f"| {r['role']} | {truth} | {ranks} | {named} | {added} "
            f"| {ratio} | {verdict} | {r['seconds']:.0f} |"
        )
    params = [(r["seed"], p) for r in records for p in r["score"]["parameters"]]
    if params:
        lines += [
            "",
            "| seed | effect | parameter | true | estimate ± 95% | relative error | in CI |",
            "|---|---|---|---|---|---|---|",
        ]
        for seed, p in params:
            lines.append(
                f"| {seed} | {p['effect']} | {p['parameter']} | {p['true']:.4g} | "
                f"{p['estimate']:.4g} ± {p['ci95']:.2g} | {100 * p['relative_error']:.1f} % | "
                f"{'yes' if p['within_ci'] else 'no'} |"
            )
    return "\n".join(lines) + "\n"


def confusion_counts(
    records: Sequence[Mapping[str, Any]],
) -> tuple[list[str], list[str], np.ndarray]:
    """``(rows, columns, counts)``: hidden-effect kind (``none`` for controls) of the cases
    with at most one hidden effect against the key of the first verdict's named effect
    (``none``: nothing named)."""
    pairs = []
    for r in records:
        if len(r["effects"]) > 1:
            continue
        truth = r["effects"][0]["kind"] if r["effects"] else "none"
        named = "none" if r["named"] is None else str(r["named"][0])
        pairs.append((truth, named))
    kinds = [k for k in [*CORRECT_CANDIDATES, "none"] if any(t == k for t, _ in pairs)]
    cols = sorted({n for _, n in pairs} - {"none"}) + ["none"]
    counts = np.zeros((len(kinds), len(cols)), dtype=int)
    for t, n in pairs:
        counts[kinds.index(t), cols.index(n)] += 1
    return kinds, cols, counts


def plot_confusion(records: Sequence[Mapping[str, Any]], path: str | Path, title: str) -> Path:
    """Heat map of :func:`confusion_counts` (cells with their counts) written to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows, cols, counts = confusion_counts(records)
    fig, ax = plt.subplots(figsize=(1.2 + 0.9 * len(cols), 1.0 + 0.55 * len(rows)))
    ax.imshow(counts, cmap="Blues", aspect="auto", vmin=0)
    ax.set_xticks(range(len(cols)), cols, rotation=30, ha="right")
    ax.set_yticks(range(len(rows)), rows)
    ax.set_xlabel("effect named first by the diagnosis (candidate key)")
    ax.set_ylabel("hidden effect (simulated)")
    peak = counts.max() if counts.size else 0
    for i in range(len(rows)):
        for j in range(len(cols)):
            if counts[i, j]:
                colour = "white" if counts[i, j] > 0.6 * peak else "black"
                ax.text(j, i, str(counts[i, j]), ha="center", va="center", color=colour)
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
