"""Smoke test of ``mcpilco-bench-markers``: a tiny rendered run writes its outputs and its
statistics agree with a direct recomputation from the same frames."""

import pytest

from mcpilco.experiments.results import read_result

pytest.importorskip("cv2", reason="the rendered marker path needs OpenCV (mcpilco[vision])")


def test_tiny_rendered_run_writes_outputs(command, tmp_path, gl_in_process):
    rc = command("mcpilco-bench-markers",
                 ["--frames", "24", "--image-size", "960", "540", "--marker-size", "0.2",
                  "--out-dir", str(tmp_path), "--no-progress"])  # fmt: skip
    assert rc == 0
    res = read_result(tmp_path / "marker_detection.json").payload()
    assert res["config"]["frames"] == 25  # the start frame + one per segment
    per = res["per_marker"]
    assert len(per) == 7
    # the overall rate is the mean of the per-marker rates (same frames for every marker)
    assert res["overall"]["detection_rate"] == pytest.approx(
        sum(r["detection_rate"] for r in per) / 7
    )
    for name in ("marker_detection.md", "marker_detection.png", "marker_detection_frame.png"):
        assert (tmp_path / name).stat().st_size > 0
    assert command("mcpilco-bench-markers", ["--frames", "10", "--out-dir", str(tmp_path)]) == 2
