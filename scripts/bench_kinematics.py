"""Kinematics learning benchmark: structure identification, FK GP, kinematic controller (ch. 2).

Parts (thesis section 2.6; what each does: :mod:`mcpilco.experiments.kinematics.parts`):
(a) Monte Carlo over random noiseless robots (Fig. 2.4), (b) misclassified triplets against
the number of noisy UR10 samples (Fig. 2.6), (c) the FK GP on the UR10 (Table 2.1), (d) the
kinematic controller with online refits (Table 2.2). ``--fk-seeds`` runs part (c) alone on
each seed and writes ``kinematics_c_seeds.{json,md}``; ``--reaching-seeds`` runs MC-PILCO
reaching through the learned kinematics against the controller of (d) on each seed
(:mod:`mcpilco.experiments.kinematics.reaching`) and writes ``kinematics_reaching.{json,md,png}``.

Outputs (``--out-dir``, default ``results/``; ``--merge`` keeps the parts not run from an
existing ``kinematics.json``): ``kinematics.json``, ``kinematics_confusion.png``,
``kinematics_noise_vs_samples.png``, ``kinematics_controller.png`` and ``kinematics.md``.

Examples::

    mcpilco-bench-kinematics                       # full run (about 30 min on 2 cores)
    mcpilco-bench-kinematics --quick               # smoke run (1-2 min)
    mcpilco-bench-kinematics --parts a --robots 16
    mcpilco-bench-kinematics --parts cd --merge
    mcpilco-bench-kinematics --reaching-seeds 300 301 302 --jobs 2
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

import torch

from mcpilco.agents.common.cli import console_main
from mcpilco.experiments.infra.sweep import SweepError, add_sweep_arguments, runner_from_args
from mcpilco.experiments.kinematics.bench import (
    KinematicsBenchSettings,
    run_benchmark,
    run_fk_seed_study,
)
from mcpilco.experiments.kinematics.parts import (
    FK_MODELS,
    REFINE_CHOICES,
    TRAIN_SELECTIONS,
)
from mcpilco.experiments.kinematics.reaching import reaching_markdown, reaching_study
from mcpilco.experiments.kinematics.report import fk_seed_markdown, markdown_report

DEFAULTS = KinematicsBenchSettings()


def _optional_degrees(text: str) -> float | None:
    """``"none"`` -> None, else a float angle in (0, 180] deg (argparse type)."""
    if text.lower() == "none":
        return None
    value = float(text)
    if not 0 < value <= 180:
        raise argparse.ArgumentTypeError(f"an angle in (0, 180] deg or 'none', got {text}")
    return value


def _parser() -> argparse.ArgumentParser:
    d = DEFAULTS
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--parts", default=d.parts, help="subset of 'abcd' to run")
    p.add_argument("--robots", type=int, default=d.robots, help="(a) Monte Carlo robots")
    p.add_argument(
        "--samples", type=int, default=d.samples, help="(b-d) frames per UR10 trajectory"
    )
    p.add_argument(
        "--sizes", type=int, nargs="+", default=list(d.sizes),
        help="(b) prefixes of the trajectory",
    )  # fmt: skip
    p.add_argument("--repeats", type=int, default=d.repeats, help="(b) trajectories")
    p.add_argument("--fk-train", type=int, default=d.fk_train, help="(c) training samples")
    p.add_argument("--ctrl-train", type=int, default=d.ctrl_train, help="(d) training samples")
    p.add_argument(
        "--train-selection", choices=TRAIN_SELECTIONS, default=d.train_selection,
        help="(c) training samples of D_tr: greedy design by the prior variance of k_l "
        "(default) or uniformly at random (thesis)",
    )  # fmt: skip
    p.add_argument(
        "--ctrl-selection", choices=TRAIN_SELECTIONS, default=d.ctrl_selection,
        help="(d) initial training samples of D_tr, as --train-selection (default random)",
    )  # fmt: skip
    p.add_argument(
        "--ctrl-model", choices=FK_MODELS, default=d.ctrl_model,
        help="(d) FK model: the thesis' GP on the end marker (default) or the chain of "
        "one-joint GPs on every marker (ChainForwardKinematicsGP)",
    )  # fmt: skip
    p.add_argument("--online-rounds", type=int, default=d.online_rounds,
                   help="(d) refits with new data")  # fmt: skip
    p.add_argument("--ctrl-steps", type=int, default=d.ctrl_steps, help="(d) controller updates")
    p.add_argument(
        "--ctrl-starts", type=int, default=d.ctrl_starts,
        help="(d) data configurations nearest to the target tried as extra starts (0: thesis)",
    )  # fmt: skip
    p.add_argument(
        "--ctrl-unlimited", action="store_true",
        help="(d) do not clip q_des to the joint box of the training data (thesis)",
    )  # fmt: skip
    p.add_argument(
        "--ctrl-orientation", choices=("ypr", "chordal"), default=d.ctrl_orientation,
        help="(d) orientation error in e_p: wrapped yaw-pitch-roll (thesis) or chordal",
    )  # fmt: skip
    p.add_argument(
        "--ctrl-refine", choices=REFINE_CHOICES, default=d.ctrl_refine,
        help="(d) online rounds: refine the previous reference, search again, or both",
    )  # fmt: skip
    p.add_argument(
        "--ctrl-hold", type=int, default=d.ctrl_hold,
        help="(d) extra frames measured at rest at each reached reference (added to the data)",
    )  # fmt: skip
    p.add_argument(
        "--rotation-outputs", choices=("five", "nine"), default=d.rotation_outputs,
        help="(d) GP rotation outputs: five elements + eq. 2.20 (thesis) or nine + SO(3)",
    )  # fmt: skip
    p.add_argument("--span", type=float, default=d.span, help="(b-d) waypoints: home +- span rad")
    p.add_argument(
        "--facing-cone", type=_optional_degrees, default=d.facing_cone,
        help=f"(b-d) markers attached facing the camera at home within this angle [deg] "
        f"(default {d.facing_cone:g}; 'none': uniformly random orientations)",
    )  # fmt: skip
    p.add_argument(
        "--visibility-cone", type=_optional_degrees, default=d.visibility_cone,
        help=f"(b-d) markers turned further from the camera are not seen, and waypoints and "
        f"targets show every marker (default {d.visibility_cone:g}; 'none': every marker seen "
        "from any side)",
    )  # fmt: skip
    p.add_argument(
        "--noise-scale", type=float, default=d.noise_scale,
        help="(c, d) multiply the env's default marker position and angle noise (sensitivity)",
    )  # fmt: skip
    p.add_argument(
        "--measurement", choices=("ideal", "aruco"), default=d.measurement,
        help="(c) marker poses from the env's noise model, or rendered + ArUco detection "
        "(needs OpenCV and MUJOCO_GL=egl/osmesa)",
    )  # fmt: skip
    p.add_argument(
        "--fk-seeds", type=int, nargs="+", default=None,
        help="part (c) alone over these seeds: writes kinematics_c_seeds.{json,md} (per-seed "
        "RMSEs, mean and range, seeds meeting the goal) instead of the other outputs",
    )  # fmt: skip
    p.add_argument(
        "--reaching-seeds", type=int, nargs="+", default=None,
        help="MC-PILCO reaching vs the gradient controller over these seeds (5 targets, "
        "--online-rounds refits each): writes kinematics_reaching.{json,md,png}",
    )  # fmt: skip
    p.add_argument(
        "--merge", action="store_true",
        help="keep the results of the parts not run from an existing kinematics.json in --out-dir",
    )  # fmt: skip
    p.add_argument("--seed", type=int, default=d.seed)
    p.add_argument("--quick", action="store_true", help="tiny sizes for a smoke run")
    p.add_argument("--out-dir", default="results")
    p.add_argument(
        "--runs-dir",
        default="runs/bench_kinematics",
        help="--fk-seeds, --reaching-seeds: one result file per seed (reused by a later call, "
        "same options)",
    )
    p.add_argument("--no-progress", action="store_true")
    add_sweep_arguments(p)  # --jobs N (local processes), --ray [ADDRESS]: the --fk-seeds seeds
    return p


@console_main("mcpilco-bench-kinematics")
def main(argv: list[str] | None = None) -> int:
    """Command-line entry point; returns 0 (1 when a seed of ``--fk-seeds`` failed)."""
    parser = _parser()
    args = parser.parse_args(argv)
    fields = {f.name for f in dataclasses.fields(KinematicsBenchSettings)}
    options = {k: v for k, v in vars(args).items() if k in fields}
    try:
        settings = KinematicsBenchSettings(**{**options, "sizes": tuple(args.sizes)})
        if args.quick:
            settings = settings.quick()
    except ValueError as err:
        parser.error(str(err))
    seeds_studies = args.fk_seeds is not None or args.reaching_seeds is not None
    if seeds_studies and (settings.measurement != "ideal" or args.merge):
        parser.error("--fk-seeds and --reaching-seeds use the noise model alone (no --merge)")
    progress = not args.no_progress
    try:
        runner = runner_from_args(args, progress=progress)
    except SweepError as err:
        parser.error(str(err))
    torch.set_num_threads(1)
    command = " ".join(["mcpilco-bench-kinematics", *(sys.argv[1:] if argv is None else argv)])
    if args.fk_seeds is not None:
        try:
            study = run_fk_seed_study(settings, args.fk_seeds, args.out_dir, command, runner,
                                      args.runs_dir, progress)  # fmt: skip
        except RuntimeError as err:  # a seed failed: the others are kept for the next call
            print(err, file=sys.stderr)
            return 1
        print(fk_seed_markdown(study, command))
        return 0
    if args.reaching_seeds is not None:
        try:
            study = reaching_study(
                args.reaching_seeds, args.out_dir, command, runner, args.runs_dir,
                samples=settings.samples, n_train=settings.ctrl_train,
                rounds=settings.online_rounds, hold=settings.ctrl_hold,
            )  # fmt: skip
        except RuntimeError as err:
            print(err, file=sys.stderr)
            return 1
        print(reaching_markdown(study))
        return 0
    res = run_benchmark(settings, args.out_dir, command, args.merge, progress)
    print(markdown_report(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
