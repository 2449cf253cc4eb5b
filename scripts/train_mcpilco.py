"""Train MC-PILCO on a Gymnasium env with a task specification (console script ``mcpilco-train``).

One random-exploration trial, then ``--trials`` policy trials; after each trial a line with
the task's cost, the success flag and the wall-clock time. The hyperparameters come from the
env's file in ``agents/mc_pilco/conf/`` (with ``--preset``), then ``--set key=value`` and
the options below. Outputs in ``--out``: ``checkpoint.pt`` (resumable with ``--resume``),
``records.json``, ``run.rrd`` (Rerun), ``trial_XX_particles.png`` and ``optimisation.png``.

Usage::

    mcpilco-train --trials 4 --out runs/seed0
    mcpilco-train --trials 5 --out runs/seed0 --resume     # continue a killed / shorter run
    mcpilco-train --trials 4 --out runs/seed0 --overwrite  # delete the run in runs/seed0 first
    mcpilco-train --preset demo --out runs/demo            # make demo's budget (12 s)
    mcpilco-train --env mcpilco/DMCCartpoleSwingUp-v0 --kernel rbf --seed 3
    mcpilco-train --env InvertedPendulum-v5 --set num_particles=100 --set opt.max_steps=300
    mcpilco-train --env my_pkg.envs:MyArm-v0 --task my_task.yaml   # your own env, registered
                                            # by my_pkg.envs; the task file says what to learn
    mcpilco-train --env Pendulum-v1 --env-kwargs "{g: 9.81}" --config my.yaml
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mcpilco.agents.common.cli import console_main
from mcpilco.agents.mc_pilco import DEFAULT_ENV_ID
from mcpilco.agents.mc_pilco.cli import budget_report, check_config, config_from_options, train
from mcpilco.agents.mc_pilco.config import ROLLOUT_DTYPES
from mcpilco.agents.mc_pilco.dynamics import KERNEL_CHOICES


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from err
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive integer (> 0), got {value}")
    return value


def _non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}") from err
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="mcpilco-train", description=__doc__, formatter_class=argparse.RawTextHelpFormatter
    )
    p.add_argument(
        "--env",
        default=DEFAULT_ENV_ID,
        help="Gymnasium env id: mcpilco/..., dm_control/<domain>-<task>-v0, Gymnasium's own, "
        "or pkg.module:EnvId to import the module (yours or an installed package's) that "
        "registers it",
    )
    p.add_argument(
        "--env-kwargs",
        metavar="YAML",
        help="keyword arguments of gym.make: a YAML mapping ('{g: 9.81}') or a YAML file",
    )
    p.add_argument(
        "--config",
        type=Path,
        help="your own config file, in the format of the shipped ones (config + presets); "
        "merged over the env's shipped file and under --set",
    )
    p.add_argument(
        "--preset",
        default="default",
        help="a preset of the env's config file or of --config (e.g. bench, demo)",
    )
    p.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="override any config field (YAML value; nested with dots: opt.max_steps=500)",
    )
    p.add_argument(
        "--task", type=Path, help="a YAML task file for an env that ships none (see TaskSpec)"
    )
    p.add_argument("--trials", type=_non_negative_int, help="policy trials after exploration")
    p.add_argument("--particles", type=_positive_int, help="particles M of the rollout")
    p.add_argument("--opt-steps", type=_positive_int, help="max policy optimisation steps")
    p.add_argument("--horizon", type=_positive_int, help="steps per trial (env episode length)")
    p.add_argument("--max-points", type=_positive_int, help="GP subset-of-data size")
    p.add_argument("--kernel", choices=KERNEL_CHOICES, help="GP kernel (default rbf+mpk)")
    p.add_argument(
        "--candidates",
        type=_positive_int,
        help="K policies optimised side by side; the lowest expected cost is applied (default 1)",
    )
    p.add_argument(
        "--rollout-dtype",
        choices=ROLLOUT_DTYPES,
        help="dtype of the GP posterior in the particle rollouts (default float32)",
    )
    p.add_argument(
        "--explore-hold",
        type=_positive_int,
        help="steps each random action of the exploration trial is held (default: the env's "
        "config file)",
    )
    p.add_argument(
        "--compile-rollout",
        action="store_true",
        default=None,
        help="use a fast rollout (config rollout_backend: auto = the package's C++ rollout, "
        "split over the threads by particles, where it applies, else torch.compile of the "
        "time step; both need a C++ compiler; --set rollout_backend=torch needs none); each "
        "trial checks it against the eager rollout and runs eagerly, with a warning, if they "
        "disagree",
    )
    p.add_argument("--seed", type=_non_negative_int)
    p.add_argument("--threads", type=_positive_int, help="torch threads (default: torch's)")
    p.add_argument(
        "--device",
        help="where the policy optimisation runs: cpu (default) or cuda[:index]; the GP fit "
        "and the env stay on the CPU",
    )
    p.add_argument("--out", type=Path, default=Path("runs/mcpilco"), help="output folder")
    p.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
    p.add_argument(
        "--overwrite", action="store_true", help="delete the run found in OUT first (else refused)"
    )
    p.add_argument(
        "--eval-episodes",
        type=int,
        default=None,
        help="after each policy trial, E episodes from the task's initial distribution (not "
        "experience): success rate with a 95 %% interval (default 0: none)",
    )
    p.add_argument("--no-progress", action="store_true", help="no tqdm bars")
    p.add_argument("--no-rrd", action="store_true", help="do not write run.rrd")
    return p


@console_main("mcpilco-train")
def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:  # unknown env id, task, preset or field; a task not learnable; no device; no compiler
        config = config_from_options(
            args.env,
            preset=args.preset,
            set_items=args.set,
            task_file=args.task,
            config_file=args.config,
            env_kwargs=args.env_kwargs,
            seed=args.seed,
            num_trials=args.trials,
            num_particles=args.particles,
            horizon=args.horizon,
            max_points=args.max_points,
            kernel=args.kernel,
            num_candidates=args.candidates,
            torch_threads=args.threads,
            rollout_dtype=args.rollout_dtype,
            explore_hold=args.explore_hold,
            device=args.device,
            compile_rollout=args.compile_rollout,
            opt_steps=args.opt_steps,
            eval_episodes=args.eval_episodes,
        )
        check_config(config)
        print(budget_report(config))
    except ValueError as err:
        parser.error(str(err))
    summary = train(
        config,
        args.out,
        resume=args.resume,
        overwrite=args.overwrite,
        progress=not args.no_progress,
        write_rrd=not args.no_rrd,
        log=print,
    )
    print(
        f"done in {summary.seconds:.1f} s: success={summary.success}, first success at trial "
        f"{summary.first_success_trial}; outputs in {summary.out_dir} "
        f"(checkpoint {summary.checkpoint.name}, rrd {summary.rrd}, {len(summary.pngs)} PNGs)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
