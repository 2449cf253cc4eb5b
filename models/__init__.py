"""Gaussian-process models with physics-structured kernels.

Sub-packages:

* :mod:`mcpilco.models.gp` -- exact multi-output GP regression on GPyTorch and a cached,
  differentiable predictor for rollouts.
* :mod:`mcpilco.models.kernels` -- linear, PK/IPK, MPK, SED-MPK and GIP kernels.

``models`` imports neither ``agents`` nor ``envs``.
"""
