"""Benchmark MC-PILCO on the cartpole swing-up (console script ``mcpilco-bench-mcpilco``).

Parts, each optional (``tracking`` and ``tracking_kernels`` only when named):

1. ``runs``: S seeds of the whole loop (exploration + policy trials) per env; per trial
   (3, 6, 9, 12, 15 s of experience) the success rate, mean time upright, mean ``|x|``,
   wall-clock per trial and per optimisation step. Seeds are sweep jobs
   (:mod:`mcpilco.experiments.infra.sweep`) with one torch thread each, in ``--jobs`` local
   processes or on Ray (``--ray [ADDRESS]``); a finished seed is not rerun.
2. ``timing``: seconds per policy optimisation step (the ``M x H`` particle rollout forward
   and backward, Adam) for the particle counts ``--timing-particles``, GP sizes ``N`` (fitted
   on random-exploration data), threads and task specs of ``--timing-env``, with each step's
   floor; ``--reference-repo``: the reference implementation's own step beside each. With
   ``--device cuda`` each step is timed as one replayed CUDA graph and op by op.
3. ``rmse``: RBF+MPK vs RBF-only (thesis Fig. 5.5): both GPs fitted on the same 3 s of
   random exploration (actions held the preset's ``explore_hold`` steps, ``--explore-hold``);
   a fixed learned swing-up policy (the final policy of a successful run of part 1, or
   ``--rmse-policy``) runs on the env and ``M`` particles are rolled out through each GP;
   reported: the RMSE of theta between particles and the real trajectory per time step
   and averaged over the 60 steps, over ``--rmse-seeds`` exploration seeds.
4. ``rmse_runs``: the same comparison on the data of finished runs (``--rmse-runs``, default
   every run under ``--runs-dir`` whose last trial swung up): both GPs fitted on the run's data
   before its last trial, particles under the last trial's policy from that trial's real initial
   state, against its real trajectory. Grouped by the kernel each run learned with and its env.
5. ``tracking``: for a tracking task (``--env mcpilco/UR10-v0``), the tracking RMS per joint after
   each policy trial against the env's controller alone; ``tracking_kernels``: on the tracking runs
   under ``--rmse-runs``, each GP kernel of ``--kernels`` refitted on a run's data before its last
   trial (``--fit-trials K``: its first K trials'), the RMSE per joint of its particles against that
   trial (:mod:`mcpilco.experiments.mcpilco.tracking`); both write ``results/mcpilco_tracking.*``.

Writes ``results/mcpilco_cartpole.json`` (merged with an existing file, one section per
env), ``results/mcpilco_cartpole.md`` and ``results/mcpilco_cartpole.png``. ``--pool`` merges
sections of the same config run on other seeds (e.g. 12 seeds, then 8 more with
``--first-seed 12 --label bench5``) into one section over all of them.

Usage::

    mcpilco-bench-mcpilco --seeds 20 --jobs 2                  # all parts, default env
    mcpilco-bench-mcpilco --parts runs --seeds 5 --preset small
    mcpilco-bench-mcpilco --parts runs --env mcpilco/DMCCartpoleSwingUp-v0 --seeds 5
    mcpilco-bench-mcpilco --parts timing rmse
    mcpilco-bench-mcpilco --parts timing --compile-rollout --timing-env mcpilco/UR10-v0
    mcpilco-bench-mcpilco --pool bench bench5                  # one section, seeds of both
    mcpilco-bench-mcpilco --parts tracking --env mcpilco/UR10-v0 --seeds 10 --jobs 2
    mcpilco-bench-mcpilco --parts tracking --env mcpilco/UR10-v0 --pushes [filtered] --seeds 10
    mcpilco-bench-mcpilco --parts tracking_kernels --rmse-runs runs/bench/UR10-v0 [--fit-trials 1]
    mcpilco-bench-mcpilco --parts timing --device cuda --timing-particles 400 4000
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from mcpilco.agents.common.cli import console_main
from mcpilco.agents.mc_pilco import DEFAULT_ENV_ID
from mcpilco.agents.mc_pilco.config import ROLLOUT_DTYPES, parse_set
from mcpilco.agents.mc_pilco.dynamics import KERNEL_CHOICES
from mcpilco.experiments.infra.sweep import SweepError, add_sweep_arguments, runner_from_args
from mcpilco.experiments.mcpilco.bench import (
    PARTS,
    bench_configs,
    load_results,
    pool_part,
    rmse_part,
    rmse_runs_part,
    runs_part,
    timing_part,
)
from mcpilco.experiments.mcpilco.reference import reference_checkout
from mcpilco.experiments.mcpilco.timing import JOINTS_SPEC, VARIANTS
from mcpilco.experiments.mcpilco.tracking import PUSH_VARIANTS, tracking_kernels_part, tracking_part


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="mcpilco-bench-mcpilco",
        description=__doc__,
        formatter_class=argparse.RawTextHelpFormatter,
    )
    p.add_argument(
        "--parts",
        nargs="+",
        choices=(*PARTS, "tracking", "tracking_kernels"),
        help=f"parts to run (default: all of {', '.join(PARTS)}; none when --pool is given; "
        "tracking and tracking_kernels only when named)",
    )
    p.add_argument(
        "--pool",
        nargs="+",
        metavar="LABEL",
        help="pool the existing sections with these labels ('' for the unlabelled one) of "
        "each --env into a section labelled LABEL1+LABEL2 (same config, other seeds), after "
        "the parts",
    )
    p.add_argument("--env", nargs="+", default=[DEFAULT_ENV_ID], help="env ids for the runs")
    p.add_argument("--seeds", type=int, default=20, help="number of seeds S (0..S-1)")
    p.add_argument("--first-seed", type=int, default=0)
    add_sweep_arguments(p)  # --jobs N (local processes, 1 thread each), --ray [ADDRESS]
    p.add_argument("--preset", default="bench", help="preset of each env's config file")
    p.add_argument(
        "--timing-append", action="store_true",
        help="timing part: replace only the rows timed again, keep the others",
    )  # fmt: skip
    p.add_argument(
        "--pushes", nargs="?", const="both", choices=PUSH_VARIANTS,
        help="tracking part: the env's random pushes on; runs with the push filter, without it "
        "or both (default)",
    )  # fmt: skip
    p.add_argument("--trials", type=int, help="policy trials (override)")
    p.add_argument("--particles", type=int, help="particles (override)")
    p.add_argument("--opt-steps", type=int, help="max opt steps per trial (override)")
    p.add_argument("--candidates", type=int, help="K policies side by side (override)")
    p.add_argument(
        "--kernel", choices=KERNEL_CHOICES,
        help="GP kernel of the runs and the timing (override; e.g. rbf for the RBF-only ablation)",
    )  # fmt: skip
    p.add_argument(
        "--mpk-degree", type=int,
        help="degree of the MPK of kernel rbf+mpk in the runs and the timing (override)",
    )  # fmt: skip
    p.add_argument(
        "--task-set", nargs="+", metavar="KEY=VALUE",
        help="replace fields of the env's task (a variant, e.g. speed_integration=true)",
    )  # fmt: skip
    p.add_argument(
        "--rollout-dtype", choices=ROLLOUT_DTYPES,
        help="dtype of the GP posterior in the particle rollouts (override; float32 default)",
    )  # fmt: skip
    p.add_argument(
        "--compile-rollout", action="store_true", default=None,
        help="use the fast rollout in the runs (use_fast_rollout, default backend); the "
        "timing part then also times every setting with the default backend, the torch "
        "backend and torch.compile",
    )  # fmt: skip
    p.add_argument("--window-objective", choices=("on", "off"), help="J^_W or J^")  # fmt: skip
    p.add_argument(
        "--explore-hold", type=int,
        help="steps each random exploration action is held (override; default: the env's, 2 "
        "on mcpilco/CartpoleSwingUp-v0, 1 = i.i.d. per step on mcpilco/DMCCartpoleSwingUp-v0; "
        "a section saved without it ran 1)",
    )  # fmt: skip
    p.add_argument(
        "--candidate-scales", type=float, nargs="+",
        help="initial weight scale of each candidate (K values; sets K when --candidates "
        "is not given)",
    )  # fmt: skip
    p.add_argument(
        "--label", default="",
        help="suffix of the results section and run folder (e.g. 'K2'), to keep variants apart",
    )  # fmt: skip
    p.add_argument(
        "--device", default="cpu",
        help="where the runs' policy optimisation and the timing part run: cpu or cuda[:index]",
    )  # fmt: skip
    p.add_argument("--timing-n", type=int, nargs="+", default=[100, 200, 250, 300])
    p.add_argument(
        "--timing-env", nargs="+", default=[DEFAULT_ENV_ID],
        help="env ids whose task specs the timing part times (each over its own horizon; "
        f"e.g. mcpilco/UR10-v0: 24 states, 12 GP outputs; {JOINTS_SPEC}: 12 and 6)",
    )  # fmt: skip
    p.add_argument("--timing-threads", type=int, nargs="+", default=[1, 2])
    p.add_argument(
        "--timing-variants", nargs="+", default=None, choices=VARIANTS,
        help="timing part: the fast steps timed beside the eager one (default: all)",
    )  # fmt: skip
    p.add_argument(
        "--timing-particles", type=int, nargs="+", default=[400],
        help="particle counts M of the timing part (e.g. 25 400: the fixed cost and the goal's M)",
    )  # fmt: skip
    p.add_argument(
        "--timing-heap-contrast", action="store_true",
        help="timing part: also time the eager step with glibc's initial heap thresholds "
        "(128 KiB) instead of the retained heap, alternating in the same rounds",
    )  # fmt: skip
    p.add_argument("--reference-repo", type=reference_checkout, help="timing part: a checkout "
                   "of merlresearch/MC-PILCO whose own step is timed beside every row")  # fmt: skip
    p.add_argument("--rmse-seeds", type=int, default=10)
    p.add_argument(
        "--rmse-policy",
        type=Path,
        help="checkpoint.pt of a run whose last trial swung up (default: the first such run "
        "under --runs-dir)",
    )
    p.add_argument(
        "--rmse-runs",
        type=Path,
        nargs="+",
        metavar="DIR",
        help="rmse_runs part: run folders (or folders of them) to use; only runs whose last "
        "trial swung up count (default: all such runs under --runs-dir); tracking_kernels "
        "part: folders of finished tracking runs (required)",
    )
    p.add_argument(
        "--kernels",
        nargs="+",
        default=["rbf", "rbf+mpk", "rbf+mpk1", "rigid_body"],
        help="tracking_kernels part: GP kernel labels to compare (rbf+mpk: degree-2 MPK, "
        "rbf+mpk1: degree 1)",
    )
    p.add_argument(
        "--fit-trials", type=int, metavar="K",
        help="tracking_kernels part: fit on the runs' first K trials (1: exploration only)",
    )  # fmt: skip
    p.add_argument("--out", type=Path, default=Path("results"))
    p.add_argument("--runs-dir", type=Path, default=Path("runs/bench_mcpilco"))
    return p


@console_main("mcpilco-bench-mcpilco")
def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.parts is None:
        args.parts = [] if args.pool else list(PARTS)
    if args.seeds < 1:
        parser.error("--seeds must be >= 1")
    try:
        runner = runner_from_args(args)
    except SweepError as err:
        parser.error(str(err))
    for name in ("timing_n", "timing_threads", "timing_particles"):
        if min(getattr(args, name)) < 1:
            parser.error(f"--{name.replace('_', '-')} values must be >= 1")
    try:
        configs = bench_configs(
            args.env,
            preset=args.preset,
            task_overrides=parse_set(args.task_set),
            num_trials=args.trials,
            num_particles=args.particles,
            num_candidates=args.candidates,
            kernel=args.kernel,
            mpk_degree=args.mpk_degree,
            rollout_dtype=args.rollout_dtype,
            compile_rollout=args.compile_rollout,
            window_objective={"on": True, "off": False}.get(args.window_objective),
            explore_hold=args.explore_hold,
            candidate_weight_scales=args.candidate_scales,
            device=args.device,
            opt_steps=args.opt_steps,
        )
    except ValueError as err:
        parser.error(str(err))

    results = load_results(args.out)
    failed = 0
    command = shlex.join(["mcpilco-bench-mcpilco", *(sys.argv[1:] if argv is None else argv)])
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    try:
        if "tracking" in args.parts:
            failed += tracking_part(
                configs, seeds, runner, args.runs_dir, args.out, args.label, args.pushes, command
            )
        if "tracking_kernels" in args.parts:
            tracking_kernels_part(
                args.rmse_runs or [], args.out, args.kernels, runner, args.particles or 100,
                command, fit_trials=args.fit_trials,
            )  # fmt: skip
    except ValueError as err:
        parser.error(str(err))
    if args.parts and set(args.parts) <= {"tracking", "tracking_kernels"}:
        print(f"wrote {args.out / 'mcpilco_tracking.json'} and its report")
        return 1 if failed else 0
    if "runs" in args.parts:
        failed += runs_part(results, configs, seeds, runner, args.runs_dir, args.out, args.label)
    if "timing" in args.parts:
        timing_part(
            results, args.out, args.timing_n, args.timing_threads, args.timing_particles,
            device=args.device, compile_rollout=bool(args.compile_rollout),
            heap_contrast=bool(args.timing_heap_contrast), env_ids=args.timing_env,
            append=bool(args.timing_append), kernel=args.kernel, mpk_degree=args.mpk_degree,
            variants=args.timing_variants, reference_repo=args.reference_repo,
        )  # fmt: skip
    if "rmse" in args.parts:
        try:
            rmse_part(
                results, args.out, args.rmse_seeds, policy_ckpt=args.rmse_policy,
                runs_dir=args.runs_dir, explore_hold=args.explore_hold,
            )  # fmt: skip
        except FileNotFoundError as err:
            parser.error(str(err))
    if "rmse_runs" in args.parts:
        try:
            rmse_runs_part(results, args.out, args.rmse_runs or [args.runs_dir])
        except ValueError as err:
            parser.error(str(err))
    if args.pool:
        try:
            pool_part(results, args.out, args.env, args.pool)
        except ValueError as err:
            parser.error(str(err))
    print(f"wrote {args.out / 'mcpilco_cartpole.json'} and {args.out / 'mcpilco_cartpole.md'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
