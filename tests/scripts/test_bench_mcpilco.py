"""``mcpilco-bench-mcpilco``: argument checks, pooling, the timing and rmse_runs parts."""

from __future__ import annotations

import pytest
import torch

from mcpilco.agents.mc_pilco import DEFAULT_ENV_ID, load_config
from mcpilco.agents.mc_pilco.fast.native import STAGE_NAMES
from mcpilco.experiments.mcpilco.bench import bench_configs, run_seed
from mcpilco.experiments.mcpilco.timing import JOINTS_SPEC
from mcpilco.experiments.results import read_result
from tests.experiments.mcpilco.test_bench import _fake_runs
from tests.experiments.mcpilco.test_reference import STEP_SLEEP, fake_reference_repo

BENCH_CONFIG = load_config(DEFAULT_ENV_ID, preset="bench")


def test_candidate_scales_must_match_candidates(tmp_path, capsys, command):
    argv = ["--parts", "runs", "--candidates", "3", "--candidate-scales", "0.01", "0.1"]
    argv += ["--out", str(tmp_path), "--runs-dir", str(tmp_path / "runs")]
    assert command("mcpilco-bench-mcpilco", argv) == 2
    assert "candidate_weight_scales must hold num_candidates=3" in capsys.readouterr().err


def test_unknown_preset_or_env_is_an_error(tmp_path, capsys, command):
    argv = ["--parts", "runs", "--out", str(tmp_path), "--runs-dir", str(tmp_path / "runs")]
    assert command("mcpilco-bench-mcpilco", [*argv, "--preset", "fast"]) == 2
    err = capsys.readouterr().err
    assert "unknown preset 'fast'" in err and "bench" in err
    assert command("mcpilco-bench-mcpilco", [*argv, "--env", "mcpilco/Nope-v0"]) == 2
    err = capsys.readouterr().err
    assert "no task ships for env id 'mcpilco/Nope-v0'" in err
    assert "mcpilco/CartpoleSwingUp-v0" in err
    assert not (tmp_path / "runs").exists()


def test_task_set_runs_a_variant_of_the_shipped_task(tmp_path, capsys, command):
    """``--task-set``: the configs carry the shipped task with the fields replaced (the UR10
    task with speed integration, as its earlier sections ran); a bad field or value is a
    usage error naming it, before any run."""
    configs = bench_configs(["mcpilco/UR10-v0"], task_overrides={"speed_integration": True})
    task = configs["mcpilco/UR10-v0"].task_spec()
    assert task.speed_integration and task.position_idx == tuple(range(6))
    assert not load_config("mcpilco/UR10-v0").task_spec().speed_integration
    argv = ["--parts", "tracking", "--env", "mcpilco/UR10-v0", "--out", str(tmp_path)]
    argv += ["--runs-dir", str(tmp_path / "runs"), "--task-set"]
    assert command("mcpilco-bench-mcpilco", [*argv, "speed_integration=3"]) == 2
    assert "speed_integration" in capsys.readouterr().err
    assert command("mcpilco-bench-mcpilco", [*argv, "colour=red"]) == 2
    assert "task.colour" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()


def test_pool_option_adds_a_pooled_section(tmp_path, capsys, command):

    import numpy as np

    from mcpilco.experiments.mcpilco.bench import RESULT_LAYOUTS, make_section, section_key
    from mcpilco.experiments.results import write_result

    rng = np.random.default_rng(3)
    cfg = BENCH_CONFIG.to_dict()
    runs = {
        section_key(DEFAULT_ENV_ID, "a"): make_section(cfg, _fake_runs([0, 1], 4, rng), 1, 1.0),
        section_key(DEFAULT_ENV_ID, "b"): make_section(cfg, _fake_runs([2], 4, rng), 1, 1.0),
    }
    write_result(tmp_path / "mcpilco_cartpole.json", RESULT_LAYOUTS[0], {"runs": runs})
    argv = ["--out", str(tmp_path), "--runs-dir", str(tmp_path / "runs")]
    assert (
        command("mcpilco-bench-mcpilco", ["--pool", "a", "b"] + argv) == 0
    )  # no parts run when only --pool is given
    out = read_result(tmp_path / "mcpilco_cartpole.json").payload()
    assert out["runs"][section_key(DEFAULT_ENV_ID, "a+b")]["seeds"] == [0, 1, 2]
    assert "(a+b)" in (tmp_path / "mcpilco_cartpole.md").read_text()
    assert command("mcpilco-bench-mcpilco", ["--pool", "a", "c"] + argv) == 2
    assert "--pool: no section" in capsys.readouterr().err


