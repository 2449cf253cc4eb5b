"""Experiments: the benchmarks by capability, the one result schema they write, the results
index, and the infrastructure they share.

* :mod:`mcpilco.experiments.mcpilco`: MC-PILCO (the benchmark, the comparison with PILCO and
  SB3, the GP predictor timings, the demo, the headline figure);
* :mod:`mcpilco.experiments.kinematics`, :mod:`~mcpilco.experiments.collision`,
  :mod:`~mcpilco.experiments.diagnosis`, :mod:`~mcpilco.experiments.identification`
  (Volterra series, inverse dynamics): the other capabilities;
* :mod:`mcpilco.experiments.infra`: the resumable sweep runner, probe jobs, its overhead,
  the robustness figures and the conversion of result files written before the schema;
* :mod:`mcpilco.experiments.results`: the result file every bench writes and its reader;
  :mod:`mcpilco.experiments.benches`: the registered benches (layouts, headline rows,
  replots); :mod:`mcpilco.experiments.results_index`: ``results/README.md`` from them.
"""
