"""Seconds per MC-PILCO policy optimisation step, the ``timing`` part of
``mcpilco-bench-mcpilco``.

One step is the forward pass through the ``M x H`` particle rollout, its backward pass and an
Adam step, on a GP fitted to random-exploration data. :func:`time_opt_step` times it eager
and, on request, with each fast rollout of :func:`~mcpilco.agents.mc_pilco.use_fast_rollout`,
alternating the variants within each round so that their ratios hold on a busy machine.

Beside the times, :func:`time_opt_step` reports a floor: the flops of the GP posterior
variance, the part of a step that grows with ``N`` squared, at this machine's float32 matmul
rate (:func:`matmul_rate`). Per particle, GP output and time step, the variance
``sigma^2 = k** - ||L^{-1} k*||^2`` costs about ``N^2`` flops forward (a triangular solve,
``N^2 / 2`` multiply-adds) and as many backward, so a step's floor is
``2 N^2 M m H / rate`` seconds (``M`` particles, ``m`` outputs, ``H`` steps). The products
floor (:func:`product_flops`) counts every product with the GP's constant matrices instead:
the RBF's exponents ``N (d + 2)``, the MPK's ``N x F`` feature block and the triangular
factor's ``N^2 / 2`` multiply-adds forward, as many backward, per particle, output and step.

Every row records the machine it ran on (:func:`cpu_info`: CPU model, ISA, L2 cache, the
native build's compiler and flags), since the ratios hold for that CPU only. The ``avx2``
variant times the native rollout built for AVX2 without AVX-512 (x86-64-v3) in the same
rounds, the stand-in for a CPU without AVX-512. With ``reference_repo`` (a checkout of the
reference implementation) the reference's own step on its matching task is timed in the same
rounds too (:mod:`~mcpilco.experiments.mcpilco.reference`).

Besides the registered envs' task specs, :func:`timing_task` knows :data:`JOINTS_SPEC`, a
12-state arm spec between the cart-pole and the UR10 tracking task.
"""

from __future__ import annotations

import resource
import statistics
import time

import numpy as np

from mcpilco.agents.mc_pilco import DEFAULT_ENV_ID, TaskSpec

__all__ = [
    "JOINTS_SPEC",
    "REFERENCE_S_PER_STEP",
    "VARIANTS",
    "cpu_info",
    "exploration_data",
    "matmul_rate",
    "product_flops",
    "reference_speedup",
    "stage_product_flops",
    "time_opt_step",
    "timing_task",
    "variance_flops",
]

JOINTS_SPEC = "mcpilco/UR10-v0:joints"
"""A timing spec, not a registered env: the UR10's six joints without the reference
(``q, qd``: 12 states, 6 torques), its cost each joint's distance from the home pose, its
initial state the UR10 task's joints (on the reference), the velocities' changes predicted and
the positions integrated (6 GP outputs over 18 inputs; the layout of the reference
implementation's UR5 task). Its data are the first 12 coordinates of ``mcpilco/UR10-v0``'s
random exploration; it times the step, it is not a task to learn."""

VARIANTS = ("compiled", "torch", "dynamo", "avx2")  # the fast steps time_opt_step can time

MATMUL_SIZE = 512  # rows and columns of the square float32 product that measures the rate

# seconds per optimisation step of the reference implementation (merlresearch/MC-PILCO) on the
# cart-pole at N = 60 GP points, 400 particles (lowest, highest measured on this machine class)
REFERENCE_S_PER_STEP = (0.45, 0.58)


def reference_speedup(s_per_step: float) -> tuple[float, float]:
    """How many times faster than the reference implementation a step of ``s_per_step``
    seconds is: :data:`REFERENCE_S_PER_STEP` divided by it (lowest, highest)."""
    if not s_per_step > 0:
        raise ValueError(f"s_per_step must be > 0, got {s_per_step}")
    lo, hi = REFERENCE_S_PER_STEP
    return lo / s_per_step, hi / s_per_step


def variance_flops(n_points: int, num_particles: int, outputs: int, horizon: int) -> float:
    """Flops of the GP posterior variance in one optimisation step, forward and backward:
    ``2 N^2 M m H`` (module docstring)."""
    return 2.0 * n_points**2 * num_particles * outputs * horizon


