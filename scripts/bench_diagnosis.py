"""Benchmark the diagnosis loop on many random hidden-effect cases: top-1 / top-3 accuracy.

Each case (``scripts/make_hidden_effect_data.py``, SCARA or UR10, seed ``s``): one random
effect on a random joint with a random magnitude (or, every ``control_every``-th case, no
effect). A nominal start model is fitted on the training files and :func:`diagnose` ranks
the candidates; a case counts for top-k when the true ``key:joint`` is among the first k
candidates of the ranking (significant first, then by evidence). Also recorded: whether
the verdict names the true effect, the held-out RMSE / noise of the affected joints after
adding the verdict's effect, false alarms on the control cases, seconds per case.

Writes ``results/diagnosis.json`` and ``results/diagnosis.md``. Example (about 10-20 s per
case on one core)::

    python -m mcpilco.scripts.bench_diagnosis --cases 30 --robot scara --workers 2
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np


def run_case(robot: str, seed: int, control: bool, duration: float) -> dict[str, Any]:
    """Generate, diagnose, add the verdict's effect; return the record of one case."""
    import torch

    torch.set_num_threads(1)
    from mcpilco.models.diagnosis import (
        DiagnosisModel,
        NominalStart,
        as_trajectories,
        diagnose,
        heldout_rmse,
    )
    from mcpilco.scripts.make_hidden_effect_data import make_case

    t0 = time.perf_counter()
    case = make_case(robot, [] if control else None, n_effects=1, seed=seed, duration=duration)
    test = as_trajectories(case.datasets("test"))
    model = DiagnosisModel(NominalStart(case.nominal_xml)).fit(case.datasets("train"))
    d = diagnose(model, test)
    ranking = [c.label for c in d.candidates]
    truth = case.truth()
    rec: dict[str, Any] = {
        "robot": robot,
        "seed": seed,
        "truth": truth,
        "effect": case.effects,
        "verdict": None if d.best is None else d.best.label,
        "ranking": ranking[:5],
        "deltas": [round(c.delta, 1) for c in d.candidates[:5]],
    }
    if truth:
        rank = ranking.index(truth[0]) + 1 if truth[0] in ranking else None
        rec.update(rank=rank, top1=rank == 1, top3=rank is not None and rank <= 3)
        rec["verdict_correct"] = rec["verdict"] == truth[0]
        if d.best is not None:
            new = model.with_effect(d.best.effect)
            rmse = heldout_rmse(new, test) / case.noise_std
            e = case.effects[0]
            joints = (
                [j for j, s in enumerate(e["size_over_noise"]) if s >= 1.0]
                if e["joint"] is None
                else [e["joint"] - 1]
            )
            rec["rmse_over_noise_after"] = float(np.max(rmse[joints]))
    else:
        rec["false_alarm"] = d.best is not None
    rec["seconds"] = time.perf_counter() - t0
    return rec


def summarise(records: list[dict[str, Any]]) -> dict[str, Any]:
    eff = [r for r in records if r["truth"]]
    ctl = [r for r in records if not r["truth"]]
    after = [r["rmse_over_noise_after"] for r in eff if "rmse_over_noise_after" in r]
    by_key: dict[str, list[bool]] = {}
    for r in eff:
        by_key.setdefault(r["truth"][0].split(":")[0], []).append(bool(r["top1"]))
    return {
        "n_effect_cases": len(eff),
        "n_control_cases": len(ctl),
        "top1": float(np.mean([r["top1"] for r in eff])) if eff else None,
        "top3": float(np.mean([r["top3"] for r in eff])) if eff else None,
        "verdict_correct": float(np.mean([r["verdict_correct"] for r in eff])) if eff else None,
        "within_1p5_noise_after_add": float(np.mean(np.array(after) <= 1.5)) if after else None,
        "false_alarm_rate": float(np.mean([r["false_alarm"] for r in ctl])) if ctl else None,
        "top1_by_effect": {k: f"{sum(v)}/{len(v)}" for k, v in sorted(by_key.items())},
        "seconds_per_case": float(np.mean([r["seconds"] for r in records])),
    }


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cases", type=int, default=30)
    p.add_argument("--robot", choices=("scara", "ur10"), default="scara")
    p.add_argument("--first-seed", type=int, default=1000)
    p.add_argument("--control-every", type=int, default=5)
    p.add_argument("--duration", type=float, default=12.0)
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--out", default="results/diagnosis")
    args = p.parse_args(argv)
    seeds = [args.first_seed + k for k in range(args.cases)]
    controls = [args.control_every > 0 and k % args.control_every == 0 for k in range(args.cases)]
    jobs = [(args.robot, s, c, args.duration) for s, c in zip(seeds, controls, strict=True)]
    from tqdm import tqdm

    if args.workers > 1:
        with ProcessPoolExecutor(args.workers) as pool:
            futures = [pool.submit(run_case, *j) for j in jobs]
            records = [f.result() for f in tqdm(futures, desc="cases")]
    else:
        records = [run_case(*j) for j in tqdm(jobs, desc="cases")]
    summary = summarise(records)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    payload = {"config": vars(args), "summary": summary, "cases": records}
    out.with_suffix(".json").write_text(json.dumps(payload, indent=1, default=str))
    lines = [
        f"# Diagnosis benchmark ({args.robot}, {len(records)} cases, seeds "
        f"{seeds[0]}..{seeds[-1]}, nominal start)",
        "",
        "| metric | value |",
        "|---|---|",
    ]
    for k, v in summary.items():
        lines.append(f"| {k} | {v if not isinstance(v, float) else round(v, 3)} |")
    lines += ["", "| seed | truth | verdict | rank | RMSE/noise after |", "|---|---|---|---|---|"]
    for r in records:
        lines.append(
            f"| {r['seed']} | {', '.join(r['truth']) or 'none'} | {r['verdict']} | "
            f"{r.get('rank', '')} | {r.get('rmse_over_noise_after', '')} |"
        )
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines[:12]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
