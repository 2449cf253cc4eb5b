"""Diagnosis experiments: the benchmark of ``mcpilco-bench-diagnosis`` on simulated robot logs
(:mod:`.bench`, scored by :mod:`.scoring`), the torque-constant benchmark
(:mod:`.torque_constants`) and the robot data with injected hidden effects
(:mod:`.hidden_effects`)."""
