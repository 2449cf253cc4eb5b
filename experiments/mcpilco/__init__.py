"""MC-PILCO experiments: the benchmark of ``mcpilco-bench-mcpilco`` (:mod:`.bench` with its
``timing``, ``rmse`` and ``tracking`` parts), the comparison with PILCO and SB3 of
``mcpilco-compare`` (:mod:`.compare`), the GP predictor timings (:mod:`.gp_predictor`) and the
demo (:mod:`.demo`)."""
