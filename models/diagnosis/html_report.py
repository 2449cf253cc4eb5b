"""One self-contained HTML report of a diagnosis run, to open offline or send to a colleague.

:class:`DiagnosisReport` holds what :func:`~.workflow.run_diagnosis` found and
:meth:`DiagnosisReport.html` renders it as a single file: the CSS inline (light and dark by the
reader's ``prefers-color-scheme``, readable in print), every figure embedded as a base64 PNG
(``data:image/png``), no scripts, no fonts, no links to other files; internal ``#`` links only.

Sections (each a collapsible ``<details>``, listed in a table of contents):

* **Verdict**: the final verdict, coloured by what it says (at the noise floor, a missing
  effect, unexplained, not enough data), and the final held-out error per joint in noise floors;
* **Checks**: what a reader must know before trusting a number (data warnings, joints above
  the floor, parameters that are not identifiable from these data, wrong signs);
* **Data**: training and held-out files, rows, sample time, output;
* **Fit per version**: held-out RMSE and RMSE / noise floor per version and joint (the
  waterfall), and nMSE / RMSE / fit % on training and held-out rows;
* **Candidates scored**: each diagnosis's ranked table (evidence gain, held-out change, group,
  estimate with its 95% interval, status) and its verdict;
* **Chosen effects**: the final model's effects with their parameters and 95% intervals, or
  "not identifiable from these data" with the reason (:mod:`.identifiability`), and the
  alternatives the data cannot tell apart from them;
* **Parameter correlation**: the posterior correlation of every joint's effect weights, cells
  shaded by ``|rho|`` (a collinear pair stands out);
* **Residual structure**: per joint, RMSE / floor, the share of the residual variance that
  bins of ``q``, ``qd``, ``qdd`` explain, the whiteness test and the cross-correlation with
  ``q``, ``qd`` and the predicted torque (:mod:`.analysis`; 99% bands), and in words;
* **Corrected parameters**: a slot for the corrected robot file's parameters, rendered when
  given (``{name: value}`` or ``{name: {"value": .., "ci95": .., "unit": .., ...}}``);
* **Figures**: the PNG figures of the run.
"""

from __future__ import annotations

import base64
import html
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mcpilco.models.diagnosis.analysis import ResidualReport
from mcpilco.models.diagnosis.identifiability import posterior_correlation, weight_names
from mcpilco.models.diagnosis.model import DiagnosisModel
from mcpilco.models.diagnosis.search import FLOOR_FACTOR, Diagnosis, FloorCheck

FloatArray = NDArray[np.float64]

__all__ = ["DiagnosisReport", "verdict_status", "weight_correlations"]

