"""Balance benchmark of MC-PILCO on a terminating balance task (``mcpilco-bench-balance``):
runs with the package's derived defaults and the task file only, each policy judged after
every trial on the env's own full-length episodes.

A trial's record judges its policy on the horizon ``H`` it was optimised for (100 steps of
``InvertedDoublePendulum-v5``); the env's episode is longer (1000 steps). Here the policy
applied after trial ``k`` runs ``E`` episodes of the env's own length from its initial
distribution (reset seeds :func:`~mcpilco.agents.common.trials.eval_seed`, disjoint from
every trial's; not experience), and a seed *balances after trial k* when all ``E`` last the
whole episode. Per trial: the experience so far, the seeds that balance, the rate with its
95 % Wilson interval; per seed: the episode lengths.

:func:`balance_bench` runs the seeds one after the other and writes
``balance_<env>[_<tag>].json`` (the result schema of :mod:`mcpilco.experiments.results`),
``.md`` and ``.png``.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mcpilco.experiments.results import (
    Headline,
    Result,
    ResultLayout,
    rate,
    read_result,
    seed_ranges,
    write_result,
)

RESULT_LAYOUTS = (
    ResultLayout(
        kind="mcpilco-balance",
        config=("env_id", "trials", "episodes", "episode_steps", "seeds_planned", "config"),
        cases=("runs",),
    ),
)


def balance_run(env_id: str, seed: int, trials: int, episodes: int, out: Path) -> dict[str, Any]:
    """One run of ``trials`` policy trials on seed ``seed`` (the derived defaults), with
    ``episodes`` full-length episodes of each trial's policy. Returns the seed's case:
    ``experience_s`` and ``episode_steps`` (per episode) per policy trial, and seconds."""
    import gymnasium as gym

    from mcpilco.agents.common.trials import eval_seed, make_env, resolve_env_id, run_episode
    from mcpilco.agents.mc_pilco.config import load_config
    from mcpilco.agents.mc_pilco.policy import policy_act
    from mcpilco.agents.mc_pilco.trainer import Trainer

    config = load_config(env_id, overrides={"seed": int(seed), "num_trials": int(trials)})
    trainer = Trainer(config, out, progress=False, log=None, write_rrd=False, overwrite=True)
    t0 = time.perf_counter()
    trainer.set_up()
    full = int(gym.spec(resolve_env_id(env_id)).max_episode_steps)
    env = make_env(env_id, full, trainer.task, config.env_kwargs)
    per_trial = []
    try:
        for k in range(trials + 1):
            trainer.run_trial(k)
            if k == 0:
                continue
            act = policy_act(trainer.policy)
            steps = [
                run_episode(env, act, eval_seed(seed, k, i), full, trainer.task)["steps"]
                for i in range(episodes)
            ]
            per_trial.append(
                {
                    "trial": k,
                    "experience_s": trainer.records[-1].experience_s,
                    "episode_steps": steps,
                    "balanced": all(s == full for s in steps),
                }
            )
    finally:
        env.close()
        trainer.env.close()
        trainer.run_folder.close()
    return {"seed": int(seed), "trials": per_trial, "seconds": time.perf_counter() - t0}


def summarise(runs: Sequence[dict[str, Any]], trials: int) -> list[dict[str, Any]]:
    """Per policy trial: the experience (the largest over the seeds), the seeds that balance
    and the rate with its interval."""
    out = []
    for k in range(1, trials + 1):
        rows = [t for r in runs for t in r["trials"] if t["trial"] == k]
        ok = [r["seed"] for r in runs for t in r["trials"] if t["trial"] == k and t["balanced"]]
        out.append(
            {
                "trial": k,
                "experience_s": max(t["experience_s"] for t in rows),
                "balanced_seeds": ok,
                "balanced": rate(len(ok), len(rows)),
            }
        )
    return out


def balance_bench(
    env_id: str,
    seeds: Sequence[int],
    trials: int,
    episodes: int,
    out_dir: Path,
    runs_dir: Path,
    tag: str = "",
    command: str | None = None,
) -> dict[str, Path]:
    """Run every seed, then write the result file, its Markdown table and its figure."""
    import gymnasium as gym

    from mcpilco.agents.common.trials import resolve_env_id
    from mcpilco.agents.mc_pilco.config import load_config

    stem = f"balance_{env_id.split('/')[-1]}" + (f"_{tag}" if tag else "")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    steps = int(gym.spec(resolve_env_id(env_id)).max_episode_steps)
    runs: list[dict[str, Any]] = []
    for seed in seeds:  # the files are rewritten after every seed (a stopped bench keeps them)
        runs.append(balance_run(env_id, seed, trials, episodes, Path(runs_dir) / f"seed{seed}"))
        print(
            f"seed {seed}: "
            + ", ".join(f"trial {t['trial']} {t['episode_steps']}" for t in runs[-1]["trials"])
        )
        payload = {
            "env_id": env_id,
            "trials": int(trials),
            "episodes": int(episodes),
            "episode_steps": steps,
            "seeds_planned": [int(s) for s in seeds],
            "config": load_config(env_id).to_dict(),
            "per_trial": summarise(runs, trials),
            "runs": runs,
        }
        path = write_result(
            out_dir / f"{stem}.json",
            RESULT_LAYOUTS[0],
            payload,
            seeds=[r["seed"] for r in runs],
            command=command,
        )
        res = read_result(path)
        md = out_dir / f"{stem}.md"
        md.write_text(markdown(res))
        png = plot(res, out_dir / f"{stem}.png")
    return {"json": path, "md": md, "png": png}


def _seed_kind(res: Result) -> str:
    dev = res.seeds.get("development") or []
    every = res.seeds.get("all") or []
    if dev and len(dev) == len(every):
        return f"development seeds {seed_ranges(dev)} (defaults were chosen on them)"
    if not dev:
        return f"report seeds {seed_ranges(every)} (run once, after the defaults were frozen)"
    return f"seeds {seed_ranges(every)}, of which development seeds {seed_ranges(dev)}"


def markdown(res: Result) -> str:
    """The result as a Markdown page."""
    full = res["episode_steps"]
    planned = res.payload().get("seeds_planned") or [r["seed"] for r in res["runs"]]
    lines = [
        f"# MC-PILCO balance on {res['env_id']}",
        "",
        f"Command: `{res.command}`  ",
        f"Date: {res.date}; commit {res.commit}  ",
        f"Seeds: {_seed_kind(res)}"
        + (
            f"; {len(res['runs'])} of the {len(planned)} planned ({seed_ranges(planned)}) ran."
            if len(planned) > len(res["runs"])
            else "."
        ),
        "",
        f"Each seed: the package's derived defaults and the task file only; after each policy "
        f"trial the applied policy runs {res['episodes']} episodes of the env's own "
        f"{full} steps (not experience). A seed balances when all of them last {full} steps.",
        "",
        "| after trial | experience | seeds balanced | rate (95 % CI) |",
        "|---|---|---|---|",
    ]
    for t in res["per_trial"]:
        r = t["balanced"]
        lines.append(
            f"| {t['trial']} | {t['experience_s']:.0f} s | {r['k']} of {r['n']} | "
            f"{100 * r['rate']:.0f} % ({100 * r['ci95'][0]:.0f}-{100 * r['ci95'][1]:.0f} %) |"
        )
    lines += ["", "| seed | episode steps after each trial | minutes |", "|---|---|---|"]
    for run in res["runs"]:
        steps = "; ".join(f"{t['trial']}: {t['episode_steps']}" for t in run["trials"])
        lines.append(f"| {run['seed']} | {steps} | {run['seconds'] / 60:.1f} |")
    return "\n".join(lines) + "\n"


def plot(res: Result, path: Path) -> Path:
    """The balanced rate with its interval against the experience."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = res["per_trial"]
    x = np.array([t["experience_s"] for t in rows])
    y = np.array([t["balanced"]["rate"] for t in rows])
    lo = np.array([t["balanced"]["ci95"][0] for t in rows])
    hi = np.array([t["balanced"]["ci95"][1] for t in rows])
    fig, ax = plt.subplots(figsize=(5, 3.2))
    ax.errorbar(x, y, yerr=[y - lo, hi - y], marker="o", capsize=3)
    ax.set_xlabel("experience [s]")
    ax.set_ylabel(f"seeds balancing {res['episode_steps']} steps")
    ax.set_ylim(-0.05, 1.05)
    ax.set_title(f"MC-PILCO, {res['env_id']}")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def replot(result: Result, json_path: Path) -> list[Path]:
    """Redraw the figure and the page from the result file alone."""
    json_path = Path(json_path)
    md = json_path.with_suffix(".md")
    md.write_text(markdown(result))
    return [plot(result, json_path.with_suffix(".png")), md]


HEADLINES: tuple[Headline, ...] = ()
"""No headline row yet (the file's seeds are named on its page)."""