def test_timing_part_reports_each_particle_count(tmp_path, capsys, command):
    """The timing part times every (N, threads, M) asked for and tables M; bad counts are
    refused before any work."""

    argv = ["--parts", "timing", "--timing-n", "20", "--timing-threads", "1"]
    argv += ["--out", str(tmp_path), "--runs-dir", str(tmp_path / "runs")]
    assert command("mcpilco-bench-mcpilco", [*argv, "--timing-particles", "0", "5"]) == 2
    assert "--timing-particles values must be >= 1" in capsys.readouterr().err
    assert command("mcpilco-bench-mcpilco", [*argv, "--timing-particles", "3", "5"]) == 0
    timing = read_result(tmp_path / "mcpilco_cartpole.json").payload()["timing"]
    assert [(t["num_particles"], t["n_points"], t["threads"]) for t in timing] == [
        (3, 20, 1),
        (5, 20, 1),
    ]
    assert all(t["s_per_step_wall"] > 0 for t in timing)
    md = (tmp_path / "mcpilco_cartpole.md").read_text()
    assert "| 3 | 20 | cpu | no | 1 |" in md and "| 5 | 20 | cpu | no | 1 |" in md
    # --compile-rollout: the same row gains the compiled step, timed in the same rounds
    assert (
        command("mcpilco-bench-mcpilco", [*argv, "--timing-particles", "3", "--compile-rollout"])
        == 0
    )
    (t,) = read_result(tmp_path / "mcpilco_cartpole.json").payload()["timing"]
    assert t["compiled_s_per_step_wall"] > 0 and t["compile_s"] > 0
    assert not t["compiled_rejected"] and t["compile_check"]["grad_rel"] < 1e-2
    # the default backend (native), the torch one and torch.compile of the time step, timed
    assert t["compile_backend"] == "native" and t["dynamo_compile_backend"] == "dynamo"
    assert t["torch_compile_backend"] == "torch" and t["torch_s_per_step_wall"] > 0
    assert t["torch_compile_check"]["grad_rel"] < 1e-2
    assert t["rollout_shards"] == 1  # 3 particles: too few to split over threads
    assert t["dynamo_s_per_step_wall"] > 0 and t["dynamo_compile_check"]["grad_rel"] < 1e-2
    md = (tmp_path / "mcpilco_cartpole.md").read_text()
    assert "| 3 | 20 | cpu | no | 1 |" in md and "x |" in md and "| native |" in md
    assert f"| {t['torch_s_per_step_wall']:.3f} | {t['torch_s_per_step_cpu']:.3f} |" in md
    # the floor: 2 N^2 M m H flops at the measured matmul rate
    assert t["floor_s"] == pytest.approx(2 * 20**2 * 3 * 2 * 60 / (t["matmul_gflops"] * 1e9))
    assert f"| {t['floor_s']:.4f} | {t['matmul_gflops']:.0f} |" in md
    # the products floor: per particle, output and step 2 (N (d + 2) + N F + N^2 / 2) forward
    # and 2 (N F + N^2 / 2 + N (d + 1)) backward; d = 6, F = (d + 1)(d + 2) / 2 = 28 (p = 2)
    per = 2 * (20 * 8 + 20 * 28 + 200) + 2 * (20 * 28 + 200 + 20 * 7)
    rate = t["matmul_gflops"] * 1e9
    assert t["products_floor_s"] == pytest.approx(per * 3 * 2 * 60 / rate)
    # the machine and the build, and the native loops' stages
    assert t["cpu_model"] and t["build_flags"] == "-O3 -march=native -fno-math-errno"
    assert t["avx2_build_flags"] == "-O3 -march=x86-64-v3 -fno-math-errno"
    assert t["avx2_s_per_step_wall"] > 0 and t["avx2_compile_check"]["grad_rel"] < 1e-2
    assert 0 < t["native_kernel_rows_taken"] <= 1 and t["build_isa"] == "native"
    assert t["native_group"] >= 1 and t["torch_version"] == torch.__version__
    assert set(t["native_stage_s"]) == set(STAGE_NAMES)
    assert all(v >= 0 for v in t["native_stage_s"].values())
    # the product stages' floors sum to the products floor; the report's stage table
    floors = t["native_stage_floor_s"]
    assert set(floors) < set(STAGE_NAMES) and len(floors) == 4
    assert sum(floors.values()) == pytest.approx(t["products_floor_s"])
    assert floors[STAGE_NAMES[1]] == pytest.approx(2 * 20 * 8 * 3 * 2 * 60 / rate)
    assert t["build_vector_floats"] in (8, 16)
    assert "### Where the `native` step's time goes" in md
    assert f"| {t['products_floor_s']:.3f} | {t['cpu_model']} ({t['cpu_isa']}) |" in md
    assert f"| {t['dynamo_s_per_step_wall']:.3f} | {t['dynamo_s_per_step_cpu']:.3f} |" in md
    # the spec's table heading, and the step against the reference implementation's 0.45-0.58 s
    assert (t["env_id"], t["state_dim"], t["action_dim"], t["gp_outputs"], t["horizon"]) == (
        "mcpilco/CartpoleSwingUp-v0",
        4,
        1,
        2,
        60,
    )
    assert (t["kernel"], t["mpk_degree"]) == ("rbf+mpk", 2)  # the cart-pole config's GP
    assert (
        "#### mcpilco/CartpoleSwingUp-v0 (n = 4, A = 1, m = 2, H = 60; GP RBF + MPK (p = 2))" in md
    )
    wall = t["compiled_s_per_step_wall"]
    assert f"| {wall:.3f} | {t['compiled_s_per_step_cpu']:.3f} | {t['floor_s']:.4f} " in md
    assert f"| {0.45 / wall:.0f}-{0.58 / wall:.0f}x |" in md
    # --timing-heap-contrast: the eager step again under glibc's initial heap thresholds;
    # --reference-repo: the reference's own step (a fake checkout) in the same rounds
    assert command("mcpilco-bench-mcpilco", [*argv, "--reference-repo", str(tmp_path)]) == 2
    assert "not a checkout of merlresearch/MC-PILCO" in capsys.readouterr().err
    ref = fake_reference_repo(tmp_path / "reference")
    argv_ref = [*argv, "--timing-particles", "3", "--timing-heap-contrast"]
    assert command("mcpilco-bench-mcpilco", [*argv_ref, "--reference-repo", str(ref)]) == 0
    payload = read_result(tmp_path / "mcpilco_cartpole.json").payload()
    (t,) = payload["timing"]
    assert t["heap128k_s_per_step_wall"] > 0 and t["heap128k_page_faults_per_step"] >= 0
    assert t["page_faults_per_step"] >= 0 and "compiled_s_per_step_wall" not in t
    assert t["reference_task"] == "cartpole" and t["reference_n_points"] == 20
    assert t["reference_s_per_step_wall"] >= STEP_SLEEP
    assert t["reference_ratio"] == pytest.approx(
        t["reference_s_per_step_wall"] / t["s_per_step_wall"]
    )
    (m,) = payload["reference_steps"]
    assert (m["task"], m["n_points"], m["num_particles"], m["threads"]) == ("cart-pole", 20, 3, 1)
    md = (tmp_path / "mcpilco_cartpole.md").read_text()
    row = next(line for line in md.splitlines() if line.startswith("| 3 | 20 | cpu | no | 1 |"))
    assert row.count("|") == 27 and f"| {t['heap128k_s_per_step_wall']:.3f} |" in row
    assert f"| {t['reference_s_per_step_wall']:.3f} (cartpole) |" in row
    assert f"(cart-pole: {m['s_per_step']:.2f} s) |" in md
    # --mpk-degree with --timing-append: the spec with another kernel, beside the first rows
    argv1 = [*argv, "--timing-particles", "3", "--mpk-degree", "1", "--timing-append"]
    assert command("mcpilco-bench-mcpilco", argv1) == 0
    timing = read_result(tmp_path / "mcpilco_cartpole.json").payload()["timing"]
    assert [t.get("mpk_degree") for t in timing] == [2, 1]
    md = (tmp_path / "mcpilco_cartpole.md").read_text()
    assert "H = 60; GP RBF + MPK (p = 1))" in md and "H = 60; GP RBF + MPK (p = 2))" in md
    # the 12-state arm spec, only the default backend's fast step beside the eager one
    argv2 = [*argv, "--timing-particles", "3", "--timing-env", JOINTS_SPEC, "--timing-append"]
    argv2 += ["--compile-rollout", "--timing-variants", "compiled"]
    assert command("mcpilco-bench-mcpilco", argv2) == 0
    (t,) = [t for t in read_result(tmp_path / "mcpilco_cartpole.json").payload()["timing"]
            if t["env_id"] == JOINTS_SPEC]  # fmt: skip
    assert (t["state_dim"], t["action_dim"], t["gp_outputs"], t["horizon"]) == (12, 6, 6, 100)
    assert t["compile_backend"] == "native" and t["compiled_s_per_step_wall"] > 0
    assert "torch_s_per_step_wall" not in t and "dynamo_s_per_step_wall" not in t


