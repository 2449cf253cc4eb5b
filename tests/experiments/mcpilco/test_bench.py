"""The MC-PILCO benchmark's library: seeds resumed from their checkpoints, sections of runs,
their pooling and their tables."""

from __future__ import annotations

import dataclasses

import pytest

from mcpilco.agents.mc_pilco import DEFAULT_ENV_ID, load_config
from mcpilco.experiments.infra.sweep import SweepRunner
from mcpilco.experiments.mcpilco.bench import bench_runs, run_seed

BENCH_CONFIG = load_config(DEFAULT_ENV_ID, preset="bench")


def test_finished_seed_is_resumed_not_rerun(tmp_path):
    from tests.agents.mc_pilco.test_trainer import SMOKE

    job = (dataclasses.replace(SMOKE, num_trials=0).to_dict(), str(tmp_path / "seed3"))
    first = run_seed(*job)
    ckpt = tmp_path / "seed3" / "checkpoint.pt"
    stamp = ckpt.stat().st_mtime_ns
    again = run_seed(*job)
    # a re-run would have rewritten the checkpoint and measured new wall-clock times
    assert ckpt.stat().st_mtime_ns == stamp
    assert again["records"] == first["records"] and again["seconds"] == first["seconds"] > 0


def test_seeds_are_sweep_jobs_with_one_result_file_each(tmp_path):
    from tests.agents.mc_pilco.test_trainer import SMOKE

    cfg = dataclasses.replace(SMOKE, num_trials=0)
    runner = SweepRunner(progress=False, log=None)
    section, sweep = bench_runs(cfg, [0, 1], runner, tmp_path)
    assert sweep.ran == ["seed0", "seed1"] and section["seeds"] == [0, 1]
    assert (tmp_path / "seed1.json").is_file() and (tmp_path / "seed1" / "checkpoint.pt").is_file()
    # one more seed: the two finished ones are read back from their result files
    more, sweep = bench_runs(cfg, [0, 1, 2], runner, tmp_path)
    assert sweep.ran == ["seed2"] and sweep.skipped == ["seed0", "seed1"]
    assert more["seeds"] == [0, 1, 2] and more["per_seed"][:2] == section["per_seed"]


def _fake_runs(seeds, n_trials, rng):
    """Run dicts as :func:`run_seed` returns them, with random per-trial outcomes."""
    runs = []
    for seed in seeds:
        records = [
            {"experience_s": 3.0, "kind": "exploration", "success": False, "time_in_goal": 0.0}
            | {"steps": 60, "cost": 60.0, "wall_s": 0.1}
        ]
        for k in range(1, n_trials + 1):
            records.append(
                {
                    "experience_s": 3.0 * (k + 1),
                    "kind": "policy",
                    "success": bool(rng.random() < 0.6),
                    "time_in_goal": float(rng.uniform(0, 2.5)),
                    "steps": 60,
                    "cost": float(rng.uniform(5, 60)),
                    "wall_s": float(rng.uniform(50, 300)),
                    "opt_steps": int(rng.integers(100, 1000)),
                    "s_per_opt_step": float(rng.uniform(0.1, 0.3)),
                    "cpu_s_per_opt_step": float(rng.uniform(0.1, 0.3)),
                    "gp_fit_s": float(rng.uniform(1, 10)),
                }
            )
        runs.append(
            {"seed": seed, "records": records, "seconds": sum(r["wall_s"] for r in records)}
        )
    return runs


def test_pooled_sections_equal_the_aggregate_over_all_seeds():
    """Pooling per-trial means of two seed sets must give the per-trial means of their union
    (computed directly from the per-seed records), and a trial only the second set ran is
    the mean over that set alone."""
    import numpy as np

    from mcpilco.experiments.mcpilco.bench import aggregate_runs, make_section, pool_sections

    rng = np.random.default_rng(0)
    runs_a, runs_b = _fake_runs(range(0, 7), 4, rng), _fake_runs(range(7, 12), 5, rng)
    cfg_a = dataclasses.replace(BENCH_CONFIG, num_trials=4).to_dict()
    cfg_b = dataclasses.replace(BENCH_CONFIG, num_trials=5).to_dict()
    pooled = pool_sections(
        [make_section(cfg_a, runs_a, 2, 10.0), make_section(cfg_b, runs_b, 2, 20.0)]
    )
    union = aggregate_runs(runs_a + runs_b)  # truncated to the 5 common trials
    assert len(pooled["per_trial"]) == 6 and len(union) == 5
    for got, want in zip(pooled["per_trial"], union, strict=False):
        assert got["seeds"] == 12
        for key in ("success_rate", "time_in_goal_s", "cost", "wall_s_per_trial"):
            assert got[key] == pytest.approx(want[key], rel=1e-12)
    last = pooled["per_trial"][5]
    assert last["seeds"] == 5
    want = np.mean([r["records"][5]["time_in_goal"] for r in runs_b])
    assert last["time_in_goal_s"] == pytest.approx(want, rel=1e-12)
    assert pooled["seeds"] == list(range(12)) and pooled["config"]["num_trials"] == 5