CSS = """
:root{--bg:#f4f6f8;--card:#fff;--fg:#212529;--muted:#6c757d;--line:#dee2e6;--ok:#2e7d32;
--warn:#e65100;--bad:#c62828;--info:#1565c0;--na:#6c757d;--code:#f1f3f5}
@media (prefers-color-scheme:dark){:root{--bg:#121212;--card:#1e1e1e;--fg:#e0e0e0;
--muted:#a0a0a0;--line:#333;--ok:#66bb6a;--warn:#ffa726;--bad:#ef5350;--info:#64b5f6;
--na:#a0a0a0;--code:#2a2a2a}}
*{box-sizing:border-box}
body{margin:0;background:var(--bg);color:var(--fg);font:15px/1.55 -apple-system,
BlinkMacSystemFont,"Segoe UI",Roboto,Helvetica,Arial,sans-serif}
main{max-width:1200px;margin:0 auto;padding:1.5rem}
header{background:var(--card);border-bottom:1px solid var(--line);padding:1rem 1.5rem}
header h1{margin:0;font-size:1.6rem}
.meta{color:var(--muted);font-size:.85rem}
section,nav{background:var(--card);border:1px solid var(--line);border-radius:.5rem;
padding:1rem 1.5rem;margin:0 0 1.2rem}
nav ul{list-style:none;margin:0;padding:0;display:flex;flex-wrap:wrap;gap:.4rem}
nav a{display:inline-block;padding:.25rem .8rem;border-radius:1rem;background:var(--bg);
color:var(--fg);text-decoration:none;font-size:.85rem}
summary{font-size:1.25rem;font-weight:700;cursor:pointer;margin:.2rem 0 .6rem}
h3{font-size:1.05rem;margin:1rem 0 .4rem}
table{border-collapse:collapse;margin:.3rem 0 .8rem;font-size:.85rem;display:block;
overflow-x:auto;max-width:100%}
th,td{border:1px solid var(--line);padding:.25rem .5rem;text-align:left;vertical-align:top}
th{background:var(--bg)}
td.num{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
code,.mono{font-family:Menlo,Consolas,"Courier New",monospace;font-size:.85em}
.verdict{border-left:.4rem solid var(--na);padding:.6rem 1rem;background:var(--bg);
border-radius:.3rem}
.verdict.ok{border-color:var(--ok)}.verdict.effect{border-color:var(--info)}
.verdict.unexplained{border-color:var(--warn)}.verdict.nodata{border-color:var(--na)}
.tag{display:inline-block;padding:.05rem .5rem;border-radius:.8rem;font-size:.8rem;
font-weight:600;color:#fff;background:var(--na)}
.tag.ok{background:var(--ok)}.tag.effect{background:var(--info)}
.tag.unexplained{background:var(--warn)}
.good{color:var(--ok)}.high{color:var(--warn);font-weight:600}.bad{color:var(--bad)}
ul.checks li{margin:.2rem 0}
figure{margin:.5rem 0 1rem}figure img{max-width:100%;height:auto;background:#fff}
figcaption{color:var(--muted);font-size:.85rem}
@media print{details{display:block}summary{list-style:none}nav{display:none}
section{break-inside:avoid}}
"""
"""The report's style sheet (inline; system fonts only)."""

STATUS_TEXT = {
    "ok": "at the noise floor",
    "effect": "missing effect found",
    "unexplained": "unexplained residual",
    "nodata": "not enough data",
}
"""Headline of each verdict status (:func:`verdict_status`)."""


def verdict_status(verdict: str) -> str:
    """``"nodata"``, ``"unexplained"``, ``"effect"`` or ``"ok"``: what ``verdict`` says,
    worst first (an effect that leaves a joint unexplained is ``"unexplained"``)."""
    if "not enough data" in verdict:
        return "nodata"
    if "unexplained" in verdict:
        return "unexplained"
    if "missing effect:" in verdict or "better described as" in verdict:
        return "effect"
    return "ok"


def weight_correlations(model: DiagnosisModel) -> list[tuple[int, list[str], FloatArray]]:
    """Per joint with effect weights, ``(joint (1-based), weight names, correlation)`` of a
    fitted model (:func:`.identifiability.posterior_correlation`)."""
    out = []
    for j in range(model.n_joints):
        gp = model.gps_[j]
        if gp.sizes:
            names = weight_names(model.block_effects(j), gp.sizes)
            out.append((j + 1, names, posterior_correlation(gp, model.theta_[j])))
    return out


def _e(x: Any) -> str:
    return html.escape(str(x), quote=True)


def _num(x: Any, fmt: str = ".4g") -> str:
    if x is None:
        return ""
    try:
        v = float(x)
    except (TypeError, ValueError):
        return _e(x)
    return "–" if not math.isfinite(v) else format(v, fmt)


def _table(head: Sequence[str], rows: Sequence[Sequence[Any]], numeric: Sequence[int] = ()) -> str:
    """An HTML table; cells are escaped unless given as ``("html", markup)``."""
    out = ["<table><thead><tr>", *(f"<th>{_e(h)}</th>" for h in head), "</tr></thead><tbody>"]
    for row in rows:
        out.append("<tr>")
        for i, cell in enumerate(row):
            cls = ' class="num"' if i in numeric else ""
            if isinstance(cell, tuple) and len(cell) == 2 and cell[0] == "html":
                out.append(f"<td{cls}>{cell[1]}</td>")
            else:
                out.append(f"<td{cls}>{_e(cell)}</td>")
        out.append("</tr>")
    out.append("</tbody></table>")
    return "".join(out)


