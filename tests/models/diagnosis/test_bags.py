"""ROS 2 bags and MCAP files as diagnosis logs.

Independent truth: a forward-simulated log of :func:`mcpilco.envs.robot_logs.simulate_log`
written as Parquet and as ``sensor_msgs/JointState`` messages by the ROS libraries' own
writers (``rosbags`` for bag folders of sqlite3 and MCAP storage, ``mcap_ros2`` for a plain
MCAP file); the bag read back must give the same dataset, and the diagnosis the same result,
as the Parquet file.
"""

from __future__ import annotations

import dataclasses
import json
import warnings

import numpy as np
import pytest

pytest.importorskip("rosbags")

from mcpilco.envs.arm_builder import arm_to_xml  # noqa: E402
from mcpilco.envs.arms import random_arm  # noqa: E402
from mcpilco.envs.robot_logs import HiddenEffect, simulate_log, write_log  # noqa: E402
from mcpilco.models.diagnosis import run_diagnosis  # noqa: E402
from mcpilco.models.diagnosis.bags import (  # noqa: E402
    BagOptions,
    parse_joint_map,
    read_bag,
    write_joint_states,
)
from mcpilco.models.robot_data import load_dataset  # noqa: E402

NAMES = ["j1", "j2", "j3"]  # the joint names of arm_to_xml's file
K_T = np.array([0.5, -1.5, 2.0])  # joint-side torque constants of the current log [N m/A]


@pytest.fixture(scope="module")
def arm():
    return random_arm(3, seed=1, joint_types="RRR").rigid()


@pytest.fixture(scope="module")
def logs(arm, tmp_path_factory):
    """Two Parquet logs (seeds 0, 1) of the arm with a hidden damping on joint 2."""
    folder = tmp_path_factory.mktemp("logs")
    effects = [HiddenEffect("damping", 2, 0.5)]
    paths = [
        write_log(folder / f"log{s}.parquet", simulate_log(arm, effects, duration=4.0, seed=s))
        for s in (0, 1)
    ]
    xml = folder / "robot.xml"
    xml.write_text(arm_to_xml(arm, friction=False))
    return paths, xml