def matmul_rate(threads: int, repeats: int = 20) -> float:
    """Flops per second of a float32 ``512 x 512`` matrix product on ``threads`` intra-op
    threads (the best of ``repeats``): what this machine's BLAS reaches on dense work."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        gen = torch.Generator().manual_seed(0)
        a = torch.randn(MATMUL_SIZE, MATMUL_SIZE, generator=gen)
        b = torch.randn(MATMUL_SIZE, MATMUL_SIZE, generator=gen)
        a @ b  # warm-up
        best = float("inf")
        for _ in range(repeats):
            t = time.perf_counter()
            a @ b
            best = min(best, time.perf_counter() - t)
    finally:
        torch.set_num_threads(before)
    return 2.0 * MATMUL_SIZE**3 / best


def timing_task(spec: str) -> tuple[TaskSpec, str]:
    """The task spec a timing ``spec`` names and the registered env whose config and data it
    uses: a registered env id (its shipped spec, itself), or :data:`JOINTS_SPEC`."""
    if spec != JOINTS_SPEC:
        return TaskSpec.for_env(spec), spec
    env_id = spec.split(":")[0]
    from mcpilco.envs.tasks import task_data

    d = dict(task_data(env_id))
    joints = list(d["joints"])
    names = list(d["state_names"][: 2 * len(joints)])  # q, qd of each joint
    reference = {k: v for k, v in d["reference"].items() if k != "states"}
    d.update(
        state_names=names,
        obs_indices=list(range(len(names))),
        speed_integration=True,
        affine_inputs=[],
        reference=reference,
        init_mean=list(d["init_mean"][: len(names)]),
        cost={
            "terms": [
                {"state": q, "target": c, "length_scale": 0.02}
                for q, c in zip(joints, reference["centre"], strict=True)
            ]
        },
        success={"full_horizon": True},
    )
    return TaskSpec.from_dict(d), env_id


def cpu_info() -> dict[str, object]:
    """What a timing row ran on: the CPU model, its vector ISA (``avx512f``, ``avx2`` or
    neither, from ``/proc/cpuinfo``), its per-core L2 cache (bytes, as the native rollout reads
    it; None without the extension), the native build's compiler and flags (``-march=native``:
    the code is built for this CPU) and the width of its products' vectors (16 floats with
    AVX-512, else 8), and the torch version."""
    import platform

    import torch

    from mcpilco.agents.mc_pilco.fast import native

    model, flags = platform.processor() or platform.machine(), set()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name") and model in ("", platform.machine()):
                    model = line.split(":", 1)[1].strip()
                elif line.startswith("flags") and not flags:
                    flags = set(line.split(":", 1)[1].split())
    except OSError:
        pass
    isa = [x for x in ("avx512f", "avx2", "fma") if x in flags]
    isa_name = native.native_isa()
    cxx = native.cpp_compiler()
    version = None
    if cxx:
        import subprocess

        try:
            out = subprocess.run([cxx, "--version"], capture_output=True, text=True, timeout=30)
            version = out.stdout.splitlines()[0] if out.stdout else None
        except (OSError, subprocess.SubprocessError):
            version = None
    try:
        lib = native.load_library()
        l2, width = int(lib.l2_cache_bytes()), int(lib.vector_floats())
    except RuntimeError:
        l2 = width = None
    return {
        "cpu_model": model,
        "cpu_isa": " ".join(isa) or "none of avx512f, avx2, fma",
        "l2_cache_bytes": l2,
        "build_compiler": version,
        "build_isa": isa_name,
        "build_flags": " ".join(native.cxx_flags(isa_name)),
        "build_vector_floats": width,
        "torch_version": torch.__version__,
    }


def stage_product_flops(
    n_points: int, features: int, inputs: int, num_particles: int, outputs: int, horizon: int
) -> dict[str, float]:
    """Flops of the products with the GP's constant matrices in one optimisation step, by the
    native rollout's stage that runs them
    (:data:`~mcpilco.agents.mc_pilco.fast.native.STAGE_NAMES`; the stages without such a
    product are left out), per particle, output and step: the RBF's exponents
    ``2 N (d + 2)``; the MPK's ``N x F`` feature block and the triangular factor
    ``2 (N F + N^2 / 2)`` forward and as many backward; the RBF inputs' ``2 N (d + 1)``
    backward (``d`` GP inputs, ``F`` MPK features)."""
    from mcpilco.agents.mc_pilco.fast.native import STAGE_NAMES

    N, F, d = n_points, features, inputs
    per = {
        STAGE_NAMES[1]: 2.0 * N * (d + 2),
        STAGE_NAMES[2]: 2.0 * (N * F + N * N / 2),
        STAGE_NAMES[5]: 2.0 * (N * F + N * N / 2),
        STAGE_NAMES[6]: 2.0 * N * (d + 1),
    }
    return {stage: f * num_particles * outputs * horizon for stage, f in per.items()}


def product_flops(
    n_points: int, features: int, inputs: int, num_particles: int, outputs: int, horizon: int
) -> float:
    """Flops of the products with the GP's constant matrices in one optimisation step,
    forward and backward: the sum of :func:`stage_product_flops`, per particle, output and
    step ``2 (N (d + 2) + N F + N^2 / 2)`` forward (the RBF's exponents, the MPK's ``N x F``
    feature block, the triangular factor) and ``2 (N F + N^2 / 2 + N (d + 1))`` backward."""
    args = (n_points, features, inputs, num_particles, outputs, horizon)
    return sum(stage_product_flops(*args).values())


def exploration_data(env_id: str, n_points: int, seed: int, hold: int = 1):
    """``n_points`` transitions of random-exploration episodes (actions held ``hold`` steps,
    :func:`~mcpilco.agents.common.trials.exploration_actions`) of the timing spec ``env_id``
    (:func:`timing_task`)."""
    from mcpilco.agents.common.trials import exploration_actions, make_env, run_episode, transitions

    task, env_id = timing_task(env_id)
    H = task.horizon
    env = make_env(env_id, H, task)
    rng = np.random.default_rng(seed)
    eps = []
    while sum(len(e["actions"]) for e in eps) < n_points:
        it = iter(exploration_actions(rng, H, hold, task.action_low, task.action_high))
        eps.append(run_episode(env, lambda _o, it=it: next(it), seed * 1000 + len(eps), H, task))
    env.close()
    s, a, s1 = transitions(eps)
    return s[:n_points], a[:n_points], s1[:n_points], eps


def time_opt_step(
    n_points: int,
    num_particles: int = 400,
    horizon: int | None = None,
    kernel: str = "rbf+mpk",
    mpk_degree: int = 2,
    threads: int = 1,
    repeats: int = 5,
    env_id: str = DEFAULT_ENV_ID,
    device: str = "cpu",
    cuda_graph: bool = True,
    compile_rollout: bool = False,
    heap_contrast: bool = False,
    variants: tuple[str, ...] = VARIANTS,
    reference_repo: str | None = None,
) -> dict[str, float]:
    """Median wall and CPU seconds of one optimisation step (rollout, backward, Adam) on the
    task of ``env_id`` (its :class:`~mcpilco.agents.mc_pilco.TaskSpec`: state and action
    sizes, GP outputs, cost) over ``horizon`` steps (None: the task's horizon), the GP with
    ``kernel`` (and ``mpk_degree``) fitted on ``n_points`` random-exploration transitions.

    ``compile_rollout``: also time the same step with a fast rollout
    (:func:`~mcpilco.agents.mc_pilco.use_fast_rollout`) of the default backend
    (``compiled_*``: ``native`` where it applies, else ``dynamo``), of the ``torch``
    backend (``torch_*``, the same chained maths in PyTorch ops, when the default is
    ``native``) and of ``torch.compile`` of the time step (``dynamo_*``, when the default is
    not already that), each on its own loss module sharing the policy and the GP posterior;
    the eager and the fast steps alternate within each round, so their ratios hold on a busy
    machine. ``variants``: which of :data:`VARIANTS` to time (``compiled`` is built first in
    any case: the others are timed where it is ``native``, as above); ``avx2`` (``avx2_*``):
    the native rollout built for x86-64-v3 (AVX2, FMA, no AVX-512;
    :data:`~mcpilco.agents.mc_pilco.fast.native.ISA_FLAGS`), on its own loss, checked
    against the eager rollout like the others (``avx2_compile_check``, its flags in
    ``avx2_build_flags``).
    ``reference_repo``: a checkout of the reference implementation; its own policy
    optimisation step (:class:`~mcpilco.experiments.mcpilco.reference.ReferenceStep`) on its
    matching task (:func:`~mcpilco.experiments.mcpilco.reference.reference_task`) with the
    same ``N``, particles, horizon and threads runs in the same rounds (``reference_*``:
    its seconds, task, data, points; ``reference_ratio``: its wall seconds over the fast
    step's, else the eager step's). The cart-pole's GP gets this run's transitions, the UR5's
    synthetic ones.
    ``compile_s``: the time of ``use_fast_rollout`` (the build and its check against
    the eager rollout, one step of each); ``compile_check`` its figures. A fast rollout that
    fails the check is not timed (``compiled_rejected``).

    ``floor_s``: :func:`variance_flops` at :func:`matmul_rate` on ``threads`` threads
    (``matmul_gflops``), the time the ``N``-squared part of a step needs at the least;
    ``products_floor_s``: :func:`product_flops` at that rate. ``native_stage_s``: with the
    native rollout, the seconds per step of each stage of its loops
    (:func:`~mcpilco.agents.mc_pilco.fast.native.stage_seconds`, summed over its threads),
    ``native_stage_floor_s`` the floor of each stage that runs products
    (:func:`stage_product_flops` at that rate per thread, summed over the threads like the
    clocks),
    ``native_group`` the tiles it runs together and ``native_kernel_rows_taken`` the share of
    RBF kernel rows its products took
    (:func:`~mcpilco.agents.mc_pilco.fast.native.kernel_rows`). The row holds :func:`cpu_info` too.

    The process keeps its freed memory (:func:`~mcpilco.models.device.retain_host_memory`,
    as a training run does); ``page_faults_per_step`` counts the minor page faults of each
    timed step. ``heap_contrast``: also time the eager step with glibc's initial heap thresholds
    (128 KiB, where its adaptive rule can stay), in the same rounds (``heap128k_*``); each
    timed step then follows an untimed one in the same setting.

    On a CUDA ``device`` the GP is fitted on the CPU and its posterior, the policy and the
    particles move to the device; each timed step ends with a synchronisation, and with
    ``cuda_graph`` the forward and backward pass is one replayed CUDA graph, as in
    :func:`~mcpilco.agents.mc_pilco.optimize_policy`.
    """
    import torch

    from mcpilco.agents.mc_pilco import (
        GPDynamicsModel,
        MCPilcoLoss,
        SaturatingCost,
        SquashedRBFPolicy,
        StateLayout,
        make_policy_module,
        use_fast_rollout,
    )
    from mcpilco.agents.mc_pilco.optimize import loss_and_grad_fn
    from mcpilco.models.device import (
        GLIBC_INITIAL_THRESHOLD,
        resolve_device,
        retain_host_memory,
    )

    dev = resolve_device(device)
    sync = torch.cuda.synchronize if dev.type == "cuda" else (lambda: None)
    torch.set_num_threads(threads)
    retain_host_memory()
    unknown = set(variants) - set(VARIANTS)
    if unknown:
        raise ValueError(f"variants must be among {VARIANTS}, got {sorted(unknown)}")
    s, a, s1, _ = exploration_data(env_id, n_points, 0)
    task, _ = timing_task(env_id)
    horizon = task.horizon if horizon is None else int(horizon)
    model = GPDynamicsModel(
        task, kernel=kernel, mpk_degree=mpk_degree, adam_iters=30, lbfgs_iters=5, max_points=None
    )
    model.fit(s, a, s1)
    policy = SquashedRBFPolicy(
        StateLayout.from_task(task), task.action_low, task.action_high, seed=0
    )
    module, dynamics = make_policy_module(policy), model.particle_dynamics()
    cost = SaturatingCost.from_task(task)

    def make_loss() -> MCPilcoLoss:  # moves the policy and the GP posterior with it
        args = (module, dynamics, cost, horizon, num_particles, task.init_mean)
        return MCPilcoLoss(*args, obs_noise_std=0.01).to(dev)

    opt = torch.optim.Adam(policy.parameters(), lr=0.01)
    policy.train()
    # the optimiser's own step: eager on the CPU, one CUDA graph on a GPU (captured here)
    params = list(policy.parameters())
    step_fns = {"eager": loss_and_grad_fn(make_loss(), params, cuda_graph=cuda_graph)}
    compile_info: dict[str, object] = {}
    compiled_losses = []
    if compile_rollout:
        # "compiled": the default backend (native where it applies, else dynamo); "torch":
        # the chained rollout in PyTorch ops; "dynamo": torch.compile of the time step
        for name, backend in (("compiled", "auto"), ("torch", "torch"), ("dynamo", "dynamo")):
            if name == "torch" and compile_info.get("compile_backend") != "native":
                continue  # the chained rollout does not apply here
            if name != "compiled" and name not in variants:
                continue
            compiled = make_loss()
            t_compile = time.perf_counter()
            fast = use_fast_rollout(compiled, backend=backend, dynamic=False)
            prefix = "" if name == "compiled" else f"{name}_"
            compile_info.update(
                {
                    f"{prefix}compile_backend": fast.backend,
                    f"{prefix}rollout_shards": fast.shards,
                    f"{prefix}compile_s": time.perf_counter() - t_compile,
                    f"{prefix}compile_check": fast.check,
                    f"{prefix}compile_error": fast.error,
                    f"{prefix}compiled_rejected": not fast.in_use,
                }
            )
            compiled_losses.append(compiled)
            if fast.in_use:
                step_fns[name] = loss_and_grad_fn(compiled, params, cuda_graph=cuda_graph)
            if fast.backend == "dynamo" and name == "compiled":
                break  # the default already is dynamo here
    if "avx2" in variants and compile_info.get("compile_backend") == "native":
        from mcpilco.agents.mc_pilco.fast.check import check_against_eager, passes
        from mcpilco.agents.mc_pilco.fast.native import NativeRollout, cxx_flags

        compiled = make_loss()
        t_compile = time.perf_counter()
        compile_info["avx2_build_flags"] = " ".join(cxx_flags("avx2"))
        try:
            engine = NativeRollout(
                compiled.policy_module, compiled.dynamics, compiled.cost,
                compiled.num_candidates * num_particles, compiled.delta_dim,
                shards=int(compile_info["rollout_shards"]), isa="avx2",
            )  # fmt: skip
            compiled.set_fast_rollout(engine)
            check = check_against_eager(compiled)
            compile_info.update(
                {"avx2_compile_s": time.perf_counter() - t_compile, "avx2_compile_check": check}
            )
            if passes(check):
                step_fns["avx2"] = loss_and_grad_fn(compiled, params, cuda_graph=cuda_graph)
                compiled_losses.append(compiled)
            else:
                compile_info["avx2_compiled_rejected"] = True
        except (RuntimeError, ValueError) as err:  # no AVX2 build on this CPU or compiler
            compile_info["avx2_compile_error"] = str(err).splitlines()[0][:500]
    reference = None
    if reference_repo is not None:
        from mcpilco.experiments.mcpilco.reference import ReferenceStep, reference_task

        ref_task = reference_task(env_id)
        reference = ReferenceStep(
            reference_repo, ref_task, n_points, num_particles, horizon,
            transitions=(s, a, s1) if ref_task == "cartpole" else None,
        )  # fmt: skip
        torch.set_num_threads(threads)
        try:  # one step first: a reference step that fails is recorded, not timed
            reference()
            step_fns["reference"] = reference
        except (RuntimeError, ValueError) as err:  # its NaN guard, its sampler's check
            compile_info["reference_error"] = str(err).splitlines()[0][:500]
            reference = None
    if heap_contrast:
        step_fns["heap128k"] = step_fns["eager"]
    engine = compiled_losses[0].fast_rollout[0] if compiled_losses else None
    native_engine = engine if type(engine).__name__ == "NativeRollout" else None
    stage_totals: dict[str, float] = {}
    rows_taken = [0, 0]
    walls: dict[str, list[float]] = {k: [] for k in step_fns}
    cpus: dict[str, list[float]] = {k: [] for k in step_fns}
    faults: dict[str, list[int]] = {k: [] for k in step_fns}
    for i in range(repeats + 1):
        for name, step_fn in step_fns.items():
            if name == "reference":  # it clocks its own step (its setup calls untimed)
                wall, cpu = step_fn()
                if i:
                    walls[name].append(wall)
                    cpus[name].append(cpu)
                continue
            if name == "heap128k":
                retain_host_memory(GLIBC_INITIAL_THRESHOLD, GLIBC_INITIAL_THRESHOLD)
            if heap_contrast:  # one untimed step after each switch: the heap settles first
                step_fn()
                opt.step()
            sync()
            t, c = time.perf_counter(), time.process_time()
            f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
            if native_engine is not None and name == "compiled":
                from mcpilco.agents.mc_pilco.fast.native import kernel_rows, stage_seconds

                stage_seconds(reset=True)
                kernel_rows(reset=True)
            step_fn()
            opt.step()
            sync()
            if i and native_engine is not None and name == "compiled":
                for stage, sec in stage_seconds().items():
                    stage_totals[stage] = stage_totals.get(stage, 0.0) + sec / repeats
                rows_taken = [x + y for x, y in zip(rows_taken, kernel_rows(), strict=True)]
            if i:  # the first round is a warm-up
                walls[name].append(time.perf_counter() - t)
                cpus[name].append(time.process_time() - c)
                faults[name].append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
            if name == "heap128k":
                retain_host_memory()
    out = {
        "env_id": env_id,
        "state_dim": dynamics.layout.n,
        "action_dim": policy.action_dim,
        "gp_outputs": dynamics.layout.output_dim,
        "kernel": kernel,
        "mpk_degree": mpk_degree if kernel == "rbf+mpk" else None,
        "horizon": horizon,
        "n_points": n_points,
        "num_particles": num_particles,
        "threads": threads,
        "device": str(dev),
        "cuda_graph": bool(cuda_graph and dev.type == "cuda"),
        "s_per_step_wall": statistics.median(walls["eager"]),
        "s_per_step_cpu": statistics.median(cpus["eager"]),
        "page_faults_per_step": statistics.median(faults["eager"]),
    }
    rate = matmul_rate(threads) if dev.type == "cpu" else float("nan")
    flops = variance_flops(n_points, num_particles, dynamics.layout.output_dim, horizon)
    pred = dynamics.delta_model
    features = getattr(getattr(pred, "row_blocks", None), "features", 0) or 0
    inputs = dynamics.layout.feature_dim + policy.action_dim
    pflops = product_flops(
        n_points, features, inputs, num_particles, dynamics.layout.output_dim, horizon
    )
    out.update(
        {"matmul_gflops": rate / 1e9, "floor_s": flops / rate, "products_floor_s": pflops / rate}
    )
    out.update(cpu_info())
    if native_engine is not None:
        out["native_group"] = int(native_engine.model.group())
        out["native_stage_s"] = stage_totals
        out["native_stage_floor_s"] = {  # thread-seconds, as the stage clocks sum them
            stage: f * threads / rate
            for stage, f in stage_product_flops(
                n_points, features, inputs, num_particles, dynamics.layout.output_dim, horizon
            ).items()
        }
        if rows_taken[1]:
            out["native_kernel_rows_taken"] = rows_taken[0] / rows_taken[1]
    out.update(compile_info)
    for name in ("compiled", "torch", "dynamo", "avx2", "heap128k"):
        if name in step_fns:
            out.update(
                {
                    f"{name}_s_per_step_wall": statistics.median(walls[name]),
                    f"{name}_s_per_step_cpu": statistics.median(cpus[name]),
                    f"{name}_page_faults_per_step": statistics.median(faults[name]),
                }
            )
    if reference is not None:
        wall = statistics.median(walls["reference"])
        fast = out.get("compiled_s_per_step_wall", out["s_per_step_wall"])
        out.update(
            {
                "reference_task": reference.task,
                "reference_n_points": reference.n_points,
                "reference_data": (
                    "this run's transitions" if reference.task == "cartpole" else "synthetic"
                ),
                "reference_s_per_step_wall": wall,
                "reference_s_per_step_cpu": statistics.median(cpus["reference"]),
                "reference_ratio": wall / fast,
            }
        )
    for compiled in compiled_losses:
        compiled.set_fast_rollout(None)
    return out
