"""Command-line checks of ``mcpilco-train``: clear errors for bad arguments, options that
reach the config, a tiny run."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pytest
import yaml

from mcpilco.agents.mc_pilco import cli as mc_cli
from mcpilco.envs.tasks import task_data


@pytest.fixture
def error_of(command, capsys):
    """``error_of(argv)``: the stderr of ``mcpilco-train argv``, which must exit 2."""

    def error_of(argv) -> str:
        assert command("mcpilco-train", argv) == 2  # argparse usage error
        return capsys.readouterr().err

    return error_of


@pytest.fixture
def config_of(command, monkeypatch, tmp_path):
    """``config_of(argv)``: the config that ``mcpilco-train argv`` would run (the run itself
    replaced by one that records its config)."""
    seen = []

    class FakeTrainer:
        def __init__(self, config, out_dir, **_kwargs):
            seen.append(config)
            self.out_dir = Path(out_dir)

        def run(self):
            return SimpleNamespace(
                seconds=0.0,
                success=False,
                first_success_trial=None,
                out_dir=self.out_dir,
                checkpoint=self.out_dir / "checkpoint.pt",
                rrd=None,
                pngs=[],
            )

    monkeypatch.setattr(mc_cli, "Trainer", FakeTrainer)

    def config_of(argv):
        assert command("mcpilco-train", [*argv, "--out", str(tmp_path / "run")]) == 0
        return seen[-1]

    return config_of


def test_unknown_env_lists_the_envs_with_a_task(tmp_path, error_of):
    err = error_of(["--env", "mcpilco/Nope-v0", "--out", str(tmp_path)])
    assert "no task specification ships for 'mcpilco/Nope-v0'" in err
    assert "mcpilco/CartpoleSwingUp-v0" in err and "mcpilco/DMCCartpoleSwingUp-v0" in err


def test_a_kinematics_task_is_refused_before_a_run_folder_exists(tmp_path, error_of):
    """MC-PILCO reaches through learned kinematics on the marker camera (TaskSpec.model):
    the GP-dynamics agent says so and where the reaching agent is, and writes nothing."""
    out = tmp_path / "run"
    err = error_of(["--env", "mcpilco/MarkerCameraReach-v0", "--out", str(out)])
    assert "learns the kinematics on this task" in err and "--reaching-seeds" in err
    assert not out.exists()


def test_unknown_env_with_a_task_file_lists_registered_ids(tmp_path, error_of):
    task = tmp_path / "nope.yaml"
    task.write_text(
        yaml.safe_dump({**task_data("mcpilco/CartpoleSwingUp-v0"), "env_id": "mcpilco/Nope-v0"})
    )
    argv = ["--env", "mcpilco/Nope-v0", "--task", str(task), "--out", str(tmp_path)]
    err = error_of(argv)
    assert "unknown env id 'mcpilco/Nope-v0'" in err
    assert "mcpilco/CartpoleSwingUp-v0" in err and "mcpilco/DMCCartpoleSwingUp-v0" in err


def test_task_file_reaches_the_config_and_its_errors_name_the_field(tmp_path, error_of, config_of):
    data = task_data("mcpilco/CartpoleSwingUp-v0")
    task = tmp_path / "task.yaml"
    task.write_text(yaml.safe_dump({**data, "horizon": 60, "init_std": 0.02}))
    cfg = config_of(["--task", str(task)])
    assert cfg.task["init_std"] == 0.02 and cfg.task_spec().init_std == (0.02,) * 4
    task.write_text(yaml.safe_dump({**data, "angles": ["phi"]}))
    err = error_of(["--task", str(task), "--out", str(tmp_path)])
    assert "task.angles[0]: unknown state name 'phi'" in err
    err = error_of(["--task", str(tmp_path / "missing.yaml"), "--out", str(tmp_path)])
    assert "--task" in err and "missing.yaml" in err


@pytest.mark.parametrize("value", ["0", "-3", "ten"])
def test_non_positive_particles_is_an_error(value, tmp_path, error_of):
    err = error_of(["--particles", value, "--out", str(tmp_path)])
    assert "--particles" in err


def test_horizon_mismatch_is_an_error(tmp_path, error_of):
    err = error_of(["--horizon", "40", "--out", str(tmp_path)])
    assert "horizon mismatch" in err and "60" in err


def test_unknown_kernel_is_an_error(tmp_path, error_of):
    err = error_of(["--kernel", "linear", "--out", str(tmp_path)])
    assert "--kernel" in err


def test_overrides_reach_the_config(config_of):
    cfg = config_of(
        ["--preset", "demo", "--trials", "2", "--particles", "7", "--opt-steps", "9"]
        + ["--candidates", "3", "--explore-hold", "1"]
    )
    assert (cfg.num_trials, cfg.num_particles, cfg.opt.max_steps) == (2, 7, 9)
    assert cfg.explore_hold == 1
    assert cfg.opt_steps_first <= 9 and cfg.num_candidates == 3


def test_set_overrides_nested_fields_and_the_options_win(config_of):
    cfg = config_of(
        ["--set", "opt.max_steps=5", "--set", "num_particles=9", "--set", "cost_angle_mode=wrap"]
        + ["--set", "cost_length_scales={x: 2.0}", "--preset", "bench"]
    )
    assert (cfg.opt.max_steps, cfg.opt.monitor_patience) == (5, 100)  # the preset's patience
    assert cfg.num_particles == 9 and cfg.cost_angle_mode == "wrap"
    assert cfg.cost_length_scales == {"x": 2.0, "theta": 3.0}
    assert config_of(["--set", "num_particles=9", "--particles", "11"]).num_particles == 11


def test_unknown_preset_or_field_is_an_error(tmp_path, error_of):
    err = error_of(["--preset", "fast", "--out", str(tmp_path)])
    assert "unknown preset 'fast'" in err and "bench" in err and "demo" in err
    err = error_of(["--set", "particles=3", "--out", str(tmp_path)])
    assert "unknown MC-PILCO config fields ['particles']" in err
    err = error_of(["--set", "num_particles", "--out", str(tmp_path)])
    assert "--set takes key=value" in err


def test_dm_control_env_gets_iid_exploration_unless_told(config_of):
    dmc = ["--env", "mcpilco/DMCCartpoleSwingUp-v0"]
    assert config_of(dmc).explore_hold == 1
    assert config_of(dmc + ["--explore-hold", "2"]).explore_hold == 2
    assert config_of([]).explore_hold == 2


def test_zero_candidates_is_an_error(tmp_path, error_of):
    err = error_of(["--candidates", "0", "--out", str(tmp_path)])
    assert "--candidates" in err


def test_tiny_training_run(tmp_path, capsys, command):
    out = tmp_path / "run"
    argv = ["--preset", "demo", "--trials", "1", "--particles", "8", "--opt-steps", "3"]
    argv += ["--threads", "1", "--no-progress", "--no-rrd", "--out", str(out), "--seed", "1"]
    assert command("mcpilco-train", argv) == 0
    text = capsys.readouterr().out
    assert "trial 1 (policy" in text and "success" in text and "done in" in text
    records = json.loads((out / "records.json").read_text())["records"]
    assert [r["opt_steps"] for r in records if r["kind"] == "policy"] == [3]
    assert (out / "checkpoint.pt").is_file()


# --------------------------------------------------------------------- a user's own env
USER_ENV = "tests.user_pendulum:UserPendulum-v0"  # a module under tests/ that registers it


def _user_task(tmp_path: Path, **changes) -> Path:
    """A task file for the user's pendulum: the angle derived from its (cos, sin) pair."""
    task = {
        "env_id": "UserPendulum-v0",
        "state_names": ["theta", "theta_dot"],
        "state_from": {"theta": {"cos": 0, "sin": 1}, "theta_dot": {"index": 2}},
        "angles": ["theta"],
        "pairs": [["theta", "theta_dot"]],
        "action_low": [-2.0],
        "action_high": [2.0],
        "dt": 0.05,
        "horizon": 20,
        "init_mean": [3.141592653589793, 0.0],
        "init_std": [1.8, 0.01],
        "cost": {"terms": [{"state": "theta", "target": 0.0, "length_scale": 1.0}]},
        "success": {"window": 5, "bounds": {"theta": {"target": 0.0, "tol": 0.3}}},
        **changes,
    }
    path = tmp_path / "my_task.yaml"
    path.write_text(yaml.safe_dump(task))
    return path


