"""The run's plots and Rerun recording: a tracked state's reference and the transitions left
out of the dynamics data appear where the docstring of :mod:`mcpilco.agents.mc_pilco.viz`
says, read back from the files."""

from __future__ import annotations

import numpy as np

from mcpilco.agents.mc_pilco.viz import plot_trial_particles, write_rerun_recording

NAMES = ["q1", "qd1", "r1", "rd1"]


def _trial(index: int, excluded: np.ndarray | None) -> dict:
    t = np.arange(11) * 0.1
    real = np.column_stack([np.sin(t) + 0.01, np.cos(t), np.sin(t), np.cos(t)])
    parts = real[None] + 0.01 * np.random.default_rng(index).normal(size=(5, 11, 4))
    return {
        "index": index,
        "particles": parts,
        "real": real,
        "excluded": excluded,
        "opt_costs": np.linspace(3.0, 1.0, 6),
        "gp_rmse": np.array([0.1, 0.2]),
        "cost": 1.0,
        "time_in_goal": 0.0,
        "success": False,
    }


def test_recording_has_the_reference_and_the_excluded_transitions(tmp_path):
    from rerun.chunk import RrdReader

    hit = np.zeros(10, dtype=bool)
    hit[[2, 7]] = True
    path = write_rerun_recording(
        tmp_path / "run.rrd",
        [_trial(0, None), _trial(1, hit)],
        0.1,
        NAMES,
        ["delta_qd1", "delta_rd1"],
        references={"q1": "r1"},
    )
    text = RrdReader(path).store().summary()
    assert "/particles/q1/reference" in text
    assert "/particles/qd1/reference" not in text  # no cost term tracks qd1
    assert "/particles/q1/excluded" in text and "/particles/rd1/excluded" in text


def test_particle_plot_draws_the_reference_and_marks_excluded_states(tmp_path, monkeypatch):
    import matplotlib.axes

    drawn: list[tuple[str, np.ndarray]] = []
    original = matplotlib.axes.Axes.plot

    def spy(self, *args, **kwargs):
        drawn.append((kwargs.get("label"), np.asarray(args[1]) if len(args) > 1 else None))
        return original(self, *args, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "plot", spy)
    trial = _trial(0, None)
    hit = np.zeros(10, dtype=bool)
    hit[[2, 7]] = True
    path = plot_trial_particles(
        tmp_path / "p.png",
        trial["particles"],
        trial["real"],
        0.1,
        NAMES,
        references={"q1": "r1"},
        excluded=hit,
    )
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    refs = [y for label, y in drawn if label == "reference (r1)"]
    assert len(refs) == 1 and np.allclose(refs[0], trial["real"][:, 2])
    marks = [y for label, y in drawn if label == "not in GP data"]
    assert len(marks) == len(NAMES)  # one set per panel, at the states x_2 and x_7
    assert np.allclose(marks[0], trial["real"][[2, 7], 0])


def test_pushes_are_shaded_in_the_plot_and_drawn_in_the_recording(tmp_path, monkeypatch):
    """A trial with pushes during transitions 3-5 and 8: the plot shades [t_3, t_6] and
    [t_8, t_9] in every panel; the recording has ``particles/<state>/push``."""
    import matplotlib.axes
    from rerun.chunk import RrdReader

    spans: list[tuple[float, float]] = []
    original = matplotlib.axes.Axes.axvspan

    def spy(self, a, b, **kwargs):
        spans.append((a, b))
        return original(self, a, b, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "axvspan", spy)
    trial = _trial(0, None)
    contact = np.zeros(10, dtype=bool)
    contact[[3, 4, 5, 8]] = True
    plot_trial_particles(
        tmp_path / "p.png", trial["particles"], trial["real"], 0.1, NAMES, contact=contact
    )
    assert len(spans) == 2 * len(NAMES)
    np.testing.assert_allclose(spans[:2], [(0.3, 0.6), (0.8, 0.9)])
    path = write_rerun_recording(
        tmp_path / "run.rrd", [dict(trial, contact=contact)], 0.1, NAMES, ["a", "b"]
    )
    text = RrdReader(path).store().summary()
    assert "/particles/q1/push" in text and "/particles/rd1/push" in text
