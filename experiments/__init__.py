"""Experiment infrastructure shared by the benchmarks: the resumable sweep runner.

:mod:`mcpilco.experiments.sweep` runs lists of independent jobs (a seed of a method on an
env, a Monte Carlo run of a benchmark) in local processes or on Ray, one result file per job;
:mod:`mcpilco.experiments.probe` holds small calibrated jobs to check a backend with, and
:mod:`mcpilco.experiments.overhead` measures the runner's overhead per job.
"""
