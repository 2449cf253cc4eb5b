"""Compare MC-PILCO with PILCO and SB3 SAC / TD3 / PPO (console script ``mcpilco-compare``).

Runs (or collects) every method over S seeds on one registered task env and writes
``results/compare_<env>[_<tag>].json``, a Markdown table (``.md``) and one PNG: success rate
vs seconds of experience (log x-axis), one curve per method, mean over seeds with a band of
+-1 standard error of the mean.

Glossary
--------
experience ``T``
    seconds of real interaction: every env step taken (exploration included) x the control
    period (0.05 s on the cartpoles; ``3 (k + 1)`` s after trial ``k`` there, fewer on a
    task whose episodes end early, such as InvertedPendulum-v5).
``p_m(T)``
    success rate of method ``m`` at ``T``: mean over seeds of each seed's last evaluation at
    or before ``T`` (sample and hold; 0 before its first evaluation), up to the shortest
    seed's budget. An evaluation is the trial's episode (MC-PILCO / PILCO) or 10
    deterministic episodes (SB3); success = ``info["success"]`` at the end of the episode.
``T90_m``
    the first ``T`` with ``p_m(T) >= 0.9`` (headline); when never reached, only
    ``T90_m > T_max`` (the budget) is known. ``T100_m``: the first ``T`` at which every
    seed's last evaluation succeeds (e.g. 10 of 10 seeds balance).
ratio
    ``T90_m / T90_MC-PILCO``: how much more experience method ``m`` needs. The report checks
    two targets: ratio >= 100 for the best SB3 method and > 1 for PILCO.

Where results come from, per method and seed: ``RUNS/<env>/<method>/seed<s>/curve.json``
when it exists and covers the budget; otherwise the run is started (or resumed from its
checkpoint). ``--collect-only`` runs nothing. ``--mcpilco-json`` takes MC-PILCO's
per-seed successes from ``mcpilco-bench-mcpilco``'s JSON instead of running it.
``--inputs`` adds learning-curve files (``mcpilco-curve/1`` format, or a compare JSON).

Usage::

    mcpilco-compare --seeds 5 --jobs 2                             # all methods, full budgets
    mcpilco-compare --methods sac td3 --seeds 10 --ray auto        # on a Ray cluster
    mcpilco-compare --methods mcpilco sac --seeds 3 --steps sac=30000
    mcpilco-compare --env mcpilco/DMCCartpoleSwingUp-v0 --methods ppo --steps 50000
    mcpilco-compare --collect-only --inputs a.json b.json --tag mine
"""

from __future__ import annotations

import argparse
import datetime
import shlex
import sys
from pathlib import Path
from typing import Any

from mcpilco.agents.baselines.common import check_task_env, load_curves
from mcpilco.agents.baselines.compare import METHODS
from mcpilco.agents.baselines.pilco import OPTIMIZERS
from mcpilco.agents.baselines.sb3 import HYPERPARAMS
from mcpilco.agents.common.cli import console_main
from mcpilco.agents.common.trials import DEFAULT_ENV_ID
from mcpilco.envs.yaml_files import parse_overrides
from mcpilco.experiments.infra.sweep import SweepError, add_sweep_arguments, runner_from_args
from mcpilco.experiments.mcpilco.compare import (
    compare,
    markdown,
    parse_sb3_hp,
    parse_steps,
    write_report,
)