def test_a_users_env_by_module_path_trains_one_trial(tmp_path, capsys, command):
    """``--env pkg.module:Id --task file.yaml``: the module is imported (it registers the id),
    the env made as gymnasium.make does, and one short policy trial runs on it."""
    out = tmp_path / "run"
    argv = ["--env", USER_ENV, "--task", str(_user_task(tmp_path)), "--trials", "1"]
    argv += ["--particles", "8", "--opt-steps", "3", "--set", "max_points=30"]
    argv += ["--set", "num_basis=10", "--set", "gp_adam_iters=5", "--set", "gp_lbfgs_iters=5"]
    argv += ["--threads", "1", "--no-progress", "--no-rrd", "--out", str(out), "--seed", "2"]
    assert command("mcpilco-train", argv) == 0
    assert "trial 1 (policy" in capsys.readouterr().out
    records = json.loads((out / "records.json").read_text())["records"]
    assert [r["kind"] for r in records] == ["exploration", "policy"]


def test_env_kwargs_and_a_users_config_file_reach_the_config(tmp_path, config_of):
    """``--env-kwargs`` (inline YAML or a file) is passed to gym.make; ``--config`` is a config
    file of the shipped format, merged over the shipped one and under ``--set``."""
    task = str(_user_task(tmp_path))
    mine = tmp_path / "my.yaml"
    mine.write_text(
        "env_id: UserPendulum-v0\nconfig: {num_particles: 17, num_basis: 12}\n"
        "presets:\n  quick: {num_trials: 1, num_particles: 19}\n"
    )
    cfg = config_of(["--env", USER_ENV, "--task", task, "--config", str(mine)])
    assert (cfg.num_particles, cfg.num_basis, cfg.num_trials) == (17, 12, 5)
    cfg = config_of(["--env", USER_ENV, "--task", task, "--config", str(mine), "--preset", "quick"])
    assert (cfg.num_particles, cfg.num_trials) == (19, 1)
    cfg = config_of(
        ["--env", USER_ENV, "--task", task, "--config", str(mine), "--set", "num_particles=5"]
    )
    assert cfg.num_particles == 5
    cfg = config_of(["--env", USER_ENV, "--task", task, "--env-kwargs", "{max_torque: 3.0}"])
    assert cfg.env_kwargs == {"max_torque": 3.0}
    kwargs = tmp_path / "kwargs.yaml"
    kwargs.write_text("max_torque: 2.5\n")
    cfg = config_of(["--env", USER_ENV, "--task", task, "--env-kwargs", str(kwargs)])
    assert cfg.env_kwargs == {"max_torque": 2.5}
    # the shipped file of a shipped env comes first, the user's over it
    mine.write_text("config: {num_particles: 23}\n")
    cfg = config_of(["--config", str(mine)])
    assert cfg.num_particles == 23 and cfg.explore_hold == 2  # the shipped file's hold


