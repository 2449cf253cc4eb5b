"""MC-PILCO: Monte Carlo probabilistic inference for learning control (thesis ch. 5)."""