def recorded_command_line(argv: list[str]) -> str:
    """The command line a report records: ``argv`` without ``--note``'s text (the report
    holds it)."""
    kept, skip = [], False
    for token in argv:
        if skip:
            skip = False
        elif token == "--note":
            skip = True
        elif not token.startswith("--note="):
            kept.append(token)
    return shlex.join(["mcpilco-compare", *kept])


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="mcpilco-compare", description=__doc__, formatter_class=argparse.RawTextHelpFormatter
    )
    p.add_argument("--env", default=DEFAULT_ENV_ID, help="registered env id with a task")
    p.add_argument(
        "--methods", nargs="+", default=list(METHODS), help=f"any of {', '.join(METHODS)}"
    )
    p.add_argument("--seeds", type=int, default=5, help="number of seeds S (first-seed ... )")
    p.add_argument("--first-seed", type=int, default=0)
    p.add_argument(
        "--steps",
        nargs="+",
        help="SB3 budget in env steps: N (all) or ALGO=N; "
        "default sac=200000 td3=200000 ppo=1000000",
    )
    p.add_argument(
        "--eval-every", type=int, default=2000, help="K: SB3 env steps between evaluations"
    )
    p.add_argument("--eval-episodes", type=int, default=10, help="episodes per SB3 evaluation")
    p.add_argument(
        "--sb3-preset",
        choices=sorted(HYPERPARAMS),
        help="rl-baselines3-zoo hyper-parameter set (default: the env's in "
        "agents/baselines/conf/sb3.yaml; SB3's defaults for an env without one)",
    )
    p.add_argument(
        "--sb3-hp", nargs="+", help="override ALGO.KEY=VALUE (e.g. sac.learning_starts=1000)"
    )
    p.add_argument(
        "--trials", type=int, help="MC-PILCO / PILCO policy trials (default: bench preset, 4)"
    )
    p.add_argument(
        "--mcpilco-preset",
        help="preset of the env's MC-PILCO config file (default: its bench preset if any)",
    )
    p.add_argument(
        "--mcpilco-set",
        nargs="+",
        metavar="KEY=VALUE",
        help="override MC-PILCO config fields (as mcpilco-train --set, e.g. opt.max_steps=50)",
    )
    p.add_argument(
        "--mcpilco-json", type=Path, help="collect MC-PILCO from mcpilco-bench-mcpilco's JSON"
    )
    p.add_argument(
        "--mcpilco-label",
        default="",
        help="with --mcpilco-json: the section's --label (e.g. K2); default: unlabelled",
    )
    p.add_argument(
        "--pilco-max-points",
        type=int,
        help="PILCO GP points (default: the env's in agents/baselines/conf/pilco.yaml, else 180)",
    )
    p.add_argument(
        "--pilco-opt-steps",
        type=int,
        help="PILCO evaluations of J (L-BFGS) or Adam steps per trial (default: the env's, "
        "else 150)",
    )
    p.add_argument(
        "--pilco-optimizer",
        choices=OPTIMIZERS,
        help="PILCO policy optimiser (default: the env's, else lbfgs, as PILCO's own "
        "line-search optimiser)",
    )
    p.add_argument(
        "--pilco-basis", type=int, help="PILCO RBF centres (default: the env's, else 50)"
    )
    p.add_argument(
        "--pilco-set",
        nargs="+",
        metavar="KEY=VALUE",
        help="override PilcoConfig fields (e.g. imagined_horizon=40 explore_steps=200)",
    )
    p.add_argument(
        "--inputs", nargs="+", type=Path, default=[], help="extra learning-curve JSON files"
    )
    p.add_argument(
        "--collect-only", action="store_true", help="run nothing; collect existing curves"
    )
    p.add_argument(
        "--rerun", action="store_true", help="ignore complete curves (resume / extend runs)"
    )
    add_sweep_arguments(p)  # --jobs N (local processes, 1 torch thread each), --ray [ADDRESS]
    p.add_argument("--runs-dir", type=Path, default=Path("runs/compare"))
    p.add_argument("--out", type=Path, default=Path("results"))
    p.add_argument("--tag", help="suffix of the output names (e.g. reduced)")
    p.add_argument("--note", help="a line of text put above the table (e.g. the budget used)")
    p.add_argument("--no-progress", action="store_true")
    return p


@console_main("mcpilco-compare")
def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    bad = [m for m in args.methods if m not in METHODS]
    if bad:
        parser.error(
            f"unknown method(s) {', '.join(map(repr, bad))}; valid methods: {', '.join(METHODS)}"
        )
    try:
        check_task_env(args.env)
    except ValueError as err:
        parser.error(str(err))
    if args.seeds < 1 or args.eval_every < 1 or args.eval_episodes < 1:
        parser.error("--seeds, --eval-every and --eval-episodes must be >= 1")
    try:
        runner = runner_from_args(args, progress=not args.no_progress)
    except SweepError as err:
        parser.error(str(err))
    if args.trials is not None and args.trials < 0:
        parser.error(f"--trials must be >= 0, got {args.trials}")
    try:
        steps = parse_steps(args.steps)
        sb3_hp = parse_sb3_hp(args.sb3_hp)
        mcpilco_set = parse_overrides(args.mcpilco_set, "--mcpilco-set")
        pilco_set = parse_overrides(args.pilco_set, "--pilco-set")
    except ValueError as err:
        parser.error(str(err))
    pilco_over = pilco_set | {
        k: v
        for k, v in (
            ("max_points", args.pilco_max_points),
            ("opt_steps", args.pilco_opt_steps),
            ("optimizer", args.pilco_optimizer),
            ("num_basis", args.pilco_basis),
        )
        if v is not None
    }
    opts: dict[str, Any] = {
        "trials": args.trials,
        "mcpilco_preset": args.mcpilco_preset,
        "mcpilco_set": mcpilco_set,
        "pilco": pilco_over,
        "steps": steps,
        "eval_every": args.eval_every,
        "eval_episodes": args.eval_episodes,
        "sb3_preset": args.sb3_preset,
        "sb3_hp": sb3_hp,
        "threads": 1,
        "progress": not args.no_progress and runner.in_process,
        "log": runner.in_process,
    }
    curves: list[dict[str, Any]] = []
    for path in args.inputs:
        try:
            curves += load_curves(path)
        except (OSError, ValueError, TypeError) as err:
            parser.error(f"--inputs {path}: {err}")
    try:
        report = compare(
            args.env,
            args.methods,
            range(args.first_seed, args.first_seed + args.seeds),
            opts,
            runner,
            args.runs_dir,
            curves=curves,
            mcpilco_json=args.mcpilco_json,
            mcpilco_label=args.mcpilco_label,
            collect_only=args.collect_only,
            rerun=args.rerun,
            tag=args.tag,
            note=args.note,
        )
    except ValueError as err:
        parser.error(str(err))
    report["command"] = recorded_command_line(sys.argv[1:] if argv is None else argv)
    report["measured"] = datetime.date.today().isoformat()
    paths = write_report(report, args.out)
    print(markdown(report))
    print(f"wrote {paths['json']}, {paths['md']} and {paths['png']}")
    return 1 if report["failed"] else 0


if __name__ == "__main__":
    sys.exit(main())
