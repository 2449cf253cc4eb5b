"""The diagnosis loop on files: compare a robot model with measurements, see where it fails,
find the missing physical effect, add it, watch the error fall (``mcpilco-diagnose``).

:func:`run_diagnosis` runs the steps of :mod:`mcpilco.models.diagnosis` on training and
held-out files and reports each step as text lines (``log``). Start model: a nominal robot
file (MJCF or URDF, rigid-body physics), or a GIP / RBF GP learned on the training files
(the joint types set the joint count and which joints are angles; a robot file then only
gives the inertial candidates, every link and the payload, their regressor). Without
held-out files the last training file (or, with one file, its last 30%) is held out.
Effects are added by name (``coulomb:2``) or automatically, best first (missing effects
before refinements inside a learned start's span), while one is significant; what the data
cannot tell apart from an added effect is reported as its alternative and only ever put in
its place (:func:`~.search.next_version`); after each addition, earlier effects whose
evidence it took are removed as new versions (stepwise selection, :func:`~.search.stepwise`).
Every version is saved as
``<out>/models/model_v<k>.json`` (never overwritten).

Motor-current files (columns ``i1..in``) are put into torque units first, ``y = k_t i``: with
the given ``torque_constants``, and for the joints without one with constants estimated on the
training files against the robot file (:mod:`~.units`; a joint the data cannot pin down is
diagnosed in its own current units, A, with a free scale of its model torque fitted with the
effects, and the reason is reported); ``k_t`` and its interval are reported, and its uncertainty is
kept either in the model (a free scale of the model torque, ``scale:j``, so that it is never
named as an offset, spring or cogging) or in the noise floor. A learned start without a robot
file has no torque units: without given constants its loop stays in amperes.

Every held-out error is read against the noise floor of :func:`~.search.heldout_floor`
(measurement noise plus the noise that estimated ``qd``/``qdd`` carry into the prediction);
the final verdict (:meth:`~.search.Diagnosis.verdict` of the last version) says "no
significant missing effect" only when every joint is at that floor, and otherwise
"unexplained" with the joint, its error in floors and the residual's structure.

With a nominal MJCF start, the last version's effects are written back as
``corrected.xml`` with the side record ``corrected_effects.json``, refined by
``mujoco.sysid`` into ``refined.xml`` (unless ``sysid`` is false), and the free-run
simulation error of the nominal, corrected and refined files on the held-out logs is reported
next to their one-step torque error (:func:`~.sysid_refine.robot_file_step`; torque logs).

The run is four stages, each a function of this module that hands its result to the next:
:func:`load_stage` (the start model, the logs read and checked, the held-out split, currents
in torque units), :func:`fit_stage` (version 0 fitted, compared and its residuals read),
:func:`search_stage` (the missing effects found and added, every version saved) and
:func:`report_stage` (the error of every version over the floor, the figures, the corrected
robot file, the verdict, ``summary.json`` and ``report.html``); :class:`HeldOut` keeps each
version's held-out predictions, floor and residual report so that no stage computes them
twice.

Outputs under ``out``: ``compare_v<k>.png`` (measured vs predicted +-2 sigma),
``residuals_v<k>.png``, ``waterfall.png``, ``diagnosis.rrd`` (Rerun), ``summary.json``, and
``report.html`` (:class:`~.html_report.DiagnosisReport`: one self-contained file with the
tables, the figures, the verdict and the residual's structure).
"""

from __future__ import annotations

import json
import math
import numbers
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.models.diagnosis.add import add_effect
from mcpilco.models.diagnosis.analysis import (
    ResidualReport,
    fit_metrics,
    metrics_table,
    residual_report,
)
from mcpilco.models.diagnosis.bags import BagOptions
from mcpilco.models.diagnosis.data import (
    MIN_FIT_ROWS,
    MIN_HELDOUT_ROWS,
    load_trajectories,
    require_motion,
    require_rows,
)
from mcpilco.models.diagnosis.effects import Effect, parse_effect
from mcpilco.models.diagnosis.html_report import DiagnosisReport, weight_correlations
from mcpilco.models.diagnosis.model import DiagnosisModel
from mcpilco.models.diagnosis.search import (
    Diagnosis,
    Removal,
    diagnose,
    heldout_floor,
    smear_judged,
    stepwise,
)
from mcpilco.models.diagnosis.start_models import (
    LEARNED_STARTS,
    NominalStart,
    StartModel,
    read_robot_text,
)
from mcpilco.models.diagnosis.units import (
    TorqueConstants,
    check_angle_units,
    currents_to_torque,
)
from mcpilco.models.gp.linear_gp import single_thread
from mcpilco.models.robot_data import Trajectories

