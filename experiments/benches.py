"""The registered benches: for each result kind, the module that writes it.

Every module named here exports ``RESULT_LAYOUTS`` (its :class:`~mcpilco.experiments.results.
ResultLayout` objects, one per kind of file it writes) and ``HEADLINES`` (the
:class:`~mcpilco.experiments.results.Headline` rows it contributes to the results index, in
the order the README cites them), and ``replot(result, path)`` where its figures can be
redrawn from its result file alone. The modules are imported on first use, so that reading
the registry costs nothing.
"""

from __future__ import annotations

import importlib
import json
from pathlib import Path
from types import ModuleType

from mcpilco.experiments.results import SCHEMA, Headline, ResultLayout, read_result

# The bench modules in the order of the results index (README order).
BENCH_MODULES: tuple[str, ...] = (
    "mcpilco.experiments.mcpilco.bench",
    "mcpilco.experiments.mcpilco.compare",
    "mcpilco.experiments.mcpilco.tracking",
    "mcpilco.experiments.mcpilco.gp_predictor",
    "mcpilco.experiments.mcpilco.budget_model",
    "mcpilco.experiments.mcpilco.evaluation",
    "mcpilco.experiments.identification.volterra",
    "mcpilco.experiments.identification.inverse_dynamics",
    "mcpilco.experiments.collision.bench",
    "mcpilco.experiments.collision.quasi_static_friction",
    "mcpilco.experiments.kinematics.bench",
    "mcpilco.experiments.kinematics.reaching",
    "mcpilco.experiments.kinematics.marker_detection",
    "mcpilco.experiments.diagnosis.bench",
    "mcpilco.experiments.diagnosis.torque_constants",
    "mcpilco.experiments.diagnosis.learned_start",
    "mcpilco.experiments.infra.overhead",
    "mcpilco.experiments.infra.robustness",
)


def bench_modules() -> list[ModuleType]:
    """The registered bench modules, imported."""
    return [importlib.import_module(name) for name in BENCH_MODULES]


def layouts() -> dict[str, ResultLayout]:
    """Every registered result kind and its layout."""
    out: dict[str, ResultLayout] = {}
    for module in bench_modules():
        for layout in module.RESULT_LAYOUTS:
            if layout.kind in out:
                raise ValueError(f"result kind {layout.kind!r} is registered twice")
            out[layout.kind] = layout
    return out


def layout(kind: str) -> ResultLayout:
    """The layout of result kind ``kind``; ValueError naming the known kinds otherwise."""
    known = layouts()
    if kind not in known:
        raise ValueError(f"unknown result kind {kind!r}; registered: {sorted(known)}")
    return known[kind]


def replot_file(path: str | Path) -> list[Path]:
    """Redraw the figures of the result file ``path`` from the file, with its bench's
    ``replot(result, path)``; [] for a bench whose figures need data the file does not hold.
    """
    result = read_result(path)
    for module in bench_modules():
        if any(lay.kind == result.kind for lay in module.RESULT_LAYOUTS):
            replot = getattr(module, "replot", None)
            return replot(result, Path(path)) if replot is not None else []
    raise ValueError(f"{path}: no registered bench writes result kind {result.kind!r}")


def replot_tree(results_dir: str | Path) -> list[Path]:
    """Redraw the figures of every result file under ``results_dir``; the figures drawn."""
    drawn = []
    for path in sorted(Path(results_dir).rglob("*.json")):
        if json.loads(path.read_text()).get("schema") == SCHEMA:
            drawn += replot_file(path)
    return drawn


def headlines() -> list[Headline]:
    """Every bench's headline rows, bench by bench in :data:`BENCH_MODULES` order."""
    return [h for module in bench_modules() for h in module.HEADLINES]
