"""Diagnose a robot model against measurements: compare, see where it fails, find the missing
physical effect, add it, watch the error fall (``mcpilco-diagnose``).

Example (data from ``python -m mcpilco.scripts.make_hidden_effect_data``)::

    mcpilco-diagnose --model results/hidden_effect/robot.xml \\
        --train results/hidden_effect/train_1.csv results/hidden_effect/train_2.csv \\
        --test results/hidden_effect/test_1.csv --auto 3 --out results/diagnosis_run

Start model: ``--model robot.xml`` (MJCF or URDF, nominal rigid-body physics), or
``--gip RRPR`` (a GIP GP learned on the training files) or ``--rbf RRPR`` (a black-box RBF GP;
the joint types set the joint count and which joints are angles); with a learned start
``--model`` only gives the inertial candidates their regressor. Without ``--test`` the last
training file (or, with one file, its last 30%) is held out. ``--add coulomb:2`` adds an
effect (repeatable; keys: viscous, coulomb, stribeck, offset, spring, cogging, payload,
inertia (``inertia:2``: link 2), armature, deadzone, delay); ``--auto N`` adds up to N
significant effects, best first (missing effects before refinements inside a learned
start's span).
Files of motor currents (``i1..in`` instead of ``tau1..taun``) are put into torque units
with ``--torque-constants K1 K2 ...`` (N m/A per joint, negative for a reversed motor;
``nan`` for a joint whose constant is to be estimated), or, without it, with constants
estimated per joint against ``--model``.
ROS 2 bags (a bag folder, ``.db3`` or ``.mcap`` file; ``pip install mcpilco[logs]``) are
read as measurement files: ``sensor_msgs/JointState`` of ``--topic`` (position, velocity,
effort), the motor currents of ``--current-topic``, bag joints paired with the robot file's
joints by name or by ``--joint-map bag_name=joint`` / ``--joint-map-file map.yaml``, resampled
onto a uniform time grid (:mod:`mcpilco.models.diagnosis.bags`).
Every version is saved as ``<out>/models/model_v<k>.json`` (never overwritten).

Outputs under ``--out``: ``compare_v<k>.png`` (measured vs predicted ±2σ),
``residuals_v<k>.png``, ``waterfall.png``, ``diagnosis.rrd`` (Rerun), ``summary.json``,
``report.html`` (one self-contained file: tables, figures, verdict, residual structure);
with an MJCF ``--model`` and torque logs also ``corrected.xml`` (the effects found written
back as MuJoCo physics), ``corrected_effects.json`` (what was written, and the effects MuJoCo
cannot express, with their 95% intervals) and ``refined.xml`` (refined by ``mujoco.sysid``;
``--no-sysid`` skips it), with the free-run error of each file on the held-out files.
The loop is :func:`mcpilco.models.diagnosis.run_diagnosis`.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from mcpilco.agents.common.cli import console_main, number_arg


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="mcpilco-diagnose", description=__doc__.split("\n")[0].rstrip(",")
    )
    p.add_argument(
        "--train", nargs="+", required=True, help="training files (.csv/.parquet, ROS 2 bags)"
    )
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
    p.add_argument(
        "--auto",
        type=number_arg(0, 100, integer=True),
        default=0,
        metavar="N",
        help="add up to N effects",
    )
    p.add_argument(
        "--threshold", type=number_arg(0, 1e6), default=5.0, help="Δlog-evidence threshold [nats]"
    )
    p.add_argument(
        "--max-points",
        type=number_arg(10, 100_000, integer=True),
        default=600,
        help="GP rows with a learned start",
    )
    p.add_argument(
        "--gip-iters",
        type=number_arg(0, 1_000_000, integer=True),
        default=100,
        help="Adam iterations of a learned start's fit",
    )
    p.add_argument(
        "--torque-constants",
        nargs="+",
        type=float,  # nan: estimate the joint's constant (checked by run_diagnosis)
        default=None,
        metavar="K",
        help="k_t per joint [N m/A] for current files; nan: estimate it (default: all)",
    )
    p.add_argument(
        "--include-root",
        default=None,
        metavar="FOLDER",
        help="folder the <include> files of --model may lie in (default: the model's folder)",
    )
    p.add_argument(
        "--topic", default=None, help="JointState topic of bag files (default: the only one)"
    )
    p.add_argument(
        "--current-topic", default=None, help="bag topic of motor currents [A] (JointState effort)"
    )
    p.add_argument(
        "--joint-map",
        nargs="+",
        default=[],
        metavar="BAG=JOINT",
        help="pair bag joint names with the robot file's (names that match pair by themselves)",
    )
    p.add_argument(
        "--joint-map-file", default=None, help="YAML file of bag_name: model_joint pairs"
    )
    p.add_argument("--out", default="results/diagnosis_run")
    p.add_argument("--no-plots", action="store_true")
    p.add_argument("--no-rerun", action="store_true")
    p.add_argument(
        "--no-sysid",
        action="store_true",
        help="write corrected.xml but skip its mujoco.sysid refinement (refined.xml)",
    )
    return p


@console_main("mcpilco-diagnose")
def main(argv: Sequence[str] | None = None) -> int:
    """Run the loop; returns 0, or 2 on bad input (one line naming the problem)."""
    args = build_parser().parse_args(argv)
    from mcpilco.envs.yaml_files import read_yaml
    from mcpilco.models.diagnosis import run_diagnosis
    from mcpilco.models.diagnosis.bags import check_joint_map, parse_joint_map

    joint_map = (
        check_joint_map(read_yaml(args.joint_map_file, "joint map"), args.joint_map_file)
        if args.joint_map_file
        else {}
    )
    joint_map.update(parse_joint_map(args.joint_map))

    learned = next(
        ((k, getattr(args, k)) for k in ("gip", "rbf") if getattr(args, k) is not None), None
    )
    run_diagnosis(
        args.train,
        args.test,
        model=args.model,
        learned=learned,
        add=args.add,
        auto=args.auto,
        threshold=args.threshold,
        max_points=args.max_points,
        gip_iters=args.gip_iters,
        include_root=args.include_root,
        torque_constants=args.torque_constants,
        topic=args.topic,
        current_topic=args.current_topic,
        joint_map=joint_map,
        out=args.out,
        plots=not args.no_plots,
        rerun=not args.no_rerun,
        sysid=not args.no_sysid,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