Log = Callable[[str], None]  # receives the report, one block of text at a time


def _is_number(value: Any, integer: bool) -> bool:
    """Whether ``value`` is a finite number (an integer with ``integer``), not a boolean."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return False
    return math.isfinite(value) and (not integer or int(value) == value)


def check_options(auto: Any, threshold: Any, max_points: Any, gip_iters: Any) -> None:
    """Refuse a numeric option of :func:`run_diagnosis` that is not a finite number in range
    (before anything is read).

    Raises:
        ValueError: naming the option, its lower bound and the value given.
    """
    for name, value, integer in (
        ("auto", auto, True),
        ("threshold", threshold, False),
        ("max_points", max_points, True),
        ("gip_iters", gip_iters, True),
    ):
        low = 10 if name == "max_points" else 0
        if not _is_number(value, integer) or value < low:
            raise ValueError(f"{name} must be a finite number >= {low}, got {value!r}")


def _require_start(model: str | Path | None, learned: tuple[str, str] | None) -> None:
    """Refuse a run with neither a robot file nor a learned start (ValueError saying how)."""
    if model is None and learned is None:
        raise ValueError(
            "give a start model: --model robot.xml (nominal), or --gip RRPR / --rbf RRPR (learned)"
        )


def start_model(
    model: str | Path | None,
    learned: tuple[str, str] | None,
    include_root: str | Path | None = None,
    gip_iters: int = 100,
) -> StartModel:
    """The start model: a learned GIP / RBF GP when ``learned`` is given (a robot file then
    gives only its inertial candidates), else the nominal robot file ``model`` (its
    ``<include>`` files confined to its folder or ``include_root``).

    Raises:
        ValueError: neither given, or an unknown learned kind.
    """
    _require_start(model, learned)
    robot = None if model is None else read_robot_text(model, include_root)
    if learned is None:
        return NominalStart(robot, name=str(model))
    kind, joint_types = learned
    if kind not in LEARNED_STARTS:
        raise ValueError(f"learned start must be one of {sorted(LEARNED_STARTS)}, got {kind!r}")
    return LEARNED_STARTS[kind](joint_types, robot=robot, adam_iters=gip_iters)


@dataclass
class LoadedLogs:
    """What :func:`load_stage` hands on.

    Attributes:
        start: the start model (unfitted).
        train, test: training and held-out trajectories, in torque units where the constants
            allow, without the derivative filter's edge rows.
        constants: the torque constants that put currents into torque units, or ``None``.
        unit: the unit of every joint's output for the reports (``None``: torque units; ``"A"``
            for all joints, or one entry per joint).
        warnings: the loader's data warnings, each once.
    """

    start: StartModel
    train: Trajectories
    test: Trajectories
    constants: TorqueConstants | None
    unit: str | list[str | None] | None
    warnings: list[str]


def _held_out_split(
    train: Trajectories, test: Trajectories | None, log: Log
) -> tuple[Trajectories, Trajectories]:
    """``(train, test)``: the given held-out logs, else the last training file, else (one
    file) the last 30% of its rows."""
    if test is not None:
        return train, test
    if train.n_segments >= 2:
        test = train.select([train.n_segments - 1])
        log(f"held out (whole file): {test.names[0]}")
        return train.select(range(train.n_segments - 1)), test
    train, test = train.split_time(0.7)
    log(f"held out: the last 30% of {train.names[0]}")
    return train, test


def _log_data_facts(train: Trajectories, test: Trajectories, log: Log) -> list[str]:
    """Log the loader's warnings and which derivatives were estimated; return the warnings."""
    warnings = list(dict.fromkeys(train.warnings + test.warnings))
    for text in warnings:
        log(f"warning: {text}")
    filters = zip(train.names + test.names, train.estimated + test.estimated, strict=False)
    for name, est in dict(filters).items():
        if est is not None:
            log(f"{name}: {' and '.join(est.groups)} estimated from q by {est.filter.name}")
    return warnings


