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
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.models.gp.linear_gp import single_thread


@single_thread()  # the matrices are small: BLAS threads only wait for each other
def _is_number(value: Any, integer: bool) -> bool:
    """Whether ``value`` is a finite number (an integer with ``integer``), not a boolean."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return False
    return math.isfinite(value) and (not integer or int(value) == value)


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
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Run the diagnosis loop on files and write its outputs (module docstring).

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
    from mcpilco.models.diagnosis import (
        LEARNED_STARTS,
        DiagnosisModel,
        NominalStart,
        diagnose,
        fit_metrics,
        heldout_floor,
        load_trajectories,
        metrics_table,
        parse_effect,
        residual_report,
        stepwise,
    )
    from mcpilco.models.diagnosis.bags import BagOptions
    from mcpilco.models.diagnosis.data import (
        MIN_FIT_ROWS,
        MIN_HELDOUT_ROWS,
        require_motion,
        require_rows,
    )
    from mcpilco.models.diagnosis.html_report import DiagnosisReport, weight_correlations
    from mcpilco.models.diagnosis.start_models import read_robot_text
    from mcpilco.models.diagnosis.units import check_angle_units, currents_to_torque

    t_start = time.perf_counter()
    for name, value, integer in (
        ("auto", auto, True),
        ("threshold", threshold, False),
        ("max_points", max_points, True),
        ("gip_iters", gip_iters, True),
    ):
        if not _is_number(value, integer) or value < (10 if name == "max_points" else 0):
            low = 10 if name == "max_points" else 0
            raise ValueError(f"{name} must be a finite number >= {low}, got {value!r}")
    if model is None and learned is None:
        raise ValueError(
            "give a start model: --model robot.xml (nominal), or --gip RRPR / --rbf RRPR (learned)"
        )
    effects_to_add = [parse_effect(a) for a in add]
    # the robot file read once, its includes confined to its folder (or include_root)
    robot = None if model is None else read_robot_text(model, include_root)
    if learned is not None:
        kind, joint_types = learned
        if kind not in LEARNED_STARTS:
            raise ValueError(f"learned start must be one of {sorted(LEARNED_STARTS)}, got {kind!r}")
        start = LEARNED_STARTS[kind](joint_types, robot=robot, adam_iters=gip_iters)
    else:
        start = NominalStart(robot, name=str(model))
    n = start.n_joints
    robot = getattr(start, "robot", None)  # the robot file's joint names pair bag joints
    bag = BagOptions(topic, current_topic, dict(joint_map or {}))
    names = None if robot is None else list(robot.model.names)[1:]
    train = load_trajectories(train, n_joints=n, bag=bag, joint_names=names)
    if test:
        test = load_trajectories(test, n_joints=n, bag=bag, joint_names=names)
    elif train.n_segments >= 2:
        test = train.select([train.n_segments - 1])
        train = train.select(range(train.n_segments - 1))
        log(f"held out (whole file): {test.names[0]}")
    else:
        train, test = train.split_time(0.7)
        log(f"held out: the last 30% of {train.names[0]}")
    require_rows(train, MIN_FIT_ROWS, "fitting a diagnosis model")  # before any work
    require_motion(train)
    require_rows(test, MIN_HELDOUT_ROWS, "confirming effects on held-out data")
    check_angle_units(start, train)  # a joint logged in degrees throughout
    check_angle_units(start, test)
    data_warnings = list(dict.fromkeys(train.warnings + test.warnings))
    for text in data_warnings:
        log(f"warning: {text}")
    filters = zip(train.names + test.names, train.estimated + test.estimated, strict=False)
    for name, est in dict(filters).items():
        if est is not None:
            log(f"{name}: {' and '.join(est.groups)} estimated from q by {est.filter.name}")
    train, test, constants = currents_to_torque(train, test, start, torque_constants)
    train, test = train.interior(), test.interior()  # without the derivative filter's edges
    if constants is not None:
        log(f"\n== 0. units: {constants.text()}")
    elif train.output == "i":
        log("\n== 0. units: currents without torque constants; the loop works in A")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} is a file; give a folder")
    out.mkdir(parents=True, exist_ok=True)
    unit: str | list[str | None] | None = "A" if train.output == "i" else None
    if constants is not None and constants.in_current.any():  # k_t not identifiable: in A
        unit = ["A" if c else None for c in constants.in_current]

    scales = [] if constants is None else constants.effects()  # k_t still free (.units)
    model = DiagnosisModel(start, scales, max_points=max_points).fit(train)
    log(f"\n== 1. compare: {model.describe()}")
    versions = [model]

    def compare(m: DiagnosisModel) -> dict:
        mean_tr, _ = m.set_valued(train, m.predict(train, with_var=False)[0])
        raw_te, var_te = m.predict(test)
        mean_te, _ = m.set_valued(test, raw_te)  # dry friction at rest: set-valued
        rows = [
            (m.name, "train", fit_metrics(train.y, mean_tr)),
            (m.name, "held-out", fit_metrics(test.y, mean_te)),
        ]
        return {"rows": rows, "mean": mean_te, "raw": raw_te, "var": var_te}

    floors: dict[str, np.ndarray] = {}
    reports: dict[str, Any] = {}  # version name -> its held-out ResidualReport
    figures: list[tuple[str, Path]] = []  # (caption, PNG) for the HTML report

    def floor(m: DiagnosisModel) -> np.ndarray:
        if m.name not in floors:
            floors[m.name] = heldout_floor(m, test, res[m.name]["raw"])
        return floors[m.name]

    def where(m: DiagnosisModel, res: dict) -> None:
        rep = residual_report(
            test, res["mean"], floor(m), start.joint_types, model_name=m.name, unit=unit
        )
        reports[m.name] = rep
        log(f"\n== 2. {rep.text()}")
        if plots:
            from mcpilco.models.diagnosis.plots import plot_residuals, plot_time

            p1 = plot_time(
                test,
                res["mean"],
                res["var"],
                m.noise_std_,
                out / f"compare_{m.name}.png",
                title=m.describe(),
            )
            p2 = plot_residuals(rep, out / f"residuals_{m.name}.png")
            figures.extend([(f"held-out, {m.describe()}", p1), (f"residuals of {m.name}", p2)])
            log(f"   plots: {p1}  {p2}")

    res = {model.name: compare(model)}
    log(metrics_table(res[model.name]["rows"], n))
    where(model, res[model.name])
    log("\n== 3. which effect is missing")
    diag = diagnose(model, test, threshold=threshold)
    log(diag.table())
    diag_obj = {model.name: diag}

    log("\n== 4. add")
    for e in effects_to_add:
        model = model.add(e)
        versions.append(model)
        log(f"   {model.describe()}")
    alternatives: dict[str, str] = {}  # never added beside the effect they stand for
    removals: list[Any] = []  # backward elimination (search.backward_step)
    for _ in range(auto):
        if model.name not in diag_obj:
            diag_obj[model.name] = diagnose(
                model, test, threshold=threshold, alternatives=alternatives
            )
            log(diag_obj[model.name].table(6))
        if diag_obj[model.name].lead is None:  # no missing effect nor in-span refinement
            break
        steps = stepwise(  # add the lead, remove what it superseded
            model, diag_obj[model.name], test, alternatives, threshold=threshold
        )
        for new, removal in steps:
            versions.append(new)
            if removal is not None:
                removals.append(removal)
                log(f"   {removal.text()}")
            log(f"   {new.describe()}")
        model = versions[-1]
    saved = [str(v.save(out / "models")) for v in versions]
    log(f"   saved: {', '.join(saved)}")
    for v in versions:
        for p in v.parameters(shape=True) if v is versions[-1] else []:
            log(f"   {v.name} {p['effect']} (joint {p['output']}): {p['text']}")

    log("\n== 5. watch the error fall (held-out)")
    for v in versions[1:]:
        res[v.name] = compare(v)
    held = np.array([res[v.name]["rows"][1][2]["rmse"] for v in versions])
    noise = floor(versions[-1])
    ratios = np.array([r / floor(v) for v, r in zip(versions, held, strict=True)])
    head = f"{'version':<8}" + "".join(f"{'RMSE j' + str(j + 1):>12}" for j in range(n))
    log(head + "   effects")
    for v, r in zip(versions, held, strict=True):
        added = ", ".join(e.variant_label for e in v.effects) or "-"
        log(f"{v.name:<8}" + "".join(f"{x:>12.4g}" for x in r) + f"   {added}")
    log(
        f"{'floor':<8}"
        + "".join(f"{x:>12.4g}" for x in noise)
        + "   (noise floor: measurement + estimated qd/qdd)"
    )
    for v, r in zip(versions, ratios, strict=True):
        log(f"{v.name:<8}" + "".join(f"{x:>11.2f}x" for x in r) + "   (RMSE / floor)")
    if len(versions) > 1:
        log(metrics_table([res[v.name]["rows"][1] for v in versions], n))
    artefacts = {}
    if plots:
        from mcpilco.models.diagnosis.plots import plot_waterfall

        artefacts["waterfall"] = str(
            plot_waterfall(
                [v.name for v in versions],
                held,
                noise,
                out / "waterfall.png",
                labels=[
                    v.describe().split(": ", 1)[0]
                    + " "
                    + (", ".join(e.label for e in v.effects) or "start")
                    for v in versions
                ],
            )
        )
    if rerun:
        from mcpilco.models.diagnosis.plots import write_rerun

        artefacts["rerun"] = str(
            write_rerun(
                out / "diagnosis.rrd", test, {v.name: res[v.name]["mean"] for v in versions}
            )
        )
    for k, p in artefacts.items():
        log(f"   {k}: {p}")
    if "waterfall" in artefacts:
        figures.append(
            ("held-out RMSE per version over the noise floor", Path(artefacts["waterfall"]))
        )
    if len(versions) > 1:
        last = versions[-1]
        where(last, res[last.name])
        if last.name not in diag_obj:
            diag_obj[last.name] = diagnose(
                last, test, threshold=threshold, alternatives=alternatives
            )
            log(diag_obj[last.name].table(6))
    robot_file = None
    if isinstance(start, NominalStart):
        from mcpilco.models.diagnosis.sysid_refine import robot_file_step

        log("\n== 6. the corrected robot file")
        robot_file = robot_file_step(versions[-1], train, test, out, sysid=sysid, log=log)
    removed = {r.version: f" (removed {r.variant}: its evidence taken by {r.by})" for r in removals}
    final = diag_obj[versions[-1].name].verdict()
    log(f"\nverdict: {final}")
    summary = {
        "versions": [v.describe() + removed.get(v.name, "") for v in versions],
        "heldout_rmse": held.tolist(),
        "noise_floor": noise.tolist(),
        "rmse_over_floor": ratios.tolist(),
        "verdict": final,
        "diagnoses": {k: d.to_dict() for k, d in diag_obj.items()},
        "saved": saved,
        "artefacts": artefacts,
        "data_warnings": data_warnings,
        "robot_file": robot_file,
        "torque_constants": None if constants is None else constants.to_dict(),
        "removed": [r.to_dict() for r in removals],
        "seconds": time.perf_counter() - t_start,
    }
    report = DiagnosisReport(
        title=f"Model diagnosis: {versions[-1].start.describe()}",
        verdict=final,
        versions=summary["versions"],
        heldout_rmse=held,
        floors=np.array([floor(v) for v in versions]),
        metrics=[row for v in versions for row in res[v.name]["rows"]],
        diagnoses=diag_obj,
        parameters=versions[-1].parameters(),
        correlations=weight_correlations(versions[-1]),
        alternatives=alternatives,
        residuals=reports[versions[-1].name],
        final_check=diag_obj[versions[-1].name].base,
        figures=figures,
        data={
            "training files": train.names,
            "held-out files": test.names,
            "rows (training, held-out)": f"{train.n_samples}, {test.n_samples}",
            "sample time": f"{train.sample_time:g} s",
            "output": "motor current i [A]" if train.output == "i" else "joint torque tau",
            **({} if constants is None else {"torque constants": constants.text()}),
            **{
                f"joint {j + 1} in A": f"torque constant not identifiable: {why}"
                for j, why in enumerate(() if constants is None else constants.reasons)
                if why is not None
            },
        },
        warnings=data_warnings,
        seconds=time.perf_counter() - t_start,
        corrected=_corrected_parameters(robot_file),
    )
    summary["report"] = str(report.write(out / "report.html"))
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=float))
    for text in data_warnings:  # repeated where the report ends
        log(f"warning: {text}")
    log(
        f"\nsummary: {out / 'summary.json'} ({summary['seconds']:.1f} s); "
        f"report: {summary['report']}"
    )
    return summary


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
