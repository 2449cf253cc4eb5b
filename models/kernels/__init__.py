"""Kernels for structured GP regression: linear, PK/IPK, MPK, SED-MPK, GIP."""