def load_stage(
    start: StartModel,
    train: Sequence[str | Path],
    test: Sequence[str | Path] | None,
    bag: BagOptions,
    torque_constants: Sequence[float | None] | None,
    log: Log,
) -> LoadedLogs:
    """Load stage: read and check the logs against the start model, hold some out, and put
    motor currents into torque units (``y = k_t i``, :func:`~.units.currents_to_torque`).

    Bag joints pair with the robot file's joint names; a log must have the model's joint
    count, enough rows and motion, and angles in radians. The derivative filter's edge rows
    are dropped after the units step (which needs whole files).

    Raises:
        ValueError: unreadable or too short files, a joint count that differs from the model's,
            a joint logged in degrees, bad torque constants.
    """
    n = start.n_joints
    robot = getattr(start, "robot", None)  # the robot file's joint names pair bag joints
    names = None if robot is None else list(robot.model.names)[1:]
    tr = load_trajectories(train, n_joints=n, bag=bag, joint_names=names)
    te = load_trajectories(test, n_joints=n, bag=bag, joint_names=names) if test else None
    tr, te = _held_out_split(tr, te, log)
    require_rows(tr, MIN_FIT_ROWS, "fitting a diagnosis model")  # before any work
    require_motion(tr)
    require_rows(te, MIN_HELDOUT_ROWS, "confirming effects on held-out data")
    check_angle_units(start, tr)  # a joint logged in degrees throughout
    check_angle_units(start, te)
    warnings = _log_data_facts(tr, te, log)
    tr, te, constants = currents_to_torque(tr, te, start, torque_constants)
    tr, te = tr.interior(), te.interior()  # without the derivative filter's edges
    if constants is not None:
        log(f"\n== 0. units: {constants.text()}")
    elif tr.output == "i":
        log("\n== 0. units: currents without torque constants; the loop works in A")
    unit: str | list[str | None] | None = "A" if tr.output == "i" else None
    if constants is not None and constants.in_current.any():  # k_t not identifiable: in A
        unit = ["A" if c else None for c in constants.in_current]
    return LoadedLogs(start, tr, te, constants, unit, warnings)


def output_folder(out: str | Path) -> Path:
    """The output folder, created.

    Raises:
        ValueError: ``out`` is a file.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} is a file; give a folder")
    out.mkdir(parents=True, exist_ok=True)
    return out


@dataclass
class HeldOut:
    """Every version's predictions on the held-out logs, each computed once.

    ``results[name]`` holds the ``(version, data set, fit_metrics)`` rows on the training
    and held-out logs and the held-out ``mean`` (dry friction at rest set-valued), ``raw``
    mean and ``var``; ``floors[name]`` the version's noise floor
    (:func:`~.search.heldout_floor`); ``reports[name]`` its residual report; ``figures`` the
    ``(caption, PNG)`` pairs for the HTML report.
    """

    data: LoadedLogs
    out: Path
    plots: bool
    log: Log
    results: dict[str, dict[str, Any]] = field(default_factory=dict)
    floors: dict[str, np.ndarray] = field(default_factory=dict)
    reports: dict[str, ResidualReport] = field(default_factory=dict)
    figures: list[tuple[str, Path]] = field(default_factory=list)

    def evaluate(self, m: DiagnosisModel) -> dict[str, Any]:
        """``m``'s fit metrics on both logs and its held-out prediction (cached)."""
        if m.name not in self.results:
            train, test = self.data.train, self.data.test
            mean_tr, _ = m.set_valued(train, m.predict(train, with_var=False)[0])
            raw_te, var_te = m.predict(test)
            mean_te, _ = m.set_valued(test, raw_te)  # dry friction at rest: set-valued
            rows = [
                (m.name, "train", fit_metrics(train.y, mean_tr)),
                (m.name, "held-out", fit_metrics(test.y, mean_te)),
            ]
            self.results[m.name] = {"rows": rows, "mean": mean_te, "raw": raw_te, "var": var_te}
        return self.results[m.name]

    def rmse(self, m: DiagnosisModel) -> np.ndarray:
        """``(n,)`` held-out RMSE of ``m`` per joint."""
        return np.asarray(self.evaluate(m)["rows"][1][2]["rmse"])

    def ratio(self, m: DiagnosisModel) -> np.ndarray:
        """``(n,)`` held-out RMSE of ``m`` over its noise floor as the verdict judges it: a
        sticking joint's own rows around its stops forgiven the derivative filter's smear,
        in the RMSE and the floor alike (:func:`~.search.smear_judged`)."""
        res = self.evaluate(m)
        if "ratio" not in res:
            rmse, floor = smear_judged(m, self.data.test, res["raw"], self.floor(m))
            res["ratio"] = rmse / floor
        return res["ratio"]

    def floor(self, m: DiagnosisModel) -> np.ndarray:
        """``(n,)`` held-out noise floor of ``m`` (cached)."""
        if m.name not in self.floors:
            self.floors[m.name] = heldout_floor(m, self.data.test, self.evaluate(m)["raw"])
        return self.floors[m.name]

    def residuals(self, m: DiagnosisModel) -> ResidualReport:
        """Where ``m`` fails on the held-out logs: its residual report against the floor,
        logged, and (with ``plots``) its time and residual figures."""
        res = self.evaluate(m)
        rep = residual_report(
            self.data.test,
            res["mean"],
            self.floor(m),
            self.data.start.joint_types,
            model_name=m.name,
            unit=self.data.unit,
        )
        self.reports[m.name] = rep
        self.log(f"\n== 2. {rep.text()}")
        if self.plots:
            from mcpilco.models.diagnosis.plots import plot_residuals, plot_time

            p1 = plot_time(
                self.data.test,
                res["mean"],
                res["var"],
                m.noise_std_,
                self.out / f"compare_{m.name}.png",
                title=m.describe(),
            )
            p2 = plot_residuals(rep, self.out / f"residuals_{m.name}.png")
            self.figures += [(f"held-out, {m.describe()}", p1), (f"residuals of {m.name}", p2)]
            self.log(f"   plots: {p1}  {p2}")
        return rep