def test_rmse_runs_part_uses_only_runs_that_swung_up_and_groups_by_their_kernel(
    tmp_path, capsys, command
):
    """Part ``rmse_runs``: a run whose last trial failed is not used (and alone is an error);
    each used run gives both kernels' RMSE on its data before the last trial, grouped by the
    kernel the run learned with."""
    import math
    import shutil

    import torch

    from tests.agents.mc_pilco.test_trainer import SMOKE

    run_seed(SMOKE.to_dict(), str(tmp_path / "failed" / "seed3"))
    src = tmp_path / "failed" / "seed3" / "checkpoint.pt"
    ckpt = torch.load(src, weights_only=False)
    ckpt["records"][-1]["success"] = False
    torch.save(ckpt, src)
    argv = ["--parts", "rmse_runs", "--out", str(tmp_path / "out")]
    assert command("mcpilco-bench-mcpilco", [*argv, "--rmse-runs", str(tmp_path / "failed")]) == 2
    assert "no run whose last trial swung up" in capsys.readouterr().err
    for kernel in ("rbf+mpk", "rbf"):  # the same data, labelled as learned with each kernel
        dst = tmp_path / "ok" / kernel / "checkpoint.pt"
        dst.parent.mkdir(parents=True)
        shutil.copy(src, dst)
        ck = torch.load(dst, weights_only=False)
        ck["records"][-1]["success"] = True
        ck["config"]["kernel"] = kernel
        torch.save(ck, dst)
    assert (
        command(
            "mcpilco-bench-mcpilco",
            [*argv, "--rmse-runs", str(tmp_path / "failed"), str(tmp_path / "ok")],
        )
        == 0
    )
    res = read_result(tmp_path / "out" / "mcpilco_cartpole.json").payload()["rmse_runs"]
    assert sorted(r["run_kernel"] for r in res["per_run"]) == ["rbf", "rbf+mpk"]
    horizon = SMOKE.task_spec().horizon
    assert all(r["n_data"] == horizon for r in res["per_run"])  # exploration only
    for r in res["per_run"]:
        assert all(math.isfinite(r[k]) and r[k] > 0 for k in ("rbf+mpk", "rbf"))
    env = SMOKE.env_id
    assert {k: g["runs"] for k, g in res["groups"].items()} == {
        f"rbf on {env}": 1,
        f"rbf+mpk on {env}": 1,
    }
    a, b = res["per_run"]  # same data, policy and seed: the label changes nothing
    assert (a["rbf+mpk"], a["rbf"]) == (b["rbf+mpk"], b["rbf"])
    assert (tmp_path / "out" / "mcpilco_cartpole_rmse_runs.png").stat().st_size > 0
    md = (tmp_path / "out" / "mcpilco_cartpole.md").read_text()
    assert f"| rbf+mpk on {env} | 1 |" in md and f"| rbf on {env} | 1 |" in md
