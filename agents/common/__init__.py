"""The runtime every agent, benchmark and console script shares.

* :mod:`~mcpilco.agents.common.trials`: trials on the system (make the env, run an episode,
  random exploration, the model's transitions, reset seeds, the outcome of an episode);
* :mod:`~mcpilco.agents.common.records`: the typed
  :class:`~mcpilco.agents.common.records.TrialRecord` of each trial and
  ``records.json``, written and read in one place;
* :mod:`~mcpilco.agents.common.checkpoint`: atomic, safe checkpoints and the resume checks;
* :mod:`~mcpilco.agents.common.run_folder`: run folders (lock, manifest, refusal to mix
  runs); :mod:`~mcpilco.agents.common.cli`: the one-line error handling of every console
  script.
"""