def fit_stage(held: HeldOut, max_points: int) -> DiagnosisModel:
    """Fit stage: version 0 (the start model, with a free scale of its torque on the joints
    whose ``k_t`` stays uncertain, :meth:`~.units.TorqueConstants.effects`) fitted on the
    training logs, compared on both logs, and its held-out residuals read (steps 1 and 2)."""
    data = held.data
    scales = [] if data.constants is None else data.constants.effects()  # k_t still free
    model = DiagnosisModel(data.start, scales, max_points=max_points).fit(data.train)
    held.log(f"\n== 1. compare: {model.describe()}")
    held.log(metrics_table(held.evaluate(model)["rows"], data.start.n_joints))
    held.residuals(model)
    return model


@dataclass
class SearchResult:
    """What :func:`search_stage` hands on.

    Attributes:
        versions: every version, ``v0`` first.
        diagnoses: version name -> its :class:`~.search.Diagnosis` on the held-out logs.
        alternatives: candidate label -> the label of the added effect it stands for.
        removals: the effects removed by backward elimination, in order.
        saved: the path of every saved version.
    """

    versions: list[DiagnosisModel]
    diagnoses: dict[str, Diagnosis]
    alternatives: dict[str, str]
    removals: list[Removal]
    saved: list[str] = field(default_factory=list)


def search_stage(
    held: HeldOut,
    model: DiagnosisModel,
    effects: Sequence[Effect],
    auto: int,
    threshold: float,
) -> SearchResult:
    """Search stage: which effect is missing (step 3), then the named ``effects`` added
    (:func:`~.add.add_effect`) and up to ``auto`` more, best first, while one is significant
    (stepwise, :func:`~.search.stepwise`: the lead added, what it superseded removed); every
    version saved under ``out/models`` (step 4)."""
    test, log = held.data.test, held.log
    log("\n== 3. which effect is missing")
    diagnoses = {model.name: diagnose(model, test, threshold=threshold)}
    log(diagnoses[model.name].table())
    log("\n== 4. add")
    found = SearchResult([model], diagnoses, {}, [])
    for e in effects:
        model = add_effect(model, e)
        found.versions.append(model)
        log(f"   {model.describe()}")
    for _ in range(auto):
        if model.name not in diagnoses:
            diagnoses[model.name] = diagnose(
                model, test, threshold=threshold, alternatives=found.alternatives
            )
            log(diagnoses[model.name].table(6))
        if diagnoses[model.name].lead is None:  # no missing effect nor in-span refinement
            break
        steps = stepwise(
            model, diagnoses[model.name], test, found.alternatives, threshold=threshold
        )
        for new, removal in steps:
            found.versions.append(new)
            if removal is not None:
                found.removals.append(removal)
                log(f"   {removal.text()}")
            log(f"   {new.describe()}")
        model = found.versions[-1]
    found.saved = [str(v.save(held.out / "models")) for v in found.versions]
    log(f"   saved: {', '.join(found.saved)}")
    for p in model.parameters(shape=True):
        log(f"   {model.name} {p['effect']} (joint {p['output']}): {p['text']}")
    return found