def _load(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return load_dataset(path)


def _mcap_file(path, ds, names, topic="/joint_states"):
    """A plain MCAP file of JointState messages written by ``mcap_ros2`` (not rosbags)."""
    from mcap_ros2.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    msgdef, _ = get_typestore(Stores.LATEST).generate_msgdef(
        "sensor_msgs/msg/JointState", ros_version=2
    )
    with path.open("wb") as f:
        writer = Writer(f)
        schema = writer.register_msgdef("sensor_msgs/msg/JointState", msgdef)
        for k, t in enumerate(ds.t):
            ns = 1_700_000_000_000_000_000 + int(round(t * 1e9))
            msg = {
                "header": {"stamp": {"sec": ns // 10**9, "nanosec": ns % 10**9}, "frame_id": ""},
                "name": list(names),
                "position": ds.q[k].tolist(),
                "velocity": [],
                "effort": ds.tau[k].tolist(),
            }
            writer.write_message(topic, schema, msg, log_time=ns, publish_time=ns)
        writer.finish()
    return path


@pytest.mark.parametrize("storage", ["sqlite3", "mcap", "plain-mcap"])
def test_bag_reads_back_the_log(logs, storage, tmp_path):
    """A log written as JointState messages (joint order shuffled in the bag) reads back as
    the Parquet file's columns, on the same time grid."""
    ds = _load(logs[0][0])
    order = [2, 0, 1]  # the bag lists the joints in another order than the model
    shuffled = dataclasses.replace(ds, q=ds.q[:, order], tau=ds.tau[:, order])
    names = [NAMES[k] for k in order]
    if storage == "plain-mcap":
        path = _mcap_file(tmp_path / "log.mcap", shuffled, names)
    else:
        path = write_joint_states(tmp_path / "bag", shuffled, names, storage=storage)
    back = read_bag(path, NAMES)
    np.testing.assert_allclose(back.t, ds.t - ds.t[0], atol=1e-9)
    np.testing.assert_allclose(back.q, ds.q, atol=1e-12)
    np.testing.assert_allclose(back.tau, ds.tau, atol=1e-9)
    assert back.metadata["computed"] == ["qd", "qdd"] and back.metadata["joint_names"] == NAMES


def test_diagnosis_on_the_bag_equals_the_diagnosis_on_parquet(logs, tmp_path):
    """The same run on the bags (an MCAP-storage bag for training, a sqlite3 one held out,
    bag joint names mapped by --joint-map) names the same effect with the same errors."""
    (train, test), xml = logs
    kw = dict(model=xml, auto=2, plots=False, rerun=False, sysid=False, log=lambda s: None)
    ref = run_diagnosis([train], [test], out=tmp_path / "parquet", **kw)
    bag_names = ["shoulder", "elbow", "wrist"]
    bags = [
        write_joint_states(tmp_path / f"bag{k}", _load(p), bag_names, storage=s)
        for k, (p, s) in enumerate([(train, "mcap"), (test, "sqlite3")])
    ]
    joint_map = dict(zip(bag_names, NAMES, strict=True))
    got = run_diagnosis([bags[0]], [bags[1]], out=tmp_path / "bag", joint_map=joint_map, **kw)
    assert "viscous:2" in ref["versions"][-1], ref["versions"]
    assert got["versions"] == ref["versions"]
    assert got["verdict"] == ref["verdict"]
    np.testing.assert_allclose(got["heldout_rmse"], ref["heldout_rmse"], rtol=1e-6)


def test_current_topic_gives_the_current_columns(arm, tmp_path):
    """With a current topic the currents i = tau / k_t are read (the efforts of the state
    topic are not read as torques)."""
    log = simulate_log(arm, [], duration=1.0, seed=3, torque_constants=K_T)
    ds = _load(write_log(tmp_path / "cur.parquet", log))
    path = write_joint_states(tmp_path / "bag", ds, NAMES, current_topic="/motor_currents")
    back = read_bag(path, NAMES, BagOptions(current_topic="/motor_currents"))
    assert back.tau is None
    np.testing.assert_allclose(back.i, ds.i, atol=1e-9)


def _one_line_error(fn, *match):
    with pytest.raises(ValueError) as err:
        fn()
    text = str(err.value)
    assert "\n" not in text, text
    for m in match:
        assert m in text, text
    return text


def test_missing_topic_lists_the_topics(logs, tmp_path):
    path = write_joint_states(tmp_path / "bag", _load(logs[0][0]), NAMES, topic="/arm/states")
    _one_line_error(
        lambda: read_bag(path, NAMES, BagOptions(topic="/joint_states")),
        "no topic '/joint_states'",
        "/arm/states (sensor_msgs/msg/JointState)",
    )
    _one_line_error(
        lambda: read_bag(path, NAMES, BagOptions(current_topic="/currents")),
        "no topic '/currents'",
    )


def test_unmatched_joint_names_list_both_sets(logs, tmp_path):
    path = write_joint_states(tmp_path / "bag", _load(logs[0][0]), ["a", "b", "c"])
    text = _one_line_error(lambda: read_bag(path, NAMES), "joint names do not match")
    assert "['j1', 'j2', 'j3']" in text and "['a', 'b', 'c']" in text, text
    assert "--joint-map" in text
    ok = read_bag(path, NAMES, BagOptions(joint_map=parse_joint_map(["a=j1", "b=j2", "c=j3"])))
    assert ok.n_joints == 3
    twice = BagOptions(joint_map={"a": "j1", "b": "j1", "c": "j3"})
    _one_line_error(lambda: read_bag(path, NAMES, twice), "both stand for model joint 'j1'")


def test_gaps_and_reordering_are_refused(logs, tmp_path):
    ds = _load(logs[0][0])
    gap = ds.subset(np.r_[0:300, 320:600])
    _one_line_error(
        lambda: read_bag(write_joint_states(tmp_path / "gap", gap, NAMES), NAMES),
        "a gap of",
        "dropped",
    )
    back = dataclasses.replace(ds.subset(np.arange(600)), t=ds.t[:600].copy())
    back.t[100], back.t[101] = back.t[101], back.t[100]
    _one_line_error(
        lambda: read_bag(write_joint_states(tmp_path / "order", back, NAMES), NAMES),
        "out of order",
    )


def test_jittered_stamps_are_resampled_linearly(logs, tmp_path):
    """Stamps with a +-0.1 ms jitter around a 4 ms grid come back on the uniform grid with
    the values of the linear interpolation between the recorded messages."""
    ds = _load(logs[0][0]).subset(np.arange(400))
    jitter = np.random.default_rng(0).uniform(-1e-4, 1e-4, ds.n_samples)
    jitter[0] = 0.0
    stamped = dataclasses.replace(ds, t=ds.t + jitter)
    back = read_bag(write_joint_states(tmp_path / "bag", stamped, NAMES), NAMES)
    stamps = np.round(stamped.t * 1e9) * 1e-9  # the messages carry nanoseconds
    step = np.median(np.diff(stamps))
    np.testing.assert_allclose(np.diff(back.t), step, rtol=1e-9)
    expect = np.interp(back.t + stamps[0], stamps, stamped.q[:, 1])
    np.testing.assert_allclose(back.q[:, 1], expect, atol=1e-12)


def test_command_reads_bags_and_refuses_bad_ones(logs, tmp_path, command):
    """The console script reads a bag (joint map from a YAML file) and refuses a missing
    topic, unmatched joints, a short and a still log with exit 2 and no report."""
    (train, test), xml = logs
    names = ["a", "b", "c"]
    bags = [write_joint_states(tmp_path / f"b{k}", _load(p), names) for k, p in enumerate(logs[0])]
    (tmp_path / "map.yaml").write_text("a: j1\nb: j2\nc: j3\n")
    base = ["--model", str(xml), "--no-plots", "--no-rerun", "--no-sysid"]
    argv = [*base, "--train", str(bags[0]), "--test", str(bags[1])]
    out = tmp_path / "run"
    ok = [*argv, "--joint-map-file", str(tmp_path / "map.yaml"), "--out", str(out)]
    assert command("mcpilco-diagnose", ok) == 0
    assert json.loads((out / "summary.json").read_text())["versions"]
    for bad in (
        [*argv, "--out", str(tmp_path / "r1")],  # joint names do not match
        [*argv, "--joint-map", "a=j1", "b=j2", "c=j3", "--topic", "/x"],
    ):
        assert command("mcpilco-diagnose", [*bad, "--out", str(tmp_path / "r1")]) == 2
        assert not (tmp_path / "r1").exists()
    ds = _load(train)
    short = write_joint_states(tmp_path / "short", ds.subset(np.arange(60)), NAMES)
    still = dataclasses.replace(ds, q=np.repeat(ds.q[:1], ds.n_samples, axis=0))
    still_bag = write_joint_states(tmp_path / "still", still, NAMES)
    for path in (short, still_bag):
        argv = [*base, "--train", str(path), "--out", str(tmp_path / "r2")]
        assert command("mcpilco-diagnose", argv) == 2
        assert not (tmp_path / "r2").exists()
