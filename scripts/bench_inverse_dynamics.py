"""Benchmark: inverse-dynamics estimators GIP, RBF, NN, FE, PP, SP (thesis section 3.4).

Parts (``--parts``, comma separated; all by default):

``scara`` (``--runs`` Monte Carlo runs with model bias), ``efficiency`` (test GMSE against
``--sizes``, no model bias), ``ur10`` (the UR10 env's motor currents) and ``timing`` (GIP
training and prediction at ``--timing-n`` points against the Cholesky floor); the protocol
is in :mod:`mcpilco.experiments.identification.inverse_dynamics`. The scara runs are sweep jobs in
``--jobs`` local processes or on Ray (``--ray [ADDRESS]``), each kept in
``RUNS_DIR/scara/run<i>.json``: a rerun computes only the runs without one.

Parts can be run in separate calls with ``--append`` (the JSON, PNGs and Markdown then hold
every part run so far). Outputs (``--out-dir``, default ``results/``): ``inverse_dynamics.json``,
``inverse_dynamics.md``, ``inverse_dynamics_scara_nmse.png``,
``inverse_dynamics_efficiency.png``, ``inverse_dynamics_ur10_nmse.png``.

Usage::

    mcpilco-bench-inverse-dynamics              # every part, default sizes
    mcpilco-bench-inverse-dynamics --parts scara --runs 2 --n-train 200
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from mcpilco.agents.common.cli import console_main
from mcpilco.experiments.identification.inverse_dynamics import ESTIMATORS, PARTS, run_benchmark
from mcpilco.experiments.infra.sweep import SweepError, add_sweep_arguments, runner_from_args


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--parts", default=",".join(PARTS), help=f"comma list of {PARTS}")
    p.add_argument("--runs", type=int, default=20, help="SCARA Monte Carlo runs")
    p.add_argument("--n-train", type=int, default=2000)
    p.add_argument("--n-test", type=int, default=2000)
    p.add_argument("--dt", type=float, default=0.1, help="sample spacing of the SCARA data [s]")
    p.add_argument("--noise", type=float, default=0.01, help="torque noise std [N m]")
    p.add_argument("--n-sinusoids", type=int, default=200)
    p.add_argument("--no-tool", action="store_true", help="SCARA without the 3 kg tool")
    p.add_argument("--estimators", default=",".join(ESTIMATORS))
    p.add_argument("--gip-std", action="store_true", help="also GIP with standardised inputs")
    p.add_argument("--sizes", default="50,100,200,500,1000,2000,4000")
    p.add_argument("--efficiency-estimators", default="GIP,PP,RBF,NN")
    p.add_argument("--ur10-train", type=int, default=40000)
    p.add_argument("--ur10-subset", type=int, default=4000)
    p.add_argument("--ur10-test-exploration", type=int, default=10000)
    p.add_argument("--no-ur10-circle", dest="ur10_circle", action="store_false")
    p.add_argument("--ur10-estimators", default="FE,PP,SP,GIP,RBF,NN")
    p.add_argument("--ur10-nn-hidden", type=int, default=600, help="thesis: 600 for the UR10")
    p.add_argument("--ur10-nn-epochs", type=int, default=40, help="epoch cap (all rows)")
    p.add_argument("--timing-n", type=int, default=2000)
    p.add_argument("--timing-adam-iters", type=int, default=20)
    p.add_argument("--timing-lbfgs-iters", type=int, default=10)
    p.add_argument("--adam-iters", type=int, default=80)
    p.add_argument("--lbfgs-iters", type=int, default=20)
    p.add_argument("--hyper-points", type=int, default=400)
    p.add_argument("--nn-hidden", type=int, default=400)
    p.add_argument("--nn-epochs", type=int, default=500)
    p.add_argument("--nn-patience", type=int, default=50)
    p.add_argument("--nn-batch", type=int, default=128)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=1, help="torch threads")
    p.add_argument("--out-dir", default="results")
    p.add_argument(
        "--runs-dir",
        default="runs/bench_inverse_dynamics",
        help="one result file per scara run (reused by a later call with the same options)",
    )
    p.add_argument("--no-progress", action="store_true")
    add_sweep_arguments(p)  # --jobs N (local processes), --ray [ADDRESS]: the scara runs
    p.add_argument(
        "--append",
        action="store_true",
        help="merge into an existing inverse_dynamics.json (parts not run here are kept)",
    )
    return p


def _list(value: str, kind: type = str) -> list:
    return [kind(v) for v in value.split(",") if v.strip()]


@console_main("mcpilco-bench-inverse-dynamics")
def main(argv: Sequence[str] | None = None) -> int:
    """Run the selected parts, write JSON, PNGs and Markdown; print the Markdown. Returns 0."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        runner = runner_from_args(args, progress=not args.no_progress)
    except SweepError as err:
        parser.error(str(err))
    parts = _list(args.parts)
    bad = [p for p in parts if p not in PARTS]
    if bad:
        raise SystemExit(f"unknown part(s) {bad}; choose from {PARTS}")
    args.estimators = _list(args.estimators)
    args.efficiency_estimators = _list(args.efficiency_estimators)
    args.ur10_estimators = _list(args.ur10_estimators)
    args.sizes = _list(args.sizes, int)
    out = run_benchmark(args, parts, runner)
    print(out["markdown"])
    if out["failed"]:
        print(f"failed scara runs (see their .error.txt in {args.runs_dir}/scara): {out['failed']}")
    return 1 if out["failed"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