def _error_table(held: HeldOut, versions: Sequence[DiagnosisModel]) -> None:
    """Log every version's held-out RMSE per joint, the noise floor and RMSE / floor."""
    n = held.data.start.n_joints
    head = f"{'version':<8}" + "".join(f"{'RMSE j' + str(j + 1):>12}" for j in range(n))
    held.log(head + "   effects")
    for v in versions:
        added = ", ".join(e.variant_label for e in v.effects) or "-"
        held.log(f"{v.name:<8}" + "".join(f"{x:>12.4g}" for x in held.rmse(v)) + f"   {added}")
    held.log(
        f"{'floor':<8}"
        + "".join(f"{x:>12.4g}" for x in held.floor(versions[-1]))
        + "   (noise floor: measurement + estimated qd/qdd)"
    )
    for v in versions:
        ratio = held.ratio(v)
        held.log(f"{v.name:<8}" + "".join(f"{x:>11.2f}x" for x in ratio) + "   (RMSE / floor)")
    if len(versions) > 1:
        held.log(metrics_table([held.evaluate(v)["rows"][1] for v in versions], n))


def _artefacts(held: HeldOut, versions: Sequence[DiagnosisModel], rerun: bool) -> dict[str, str]:
    """The waterfall figure (with ``plots``) and the Rerun recording (with ``rerun``)."""
    artefacts: dict[str, str] = {}
    if held.plots:
        from mcpilco.models.diagnosis.plots import plot_waterfall

        labels = [
            v.describe().split(": ", 1)[0]
            + " "
            + (", ".join(e.label for e in v.effects) or "start")
            for v in versions
        ]
        held_rmse = np.array([held.rmse(v) for v in versions])
        path = plot_waterfall(
            [v.name for v in versions],
            held_rmse,
            held.floor(versions[-1]),
            held.out / "waterfall.png",
            labels=labels,
        )
        artefacts["waterfall"] = str(path)
    if rerun:
        from mcpilco.models.diagnosis.plots import write_rerun

        means = {v.name: held.evaluate(v)["mean"] for v in versions}
        artefacts["rerun"] = str(write_rerun(held.out / "diagnosis.rrd", held.data.test, means))
    for k, p in artefacts.items():
        held.log(f"   {k}: {p}")
    if "waterfall" in artefacts:
        caption = "held-out RMSE per version over the noise floor"
        held.figures.append((caption, Path(artefacts["waterfall"])))
    return artefacts


def _final_diagnosis(held: HeldOut, found: SearchResult, threshold: float) -> None:
    """The last version's residuals and diagnosis, when it is not version 0 (read by the
    search stage already)."""
    if len(found.versions) > 1:
        last = found.versions[-1]
        held.residuals(last)
        if last.name not in found.diagnoses:
            found.diagnoses[last.name] = diagnose(
                last, held.data.test, threshold=threshold, alternatives=found.alternatives
            )
            held.log(found.diagnoses[last.name].table(6))


def _report_data(data: LoadedLogs) -> dict[str, Any]:
    """Facts about the data for the HTML report: files, rows, sample time, output, units."""
    constants = data.constants
    return {
        "training files": data.train.names,
        "held-out files": data.test.names,
        "rows (training, held-out)": f"{data.train.n_samples}, {data.test.n_samples}",
        "sample time": f"{data.train.sample_time:g} s",
        "output": "motor current i [A]" if data.train.output == "i" else "joint torque tau",
        **({} if constants is None else {"torque constants": constants.text()}),
        **{
            f"joint {j + 1} in A": f"torque constant not identifiable: {why}"
            for j, why in enumerate(() if constants is None else constants.reasons)
            if why is not None
        },
    }


