"""Gymnasium MuJoCo environments of mcpilco.

Importing this package registers the environments with string entry points, so that no
MuJoCo model is built and nothing from ``agents``/``models`` is imported at registration.
"""
