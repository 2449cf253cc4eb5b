"""The learned-start benchmark's faces: bad variants and evaluation seeds are refused
before any simulation; the table lists every variant's ratios."""

import pytest

from mcpilco.experiments.diagnosis.learned_start import main, markdown, run_case


def test_unknown_variant_and_evaluation_seed_are_refused(capsys) -> None:
    with pytest.raises(ValueError, match="unknown variants"):
        run_case(0, 3, "RRR", variants=["gip", "magic"])
    assert main(["--seeds", "1000"]) == 2
    assert "not development seeds" in capsys.readouterr().err


def test_markdown_lists_every_variant() -> None:
    rec = {
        "seed": 3,
        "arm": "RRR",
        "sample_time": 0.004,
        "encoder_counts_per_rev": 32768,
        "train_rows": 2000,
        "variants": {
            "gip": {"rows": 600, "ratio": [1.5, 1.1, 2.0], "cpu_s": 10.0, "wall_s": 12.0},
            "chain": {
                "rows": 2000,
                "parameters": 30,
                "ratio": [1.0, 1.05, 1.1],
                "cpu_s": 30.0,
                "wall_s": 31.0,
            },
        },
    }
    text = markdown({"command": "python -m x", "cpus": 2}, [rec])
    assert (
        "| 3 | RRR | 4 | 32768 | 2000 | gip | 600 | - | 1.50 1.10 2.00 | 2.00 | 10 | 12 |" in text
    )
    assert "| chain | 2000 | 30 | 1.00 1.05 1.10 | 1.10 | 30 | 31 |" in text
    assert "Development seeds [3]" in text
    assert "Report seeds [1003]" in markdown({"command": "x", "cpus": 2}, [{**rec, "seed": 1003}])