def _summary(
    held: HeldOut, found: SearchResult, artefacts: dict[str, str], robot_file: dict | None
) -> dict[str, Any]:
    """The summary of the run (:func:`run_diagnosis`'s return value) less its ``seconds`` and
    ``report``."""
    versions, data, last = found.versions, held.data, found.versions[-1]
    removed = {
        r.version: f" (removed {r.variant}: its evidence taken by {r.by})" for r in found.removals
    }
    return {
        "versions": [v.describe() + removed.get(v.name, "") for v in versions],
        "heldout_rmse": np.array([held.rmse(v) for v in versions]).tolist(),
        "noise_floor": held.floor(last).tolist(),
        "rmse_over_floor": np.array([held.ratio(v) for v in versions]).tolist(),
        "verdict": found.diagnoses[last.name].verdict(),
        "diagnoses": {k: d.to_dict() for k, d in found.diagnoses.items()},
        "saved": found.saved,
        "artefacts": artefacts,
        "data_warnings": data.warnings,
        "robot_file": robot_file,
        "torque_constants": None if data.constants is None else data.constants.to_dict(),
        "removed": [r.to_dict() for r in found.removals],
    }


def _html_report(
    held: HeldOut, found: SearchResult, summary: dict[str, Any], seconds: float
) -> DiagnosisReport:
    """The run's :class:`~.html_report.DiagnosisReport` (``report.html``)."""
    versions, last = found.versions, found.versions[-1]
    return DiagnosisReport(
        title=f"Model diagnosis: {last.start.describe()}",
        verdict=summary["verdict"],
        versions=summary["versions"],
        heldout_rmse=np.array([held.rmse(v) for v in versions]),
        floors=np.array([held.floor(v) for v in versions]),
        metrics=[row for v in versions for row in held.evaluate(v)["rows"]],
        diagnoses=found.diagnoses,
        parameters=last.parameters(),
        correlations=weight_correlations(last),
        alternatives=found.alternatives,
        residuals=held.reports[last.name],
        final_check=found.diagnoses[last.name].base,
        figures=held.figures,
        data=_report_data(held.data),
        warnings=held.data.warnings,
        seconds=seconds,
        corrected=_corrected_parameters(summary["robot_file"]),
    )


def report_stage(
    held: HeldOut,
    found: SearchResult,
    *,
    threshold: float,
    rerun: bool,
    sysid: bool,
    t_start: float,
) -> dict[str, Any]:
    """Report stage: watch the error fall (step 5: every version's held-out error over its
    floor, the figures), the corrected robot file of a nominal MJCF start (step 6,
    :func:`~.sysid_refine.robot_file_step`), the verdict, ``summary.json`` and
    ``report.html``. Returns the summary (:func:`run_diagnosis`)."""
    versions, log, out, data = found.versions, held.log, held.out, held.data
    log("\n== 5. watch the error fall (held-out)")
    _error_table(held, versions)
    artefacts = _artefacts(held, versions, rerun)
    _final_diagnosis(held, found, threshold)
    robot_file = None
    if isinstance(data.start, NominalStart):
        from mcpilco.models.diagnosis.sysid_refine import robot_file_step

        log("\n== 6. the corrected robot file")
        robot_file = robot_file_step(versions[-1], data.train, data.test, out, sysid=sysid, log=log)
    summary = _summary(held, found, artefacts, robot_file)
    log(f"\nverdict: {summary['verdict']}")
    summary["seconds"] = time.perf_counter() - t_start
    report = _html_report(held, found, summary, time.perf_counter() - t_start)
    summary["report"] = str(report.write(out / "report.html"))
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=float))
    for text in data.warnings:  # repeated where the report ends
        log(f"warning: {text}")
    log(
        f"\nsummary: {out / 'summary.json'} ({summary['seconds']:.1f} s); "
        f"report: {summary['report']}"
    )
    return summary