def _ratio_cell(r: float) -> tuple[str, str]:
    cls = "good" if r <= FLOOR_FACTOR else "high"
    return ("html", f'<span class="{cls}">{_num(r, ".2f")}x</span>')


def _png(data: str | Path | bytes) -> str:
    raw = data if isinstance(data, bytes) else Path(data).read_bytes()
    if not raw.startswith(b"\x89PNG"):
        raise ValueError(
            f"figure {data if not isinstance(data, bytes) else '<bytes>'} is not a PNG"
        )
    return "data:image/png;base64," + base64.b64encode(raw).decode("ascii")


@dataclass
class DiagnosisReport:
    """What one diagnosis run found, rendered by :meth:`html` (module docstring).

    Attributes:
        title: the report's heading.
        verdict: the final verdict (:meth:`.Diagnosis.verdict` of the last version).
        versions: every version's description (``"v1: ... + viscous:2"``).
        heldout_rmse: ``(k, n)`` held-out RMSE per version and joint.
        floors: ``(k, n)`` each version's noise floor on the held-out rows.
        metrics: ``(version, data set, fit_metrics)`` rows (:func:`.analysis.fit_metrics`).
        diagnoses: version name -> its :class:`.Diagnosis`.
        parameters: the final model's :meth:`.DiagnosisModel.parameters` rows.
        correlations: per joint ``(joint (1-based), weight names, (P, P) correlation)`` of the
            final model (:func:`.identifiability.posterior_correlation`).
        alternatives: candidate label -> label of the effect it is an alternative to.
        residuals: the final version's :class:`.ResidualReport` on the held-out rows.
        final_check: the final version's :class:`.FloorCheck`.
        figures: ``(caption, PNG path or bytes)``.
        corrected: corrected robot-file parameters, ``{name: value}`` or
            ``{name: {column: value}}`` (``None``: no corrected file in this run).
        data: facts about the data, ``{label: value}`` (files, rows, sample time, ...).
        warnings: data warnings of the loader.
        seconds: the run's wall time.
    """

    title: str
    verdict: str
    versions: list[str]
    heldout_rmse: FloatArray
    floors: FloatArray
    metrics: list[tuple[str, str, Mapping[str, Any]]] = field(default_factory=list)
    diagnoses: Mapping[str, Diagnosis] = field(default_factory=dict)
    parameters: list[Mapping[str, Any]] = field(default_factory=list)
    correlations: list[tuple[int, list[str], FloatArray]] = field(default_factory=list)
    alternatives: Mapping[str, str] = field(default_factory=dict)
    residuals: ResidualReport | None = None
    final_check: FloorCheck | None = None
    figures: list[tuple[str, str | Path | bytes]] = field(default_factory=list)
    corrected: Mapping[str, Any] | None = None
    data: Mapping[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    seconds: float | None = None

    def __post_init__(self) -> None:
        self.heldout_rmse = np.atleast_2d(np.asarray(self.heldout_rmse, dtype=np.float64))
        self.floors = np.atleast_2d(np.asarray(self.floors, dtype=np.float64))
        k = len(self.versions)
        if self.heldout_rmse.shape[0] != k or self.floors.shape != self.heldout_rmse.shape:
            raise ValueError(
                f"heldout_rmse {self.heldout_rmse.shape} and floors {self.floors.shape} must "
                f"both be (versions = {k}, joints)"
            )
        if self.corrected is not None and not isinstance(self.corrected, Mapping):
            raise TypeError(
                f"corrected must be a mapping name -> value, got {type(self.corrected).__name__}"
            )

    # ------------------------------------------------------------------ sections
    @property
    def n_joints(self) -> int:
        return int(self.heldout_rmse.shape[1])

    def _ratios(self) -> FloatArray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.floors > 0, self.heldout_rmse / self.floors, np.inf)

    def _unidentified(self) -> list[Mapping[str, Any]]:
        return [p for p in self.parameters if p.get("unidentified")]

    def _verdict_section(self) -> str:
        status = verdict_status(self.verdict)
        final = self._ratios()[-1]
        rows = [
            [f"joint {j + 1}", _num(self.heldout_rmse[-1, j]), _num(self.floors[-1, j])]
            + [_ratio_cell(final[j])]
            for j in range(self.n_joints)
        ]
        return (
            f'<p><span class="tag {status}">{_e(STATUS_TEXT[status])}</span></p>'
            f'<div class="verdict {status}"><p>{_e(self.verdict)}</p></div>'
            f"<h3>final held-out error ({_e(self.versions[-1].split(':', 1)[0])})</h3>"
            + _table(["joint", "RMSE", "noise floor", "RMSE / floor"], rows, numeric=(1, 2, 3))
            + f'<p class="meta">At the floor: RMSE within {FLOOR_FACTOR:g} noise floors '
            "(measurement noise plus the noise that estimated qd/qdd carry into the "
            "prediction).</p>"
        )

    def _checks_section(self) -> str:
        items = []
        for w in self.warnings:
            items.append(("high", f"data: {w}"))
        if self.final_check is not None:
            for j in self.final_check.failing:
                items.append(
                    (
                        "high",
                        f"joint {j} is at {self.final_check.ratio[j - 1]:.2f}x the noise floor: "
                        "the model does not explain its torque (see Residual structure)",
                    )
                )
        for p in self._unidentified():
            items.append(
                (
                    "high",
                    f"{p['effect']} (joint {p['output']}): {p['name']} is not identifiable from "
                    f"these data: {p['unidentified']}",
                )
            )
        for p in self.parameters:
            if p.get("wrong_sign"):
                items.append(("bad", f"{p['effect']}: {p['name']} has an unphysical sign"))
        if not items:
            items.append(("good", "no warnings: every joint at the floor, every parameter pinned"))
        return (
            '<ul class="checks">'
            + "".join(f'<li class="{cls}">{_e(text)}</li>' for cls, text in items)
            + "</ul>"
        )

    def _data_section(self) -> str:
        rows = [
            [k, ", ".join(map(str, v)) if isinstance(v, list | tuple) else v]
            for k, v in self.data.items()
        ]
        if self.seconds is not None:
            rows.append(["run time", f"{self.seconds:.1f} s"])
        return _table(["", ""], rows)

    def _fit_section(self) -> str:
        n = self.n_joints
        ratios = self._ratios()
        head = ["version"] + [f"RMSE j{j + 1}" for j in range(n)]
        head += [f"/floor j{j + 1}" for j in range(n)]
        rows = []
        for v, desc in enumerate(self.versions):
            rows.append(
                [desc]
                + [_num(x) for x in self.heldout_rmse[v]]
                + [_ratio_cell(x) for x in ratios[v]]
            )
        out = "<h3>held-out error per version</h3>" + _table(
            head, rows, numeric=tuple(range(1, 2 * n + 1))
        )
        if self.metrics:
            mrows = []
            for version, which, m in self.metrics:
                for j in range(n):
                    mrows.append(
                        [
                            version,
                            which,
                            j + 1,
                            _num(m["nmse"][j], ".3e"),
                            _num(m["rmse"][j]),
                            _num(m["fit_pct"][j], ".2f"),
                        ]
                    )
            out += "<h3>fit metrics</h3>" + _table(
                ["version", "data", "joint", "nMSE", "RMSE", "fit %"], mrows, numeric=(2, 3, 4, 5)
            )
        return out

    def _candidates_section(self) -> str:
        if not self.diagnoses:
            return "<p>No diagnosis in this run.</p>"
        out = []
        for name, d in self.diagnoses.items():
            rows = []
            for i, c in enumerate(d.candidates, 1):
                held = "" if c.heldout_delta_pct is None else f"{c.heldout_delta_pct:+.1f} %"
                rows.append(
                    [
                        i,
                        c.effect.variant_label,
                        c.joint_text,
                        _num(c.delta, ".1f"),
                        held,
                        c.group,
                        c.estimate_text(),
                        d.status(c),
                    ]
                )
            out.append(f"<h3>diagnosis of {_e(name)}</h3>")
            out.append(
                _table(
                    [
                        "#",
                        "effect",
                        "joint",
                        "Δ log-evidence [nats]",
                        "held-out ΔRMSE",
                        "group",
                        "estimate ± 95% CI",
                        "status",
                    ],
                    rows,
                    numeric=(0, 3, 4, 5),
                )
            )
            out.append(f'<p class="mono">{_e(d.verdict())}</p>')
        threshold = next(iter(self.diagnoses.values())).threshold
        out.append(
            f'<p class="meta">Significant: more than {threshold:g} '
            "nats of evidence with a physical sign, and a lower held-out RMSE. A group holds "
            "candidates whose fitted torques correlate (the data cannot tell them apart).</p>"
        )
        return "".join(out)

    def _effects_section(self) -> str:
        if not self.parameters:
            out = "<p>No effect was added: the final model is the start model.</p>"
        else:
            rows = []
            for p in self.parameters:
                if p.get("unidentified"):
                    est = ("html", '<span class="high">not identifiable from these data</span>')
                    ci, why = "", p["unidentified"]
                else:
                    est, ci, why = _num(p["value"]), _num(p["ci95"]), ""
                rows.append([p["effect"], p["output"], p["name"], est, ci, p.get("unit", ""), why])
            out = _table(
                ["effect", "joint", "parameter", "value", "± 95% CI", "unit", "identifiability"],
                rows,
                numeric=(1, 3, 4),
            )
        if self.alternatives:
            rows = [[alt, eff] for alt, eff in self.alternatives.items()]
            out += "<h3>alternatives (never added beside the effect they stand for)</h3>"
            out += _table(["candidate", "alternative to"], rows)
        return out

    def _correlation_section(self) -> str:
        if not self.correlations:
            return "<p>No effect weights in the final model.</p>"
        out = []
        for joint, names, corr in self.correlations:
            out.append(f"<h3>joint {joint}</h3><table><thead><tr><th></th>")
            out += [f"<th>{_e(n)}</th>" for n in names]
            out.append("</tr></thead><tbody>")
            for i, n in enumerate(names):
                out.append(f"<tr><th>{_e(n)}</th>")
                for k in range(len(names)):
                    r = float(corr[i, k])
                    a = 0.0 if i == k else min(abs(r), 1.0)
                    hue = "198,40,40" if r < 0 else "21,101,192"
                    style = f"background:rgba({hue},{0.85 * a:.2f})" if a > 0 else ""
                    out.append(f'<td class="num" style="{style}">{r:+.2f}</td>')
                out.append("</tr>")
            out.append("</tbody></table>")
        out.append(
            '<p class="meta">Posterior correlation of the effect weights on each joint (the start '
            "model marginalised); |ρ| near 1 means the data fix only a combination.</p>"
        )
        return "".join(out)

    def _residual_section(self) -> str:
        out = []
        if self.final_check is not None and self.final_check.failing:
            out.append("<h3>joints above the noise floor</h3><ul>")
            for j in self.final_check.failing:
                words = self.final_check.structure.get(j, "")
                out.append(
                    f"<li><b>joint {j}: {self.final_check.ratio[j - 1]:.2f}x the floor</b>"
                    + (f"; residual: {_e(words)}" if words else "")
                    + "</li>"
                )
            out.append("</ul>")
        if self.residuals is None:
            return "".join(out) or "<p>No residual analysis in this run.</p>"
        ratios = self._ratios()[-1]
        rows = []
        for jr in self.residuals.joints:
            j = jr.joint
            bins = ", ".join(f"{k}{j} {100 * v:.0f}%" for k, v in jr.explained.items())
            w = jr.whiteness
            white = (
                ""
                if w is None
                else (
                    f"{'white' if w.passed else 'not white'}: peak {w.peak:+.2f} at lag "
                    f"{w.peak_lag} (band ±{w.band:.3f})"
                )
            )
            xc = []
            for name, t in jr.xcorr.items():
                mark = "ok" if t.passed else "CORRELATED"
                xc.append(
                    f"{name}{j}: {mark}, peak {t.peak:+.2f} at lag {t.peak_lag} "
                    f"(band ±{t.band:.3f})"
                )
            rows.append(
                [
                    j,
                    _ratio_cell(ratios[j - 1]) if j - 1 < ratios.size else "",
                    bins,
                    white,
                    ("html", "<br>".join(_e(x) for x in xc)),
                    jr.structure(),
                ]
            )
        out.append(f"<h3>held-out residual of {_e(self.residuals.model_name)}</h3>")
        out.append(
            _table(
                [
                    "joint",
                    "RMSE / floor",
                    "variance explained by bins",
                    "whiteness (lags 1..L)",
                    "cross-correlation with inputs (lags −L..L)",
                    "in words",
                ],
                rows,
                numeric=(0, 1),
            )
        )
        out.append(
            '<p class="meta">As MATLAB\'s resid: 99% band of one lag; a test fails when any lag '
            "leaves the band widened for all lags at once. Cross-correlation bands use "
            "Bartlett's variance of two independent autocorrelated series; the torque input "
            "is the predicted torque. Lag > 0: the input leads the residual.</p>"
        )
        out.append("<h3>where the model fails (worst first)</h3><ul>")
        out += [f"<li>{_e(t)}</li>" for t in self.residuals.findings()]
        out.append("</ul>")
        return "".join(out)

    def _corrected_section(self) -> str:
        if self.corrected is None:
            return "<p>No corrected robot file was written in this run.</p>"
        if not self.corrected:
            return "<p>No parameter of the robot file was corrected.</p>"
        nested = [v for v in self.corrected.values() if isinstance(v, Mapping)]
        if not nested:
            rows = [[k, v if isinstance(v, str) else _num(v)] for k, v in self.corrected.items()]
            return _table(["parameter", "value"], rows, numeric=(1,))
        cols: list[str] = []
        for v in nested:
            cols += [c for c in v if c not in cols]
        rows = []
        for k, v in self.corrected.items():
            if isinstance(v, Mapping):
                cells = [v.get(c, "") for c in cols]
            else:
                cells = [v] + [""] * (len(cols) - 1)
            rows.append([k] + [c if isinstance(c, str) else _num(c) for c in cells])
        return _table(["parameter", *cols], rows)

    def _figures_section(self) -> str:
        if not self.figures:
            return "<p>No figures in this run (figures off).</p>"
        return "".join(
            f'<figure><img alt="{_e(cap)}" src="{_png(data)}"><figcaption>{_e(cap)}'
            "</figcaption></figure>"
            for cap, data in self.figures
        )

    # ------------------------------------------------------------------ document
    def html(self) -> str:
        """The report as one HTML document (module docstring)."""
        sections = [
            ("verdict", "Verdict", self._verdict_section()),
            ("checks", "Checks", self._checks_section()),
            ("data", "Data", self._data_section()),
            ("fit", "Fit per version", self._fit_section()),
            ("candidates", "Candidates scored", self._candidates_section()),
            ("effects", "Chosen effects", self._effects_section()),
            ("correlation", "Parameter correlation", self._correlation_section()),
            ("residuals", "Residual structure", self._residual_section()),
            ("corrected", "Corrected parameters", self._corrected_section()),
            ("figures", "Figures", self._figures_section()),
        ]
        toc = "".join(f'<li><a href="#{a}">{_e(t)}</a></li>' for a, t, _ in sections)
        body = "".join(
            f'<section id="{a}"><details open><summary>{_e(t)}</summary>{content}'
            "</details></section>"
            for a, t, content in sections
        )
        stamp = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
        return (
            '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            '<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>{_e(self.title)}</title><style>{CSS}</style></head><body>"
            f'<header><h1>{_e(self.title)}</h1><div class="meta">mcpilco model diagnosis · '
            f"generated {stamp}</div></header><main><nav><ul>{toc}</ul></nav>{body}</main>"
            "</body></html>\n"
        )

    def write(self, path: str | Path) -> Path:
        """Write :meth:`html` to ``path`` (parent folders created); returns the path."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(self.html(), encoding="utf-8")
        return path
