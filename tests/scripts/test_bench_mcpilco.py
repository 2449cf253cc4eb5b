"""The MC-PILCO benchmark script: seeds resumed from their checkpoints, argument checks."""

from __future__ import annotations

import dataclasses

import pytest

from mcpilco.scripts.bench_mcpilco import _run_seed, main


def test_finished_seed_is_resumed_not_rerun(tmp_path):
    from tests.agents.mc_pilco.test_loop import SMOKE

    job = (dataclasses.replace(SMOKE, num_trials=0).to_dict(), str(tmp_path / "seed3"))
    first = _run_seed(job)
    ckpt = tmp_path / "seed3" / "checkpoint.pt"
    stamp = ckpt.stat().st_mtime_ns
    again = _run_seed(job)
    # a re-run would have rewritten the checkpoint and measured new wall-clock times
    assert ckpt.stat().st_mtime_ns == stamp
    assert again["records"] == first["records"] and again["seconds"] == first["seconds"] > 0


def test_candidate_scales_must_match_candidates(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(
            ["--parts", "runs", "--candidates", "3", "--candidate-scales", "0.01", "0.1"]
            + ["--out", str(tmp_path), "--runs-dir", str(tmp_path / "runs")]
        )
    assert "candidate_weight_scales must hold num_candidates=3" in capsys.readouterr().err
