"""Pieces shared by the agents' runs and the console scripts: run folders (lock, manifest,
refusal to mix runs) and the one-line error handling of every console script."""