def _other_task(tmp_path: Path) -> str:
    path = _user_task(tmp_path)
    path.write_text(path.read_text().replace("UserPendulum-v0", "Other-v0"))
    return str(path)


def test_users_env_errors_are_one_line_naming_what_is_wrong(tmp_path, error_of):
    task = str(_user_task(tmp_path))
    err = error_of(
        ["--env", "tests.no_such_module:UserPendulum-v0", "--task", task, "--out", str(tmp_path)]
    )
    assert "cannot import module 'tests.no_such_module'" in err
    err = error_of(["--env", "tests.user_pendulum:Other-v0", "--task", _other_task(tmp_path)])
    assert "module 'tests.user_pendulum' registers no env id 'Other-v0'" in err
    task = str(_user_task(tmp_path))
    err = error_of(["--env", USER_ENV, "--task", task, "--env-kwargs", "{no_such_arg: 1}"])
    assert "env_kwargs" in err and "no_such_arg" in err
    err = error_of(["--env", USER_ENV, "--task", task, "--env-kwargs", "[1, 2]"])
    assert "--env-kwargs" in err and "mapping" in err
    err = error_of(["--env", USER_ENV, "--task", task, "--config", str(tmp_path / "nope.yaml")])
    assert "nope.yaml" in err
    bad = tmp_path / "bad.yaml"
    bad.write_text("config: {num_particles: 3}\nhyper: {}\n")
    err = error_of(["--env", USER_ENV, "--task", task, "--config", str(bad)])
    assert "unknown keys ['hyper']" in err


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"state_from": {"theta": {"cos": 0, "sin": 5}, "theta_dot": {"index": 2}}}, "sin"),
        ({"state_from": {"theta": {"cos": 0}, "theta_dot": {"index": 2}}}, "theta.sin"),
        ({"state_from": {"theta": {"cos": 0, "sin": 1}}}, "state_from.theta_dot"),
        ({"env_reset_options": {"spread": 0.1}}, "task.success.bounds"),
    ],
)
def test_a_task_that_cannot_be_learned_is_refused_before_any_trial(
    tmp_path, error_of, changes, field
):
    """An unobservable state, a derived pair with a missing half, a success set that every
    sampled reset already lies in: one line naming the field, and no run folder."""
    out = tmp_path / "run"
    err = error_of(["--env", USER_ENV, "--task", str(_user_task(tmp_path, **changes))]
                   + ["--out", str(out)])  # fmt: skip
    assert field in err and len(err.strip().splitlines()[-1]) > 0
    assert not out.exists()


def test_a_module_in_the_current_folder_is_found(tmp_path, monkeypatch, config_of):
    """``--env my_envs:Id`` with ``my_envs.py`` in the current folder (not on the Python path)
    imports it, as ``python -m`` would find it."""
    import sys

    source = (Path(__file__).parents[1] / "user_pendulum.py").read_text()
    (tmp_path / "my_cwd_envs.py").write_text(source.replace("UserPendulum-v0", "CwdPendulum-v0"))
    monkeypatch.setattr(sys, "path", [p for p in sys.path if p not in ("", str(tmp_path))])
    monkeypatch.chdir(tmp_path)
    task = _user_task(tmp_path)
    task.write_text(task.read_text().replace("UserPendulum-v0", "CwdPendulum-v0"))
    cfg = config_of(["--env", "my_cwd_envs:CwdPendulum-v0", "--task", str(task)])
    assert cfg.env_id == "my_cwd_envs:CwdPendulum-v0"
    assert "my_cwd_envs" in sys.modules
    monkeypatch.delitem(sys.modules, "my_cwd_envs")