@single_thread()  # the matrices are small: BLAS threads only wait for each other
def run_diagnosis(
    train: Sequence[str | Path],
    test: Sequence[str | Path] | None = None,
    *,
    model: str | Path | None = None,
    learned: tuple[str, str] | None = None,
    add: Sequence[str] = (),
    auto: int = 0,
    threshold: float = 5.0,
    max_points: int = 600,
    gip_iters: int = 100,
    include_root: str | Path | None = None,
    torque_constants: Sequence[float | None] | None = None,
    topic: str | None = None,
    current_topic: str | None = None,
    joint_map: Mapping[str, str] | None = None,
    out: str | Path = "results/diagnosis_run",
    plots: bool = True,
    rerun: bool = True,
    sysid: bool = True,
    log: Log = print,
) -> dict[str, Any]:
    """Run the diagnosis loop on files and write its outputs (module docstring): the load,
    fit, search and report stages in turn.

    Args:
        train: training files (CSV / Parquet, dataset schema; ROS 2 bag folders, ``.db3``
            and ``.mcap`` files of ``sensor_msgs/JointState``, :mod:`~.bags`).
        test: held-out files (default: split off the training files).
        model: nominal robot file (MJCF ``.xml`` or URDF); the start model unless
            ``learned`` is given.
        learned: ``(kind, joint_types)``, kind in ``LEARNED_STARTS`` (``"gip"``, ``"rbf"``),
            e.g. ``("gip", "RRPR")``: a learned start model.
        add: effects to add, e.g. ``["coulomb:2"]``.
        auto: add up to this many significant effects, best first.
        threshold: log-evidence threshold of a significant effect [nats].
        max_points: GP rows of a learned start.
        gip_iters: Adam iterations of a learned start's fit.
        include_root: folder the ``<include>`` files of ``model`` must lie in (None: the
            model's folder; :mod:`mcpilco.models.robot_files`).
        torque_constants: joint-side torque constants ``k_t`` [N m/A or N/A], one per joint,
            for current files; ``None``/``nan`` entries, or all when not given, are
            estimated (:mod:`~.units`).
        topic: the JointState topic of bag files (``None``: the bag's only one).
        current_topic: a bag topic of motor currents (``None``: the efforts are torques).
        joint_map: bag joint name -> the robot file's joint name, for names that differ
            (equal names pair by themselves).
        out: output folder (created).
        plots, rerun: write the PNG figures / the Rerun recording.
        sysid: refine the corrected robot file with ``mujoco.sysid`` (nominal MJCF start).
        log: receives the report, one block of text at a time.

    Returns:
        The summary written to ``out/summary.json``: ``versions``, ``heldout_rmse`` (one row
        per version), ``noise_floor`` (of the last version), ``rmse_over_floor`` (one row per
        version, each over its own floor), ``verdict`` (the last version's), ``diagnoses``,
        ``saved``, ``artefacts``, ``data_warnings``, ``torque_constants`` (current files
        in torque units: ``k_t`` per joint with its 95% interval; else ``None``),
        ``robot_file`` (the corrected robot file's record, or ``None``), ``seconds``,
        ``report`` (the path of ``report.html``).

    Raises:
        ValueError: bad input (no start model, unreadable or too short files, a joint count
            that differs from the model's, ``out`` a file, bad torque constants), with a
            message naming it.
    """
    t_start = time.perf_counter()
    check_options(auto, threshold, max_points, gip_iters)
    _require_start(model, learned)  # before the effects' names are read
    effects = [parse_effect(a) for a in add]
    start = start_model(model, learned, include_root, gip_iters)
    bag = BagOptions(topic, current_topic, dict(joint_map or {}))
    data = load_stage(start, train, test, bag, torque_constants, log)
    held = HeldOut(data, output_folder(out), plots, log)
    v0 = fit_stage(held, max_points)
    found = search_stage(held, v0, effects, auto, threshold)
    return report_stage(held, found, threshold=threshold, rerun=rerun, sysid=sysid, t_start=t_start)


def _corrected_parameters(record: dict | None) -> dict | None:
    """The report's corrected-parameter rows from :func:`~.sysid_refine.robot_file_step`'s
    record: each written MJCF attribute with the file's value, the diagnosis value and its
    95 % interval, the ``mujoco.sysid`` value where refined, and the free-run error of the
    three files (None: no corrected file in this run)."""
    if record is None or "skipped" in record:
        return None
    refined = {
        (p["element"], p["attribute"]): p["value"]
        for p in record.get("sysid", {}).get("parameters", [])
    }
    rows: dict = {}
    for c in record["written"]:
        rows[f"{c['element']} {c['attribute']}"] = {
            "file": c["before"],
            "diagnosis": c["after"],
            "ci95": c["ci95"],
            "mujoco.sysid": refined.get((c["element"], c["attribute"]), "-"),
            "effect": c["effect"],
        }
    for name, rmse in record.get("free_run", {}).items():
        if isinstance(rmse, list):
            rows[f"free-run q RMSE, {name} file [rad]"] = {
                "diagnosis": ", ".join(f"{x:.3g}" for x in rmse)
            }
    return rows