def test_pooling_refuses_other_configs_and_repeated_seeds():
    import numpy as np

    from mcpilco.experiments.mcpilco.bench import make_section, pool_sections

    rng = np.random.default_rng(1)
    cfg = BENCH_CONFIG.to_dict()
    a = make_section(cfg, _fake_runs([0, 1], 4, rng), 1, 1.0)
    other = dataclasses.replace(BENCH_CONFIG, kernel="rbf").to_dict()
    with pytest.raises(ValueError, match="kernel"):
        pool_sections([a, make_section(other, _fake_runs([2], 4, rng), 1, 1.0)])
    with pytest.raises(ValueError, match="a seed appears in two sections"):
        pool_sections([a, make_section(cfg, _fake_runs([1, 2], 4, rng), 1, 1.0)])


def test_report_states_what_each_policy_was_trained_on(tmp_path):
    import numpy as np

    from mcpilco.experiments.mcpilco.bench import make_section, section_table

    section = make_section(
        BENCH_CONFIG.to_dict(), _fake_runs([0, 1, 2, 5], 2, np.random.default_rng(2)), 1, 1.0
    )
    table = section_table("env", section)
    assert "4 seeds (0-2, 5)" in table
    assert "| success rate [95 % Wilson] | time in goal [s] |" in table
    # exploration: 0 of 4 seeds, Wilson upper end z^2 / (n + z^2) = 3.8416 / 7.8416 = 49 %
    assert "| 3 s (exploration) | - | 0% [0-49] |" in table
    assert "time upright" not in table and "mean abs x" not in table
    rows = [line for line in table.splitlines() if line.startswith("| ") and " s (" in line]
    assert [r.split("|")[1:3] for r in rows] == [
        [" 3 s (exploration) ", " - "],
        [" 6 s (policy) ", " 3 s "],
        [" 9 s (policy) ", " 6 s "],
    ]


def test_sections_saved_before_explore_hold_are_kept_apart_and_labelled_iid():
    """A section whose config predates ``explore_hold`` ran i.i.d. exploration: its header
    says 1 step, and pooling it with a held-exploration section is refused."""
    import numpy as np

    from mcpilco.experiments.mcpilco.bench import make_section, pool_sections, section_table

    rng = np.random.default_rng(3)
    old_cfg = BENCH_CONFIG.to_dict()
    del old_cfg["explore_hold"]
    old = make_section(old_cfg, _fake_runs([0, 1], 2, rng), 1, 1.0)
    new = make_section(BENCH_CONFIG.to_dict(), _fake_runs([2, 3], 2, rng), 1, 1.0)
    assert "exploration actions held 1 step(s)" in section_table("env", old)
    assert "exploration actions held 2 step(s)" in section_table("env", new)
    with pytest.raises(ValueError, match="explore_hold"):
        pool_sections([old, new])


def test_pooled_report_names_the_seeds_of_a_trial_only_some_ran():
    import numpy as np

    from mcpilco.experiments.mcpilco.bench import make_section, pool_sections, section_table

    rng = np.random.default_rng(4)
    cfg_a = dataclasses.replace(BENCH_CONFIG, num_trials=1).to_dict()
    a = make_section(cfg_a, _fake_runs([0, 1], 1, rng), 1, 1.0)
    cfg_b = dataclasses.replace(BENCH_CONFIG, num_trials=2).to_dict()
    b = make_section(cfg_b, _fake_runs([2], 2, rng), 1, 1.0)
    table = section_table("env", pool_sections([a, b]))
    assert "Pooled from 2 runs of the same config (2 + 1 seeds" in table
    assert "averages runs of [1, 2] policy trials" in table
    assert "| 6 s (policy) |" in table and "| 9 s (policy, 1 seeds) |" in table


def test_reference_table_divides_by_the_references_own_step_where_one_was_timed():
    """A timed step with the reference's own step on a comparable task (same spec, N,
    particles and threads) is divided into that step; every other cart-pole step into the
    reference's cart-pole range 0.45-0.58 s, a step of another spec gets no ratio; rows name
    their GP kernel."""
    from mcpilco.experiments.mcpilco.bench import reference_table

    def row(env_id: str, n: int, wall: float, degree: int) -> dict:
        return {
            "env_id": env_id, "kernel": "rbf+mpk", "mpk_degree": degree, "n_points": n,
            "num_particles": 50, "threads": 2, "s_per_step_wall": wall, "s_per_step_cpu": wall,
        }  # fmt: skip

    measured = [
        {"env_id": "arm", "task": "UR5", "n_points": 100, "num_particles": 50, "threads": 2,
         "s_per_step": 2.0},
    ]  # fmt: skip
    md = reference_table(
        [row("arm", 100, 0.1, 1), row("arm", 200, 0.1, 1), row(DEFAULT_ENV_ID, 100, 0.05, 2)],
        measured,
    )
    lines = [line for line in md if line.startswith(("| arm", f"| {DEFAULT_ENV_ID}"))]
    assert lines[0].startswith("| arm (RBF + MPK (p = 1)) | 50 | 100 |")
    assert lines[0].endswith("| 20x (UR5: 2.00 s) |")
    assert lines[1].endswith("| - |")  # no reference step at N = 200
    assert lines[2].endswith("| 9-12x |")
