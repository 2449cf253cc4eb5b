"""Learning agents: MC-PILCO and adapters for baselines. Imports ``models``, reads ``envs``."""
