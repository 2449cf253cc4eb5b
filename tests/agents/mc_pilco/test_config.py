"""MC-PILCO's config round-trips through to_dict / from_dict for every shipped file and
preset; the names of fields added later stay private to the config module."""

from __future__ import annotations

import json

import pytest

from mcpilco.agents.mc_pilco import MCPilcoConfig, load_config
from mcpilco.agents.mc_pilco import config as config_module
from mcpilco.agents.mc_pilco.config import config_files


@pytest.mark.parametrize("env_id", sorted(config_files()))
def test_every_shipped_config_round_trips(env_id):
    import yaml

    presets = yaml.safe_load(config_files()[env_id].read_text()).get("presets") or {}
    for preset in ["default", *sorted(presets)]:
        cfg = load_config(env_id, preset=preset)
        saved = cfg.to_dict()
        assert MCPilcoConfig.from_dict(saved) == cfg
        # through JSON, as records.json and the checkpoints hold it
        assert MCPilcoConfig.from_dict(json.loads(json.dumps(saved))) == cfg


def test_the_default_config_round_trips_and_legacy_names_are_private():
    assert MCPilcoConfig.from_dict(MCPilcoConfig().to_dict()) == MCPilcoConfig()
    public = [n for n in vars(config_module) if "LEGACY" in n and not n.startswith("_")]
    assert public == []
    # a config saved before explore_hold, policy_init and push_filter existed
    old = {k: v for k, v in MCPilcoConfig().to_dict().items()}
    for name in ("explore_hold", "policy_init", "push_filter"):
        old.pop(name)
    cfg = MCPilcoConfig.from_dict(old)
    assert (cfg.explore_hold, cfg.policy_init, cfg.push_filter) == (1, "box", None)
