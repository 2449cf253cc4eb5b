"""Experiments: the benchmarks' protocols, aggregation and reports, and the sweep runner they
share.

:mod:`mcpilco.experiments.infra.sweep` runs lists of independent jobs (a seed of a method on an
env, a Monte Carlo run of a benchmark) in local processes or on Ray, one result file per job;
:mod:`mcpilco.experiments.infra.probe` holds small calibrated jobs to check a backend with, and
:mod:`mcpilco.experiments.infra.overhead` measures the runner's overhead per job.
:mod:`mcpilco.experiments.mcpilco.bench` (with :mod:`~mcpilco.experiments.mcpilco.timing` and
:mod:`~mcpilco.experiments.mcpilco.rmse`) is the MC-PILCO benchmark,
:mod:`mcpilco.experiments.mcpilco.compare` the comparison with PILCO and SB3, and
:mod:`mcpilco.experiments.infra.robustness` the robustness figures (bad, fuzzed inputs,
killed runs).
"""
