"""Diagnose a robot model against measurements: compare, see where it fails, find the missing
physical effect, add it, watch the error fall (``mcpilco-diagnose``).

Example (data from ``python -m mcpilco.scripts.make_hidden_effect_data``)::

    mcpilco-diagnose --model results/hidden_effect/robot.xml \\
        --train results/hidden_effect/train_1.csv results/hidden_effect/train_2.csv \\
        --test results/hidden_effect/test_1.csv --auto 3 --out results/diagnosis_run

Start model: ``--model robot.xml`` (MJCF or URDF, nominal rigid-body physics), or
``--gip RRPR`` (a GIP GP learned on the training files) or ``--rbf RRPR`` (a black-box RBF GP;
the joint types set the joint count and which joints are angles); with a learned start
``--model`` only gives the payload candidate its regressor. Without ``--test`` the last
training file (or, with one file, its last 30%) is held out. ``--add coulomb:2`` adds an
effect (repeatable; keys: viscous, coulomb, stribeck, offset, spring, cogging, payload,
armature, deadzone, delay); ``--auto N`` adds up to N significant effects, best first
(missing effects before refinements inside a learned start's span).
Every version is saved as ``<out>/models/model_v<k>.json`` (never overwritten).

Outputs under ``--out``: ``compare_v<k>.png`` (measured vs predicted ±2σ),
``residuals_v<k>.png``, ``waterfall.png``, ``diagnosis.rrd`` (Rerun), ``summary.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from mcpilco.agents.common.cli import console_main


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="mcpilco-diagnose", description=__doc__.split("\n")[0].rstrip(",")
    )
    p.add_argument("--train", nargs="+", required=True, help="training files (.csv/.parquet)")
    p.add_argument("--test", nargs="*", default=None, help="held-out files")
    p.add_argument("--model", default=None, help="nominal robot file (MJCF .xml or URDF)")
    learned = p.add_mutually_exclusive_group()
    learned.add_argument(
        "--gip", default=None, metavar="JOINT_TYPES", help="learned GIP start, e.g. RRPR"
    )
    learned.add_argument(
        "--rbf", default=None, metavar="JOINT_TYPES", help="learned RBF start, e.g. RRPR"
    )
    p.add_argument("--add", action="append", default=[], metavar="EFFECT", help="e.g. coulomb:2")
    p.add_argument("--auto", type=int, default=0, metavar="N", help="add up to N effects")
    p.add_argument("--threshold", type=float, default=5.0, help="Δlog-evidence threshold [nats]")
    p.add_argument("--max-points", type=int, default=600, help="GP rows with a learned start")
    p.add_argument(
        "--gip-iters", type=int, default=100, help="Adam iterations of a learned start's fit"
    )
    p.add_argument("--out", default="results/diagnosis_run")
    p.add_argument("--no-plots", action="store_true")
    p.add_argument("--no-rerun", action="store_true")
    return p


@console_main("mcpilco-diagnose")
def main(argv: Sequence[str] | None = None) -> int:
    """Run the loop; returns 0, or 2 on bad input (one line naming the problem)."""
    return _run(build_parser().parse_args(argv))


def _run(args: argparse.Namespace) -> int:
    from mcpilco.models.diagnosis import (
        LEARNED_STARTS,
        DiagnosisModel,
        NominalStart,
        diagnose,
        fit_metrics,
        load_trajectories,
        metrics_table,
        noise_floor,
        parse_effect,
        residual_report,
    )
    from mcpilco.models.diagnosis.data import MIN_FIT_ROWS, MIN_HELDOUT_ROWS, require_rows

    t_start = time.perf_counter()
    learned = {k: getattr(args, k) for k in LEARNED_STARTS if getattr(args, k) is not None}
    if args.model is None and not learned:
        raise ValueError(
            "give a start model: --model robot.xml (nominal), or --gip RRPR / --rbf RRPR (learned)"
        )
    effects_to_add = [parse_effect(a) for a in args.add]
    if learned:
        ((kind, joint_types),) = learned.items()
        start = LEARNED_STARTS[kind](joint_types, robot=args.model, adam_iters=args.gip_iters)
    else:
        start = NominalStart(args.model)
    n = start.n_joints
    train = load_trajectories(args.train, n_joints=n)
    if args.test:
        test = load_trajectories(args.test, n_joints=n)
    elif train.n_segments >= 2:
        test = train.select([train.n_segments - 1])
        train = train.select(range(train.n_segments - 1))
        print(f"held out (whole file): {test.names[0]}")
    else:
        train, test = train.split_time(0.7)
        print(f"held out: the last 30% of {train.names[0]}")
    require_rows(train, MIN_FIT_ROWS, "fitting a diagnosis model")  # before any work
    require_rows(test, MIN_HELDOUT_ROWS, "confirming effects on held-out data")
    data_warnings = list(dict.fromkeys(train.warnings + test.warnings))
    for text in data_warnings:
        print(f"warning: {text}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} is a file; give a folder")
    out.mkdir(parents=True, exist_ok=True)
    unit = "A" if train.output == "i" else None

    model = DiagnosisModel(start, max_points=args.max_points).fit(train)
    print(f"\n== 1. compare: {model.describe()}")
    versions = [model]

    def compare(m: DiagnosisModel) -> dict:
        mean_tr, _ = m.predict(train, with_var=False)
        mean_te, var_te = m.predict(test)
        rows = [
            (m.name, "train", fit_metrics(train.y, mean_tr)),
            (m.name, "held-out", fit_metrics(test.y, mean_te)),
        ]
        return {"rows": rows, "mean": mean_te, "var": var_te}

    def where(m: DiagnosisModel, res: dict) -> None:
        rep = residual_report(
            test, res["mean"], None, start.joint_types, model_name=m.name, unit=unit
        )
        print(f"\n== 2. {rep.text()}")
        if not args.no_plots:
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
            print(f"   plots: {p1}  {p2}")

    res = {model.name: compare(model)}
    print(metrics_table(res[model.name]["rows"], n))
    where(model, res[model.name])
    print("\n== 3. which effect is missing")
    diag = diagnose(model, test, threshold=args.threshold)
    print(diag.table())
    diag_obj = {model.name: diag}

    print("\n== 4. add")
    for e in effects_to_add:
        model = model.add(e)
        versions.append(model)
        print(f"   {model.describe()}")
    for _ in range(args.auto):
        if model.name not in diag_obj:
            diag_obj[model.name] = diagnose(model, test, threshold=args.threshold)
            print(diag_obj[model.name].table(6))
        lead = diag_obj[model.name].lead  # the missing effect, else an in-span refinement
        if lead is None:
            break
        model = model.with_effect(lead.effect, backfit=True)
        versions.append(model)
        print(f"   {model.describe()}")
    saved = [str(v.save(out / "models")) for v in versions]
    print(f"   saved: {', '.join(saved)}")
    for v in versions:
        for p in v.parameters() if v is versions[-1] else []:
            print(f"   {v.name} {p['effect']} (joint {p['output']}): {p['text']}")

    print("\n== 5. watch the error fall (held-out)")
    for v in versions[1:]:
        res[v.name] = compare(v)
    held = np.array([res[v.name]["rows"][1][2]["rmse"] for v in versions])
    noise = noise_floor(test, res[versions[-1].name]["mean"])
    head = f"{'version':<8}" + "".join(f"{'RMSE j' + str(j + 1):>12}" for j in range(n))
    print(head + "   effects")
    for v, r in zip(versions, held, strict=True):
        added = ", ".join(e.variant_label for e in v.effects) or "-"
        print(f"{v.name:<8}" + "".join(f"{x:>12.4g}" for x in r) + f"   {added}")
    print(f"{'noise':<8}" + "".join(f"{x:>12.4g}" for x in noise) + "   (noise floor)")
    if len(versions) > 1:
        print(metrics_table([res[v.name]["rows"][1] for v in versions], n))
    artefacts = {}
    if not args.no_plots:
        from mcpilco.models.diagnosis.plots import plot_waterfall

        artefacts["waterfall"] = str(
            plot_waterfall(
                [v.name for v in versions],
                held,
                versions[-1].noise_std_,
                out / "waterfall.png",
                labels=[
                    v.describe().split(": ", 1)[0]
                    + " "
                    + (", ".join(e.label for e in v.effects) or "start")
                    for v in versions
                ],
            )
        )
    if not args.no_rerun:
        from mcpilco.models.diagnosis.plots import write_rerun

        artefacts["rerun"] = str(
            write_rerun(
                out / "diagnosis.rrd", test, {v.name: res[v.name]["mean"] for v in versions}
            )
        )
    for k, p in artefacts.items():
        print(f"   {k}: {p}")
    if len(versions) > 1:
        last = versions[-1]
        where(last, res[last.name])
        if last.name not in diag_obj:
            diag_obj[last.name] = diagnose(last, test, threshold=args.threshold)
            print(diag_obj[last.name].table(6))
        else:
            print(diag_obj[last.name].verdict())
    summary = {
        "versions": [v.describe() for v in versions],
        "heldout_rmse": held.tolist(),
        "noise_floor": noise.tolist(),
        "diagnoses": {k: d.to_dict() for k, d in diag_obj.items()},
        "saved": saved,
        "artefacts": artefacts,
        "data_warnings": data_warnings,
        "seconds": time.perf_counter() - t_start,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=float))
    for text in data_warnings:  # repeated where the report ends
        print(f"warning: {text}")
    print(f"\nsummary: {out / 'summary.json'} ({summary['seconds']:.1f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
