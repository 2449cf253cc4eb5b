"""Exact multi-output GP regression on GPyTorch and a cached predictor for rollouts."""
