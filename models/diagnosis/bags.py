"""Robot logs from ROS 2 bags and MCAP files, as diagnosis datasets.

A ROS 2 arm logs its joints as ``sensor_msgs/msg/JointState`` messages (``name``,
``position``, ``velocity``, ``effort``, one entry per joint, a ``header.stamp``), recorded by
``ros2 bag record`` into a bag: a folder with ``metadata.yaml`` and its storage files
(``.db3``, sqlite3, or ``.mcap``), or a storage file alone; a plain MCAP file with ROS 2
(``ros2msg``/CDR) channels reads the same way. :func:`read_bag` turns one such log into the
:class:`~mcpilco.models.robot_data.Trajectories` of a CSV/Parquet file, so everything after
it (derivative estimates, checks, the diagnosis loop) is the same. The reader is the
maintained ``rosbags`` package (optional extra ``logs``: ``pip install mcpilco[logs]``).

What is read
    * ``topic``: the JointState topic (default: the bag's only one). ``position`` gives
      ``q1..qn``; ``velocity``, when every message has it, ``qd1..qdn`` (otherwise ``qd`` and
      ``qdd`` are estimated from ``q`` as for a position-only file); ``effort`` gives
      ``tau1..taun`` [N m or N].
    * ``current_topic`` (optional): the motor currents [A], ``i1..in``, from a JointState
      topic (its ``effort`` field, matched by joint name, as drives that report currents
      publish them) or a ``std_msgs/msg/Float64MultiArray`` topic (one value per model
      joint, in the model's joint order). With a current topic the loop works on the
      currents (``effort`` of ``topic`` is not read as torque), as for a current-only file.

Joint names
    Column ``j`` is the model's ``j``-th joint (``joints``, the robot file's hinge and slide
    joints in tree order). A bag joint ``b`` stands for the model joint ``joint_map.get(b,
    b)``: names that match are paired without a map; ``joint_map`` (``--joint-map
    bag_name=model_joint``, or a YAML mapping file read by the caller and checked by
    :func:`check_joint_map`) pairs the others.
    Bag joints that stand for no model joint (a gripper) are left out with a warning; a model
    joint without a bag joint is refused with both name lists. Without model names (a
    learned start and no robot file) the joints are taken in the bag's order.

Time
    A message's time is its ``header.stamp``, or the bag's receive time when the stamp is
    zero. Stamps that do not increase (messages out of order, repeated) and intervals
    longer than :data:`GAP_FACTOR` times the median one (dropped messages) are refused: a
    diagnosis needs one uninterrupted record. The rest is resampled onto the uniform grid
    ``t_k = k T`` (``T`` the median interval, ``t`` from the first message) by linear
    interpolation between the two messages around ``t_k``, every channel alike (the
    current topic too, on the span both topics cover). Linear interpolation errs by at most
    ``T^2 |qdd| / 8`` within an interval, below an encoder step for the rates arms log at
    (1 kHz, ``qdd`` of 10 rad/s^2: 1.3e-6 rad); a log already on a uniform grid passes
    unchanged.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from mcpilco.models.robot_data import Trajectories, from_frame

FloatArray = NDArray[np.float64]

__all__ = [
    "BAG_SUFFIXES",
    "GAP_FACTOR",
    "JOINT_STATE",
    "BagOptions",
    "is_bag",
    "parse_joint_map",
    "read_bag",
    "check_joint_map",
    "write_joint_states",
]

JOINT_STATE = "sensor_msgs/msg/JointState"
"""The ROS 2 message type of joint positions, velocities and efforts."""
FLOAT_ARRAY = "std_msgs/msg/Float64MultiArray"
"""The plain array type a current topic may have instead (values in the model's order)."""
BAG_SUFFIXES = (".mcap", ".db3")
"""Storage files read as bags (a folder with ``metadata.yaml`` is a bag too)."""
GAP_FACTOR = 3.0
"""An interval between messages longer than this times the median one is a gap (refused)."""


@dataclass(frozen=True)
class BagOptions:
    """What to read from a bag (module docstring).

    Attributes:
        topic: the JointState topic (``None``: the bag's only one).
        current_topic: a topic of motor currents, or ``None``.
        joint_map: bag joint name -> model joint name, for names that differ.
    """

    topic: str | None = None
    current_topic: str | None = None
    joint_map: Mapping[str, str] = field(default_factory=dict)


def is_bag(path: str | Path) -> bool:
    """Whether ``path`` is a ROS 2 bag folder (``metadata.yaml``) or an ``.mcap``/``.db3``
    file."""
    p = Path(path)
    if p.is_dir():
        return (p / "metadata.yaml").is_file()
    return p.suffix.lower() in BAG_SUFFIXES


def parse_joint_map(pairs: Sequence[str]) -> dict[str, str]:
    """``{"bag": "model"}`` from ``["bag=model", ...]`` (the ``--joint-map`` flags).

    Raises:
        ValueError: an item without ``=`` or with an empty side, or a bag name given twice.
    """
    out: dict[str, str] = {}
    for item in pairs:
        bag, sep, joint = str(item).partition("=")
        if not sep or not bag.strip() or not joint.strip():
            raise ValueError(
                f"--joint-map {item!r}: give bag_name=model_joint (e.g. shoulder_pan=j1)"
            )
        if bag.strip() in out:
            raise ValueError(f"--joint-map: bag joint {bag.strip()!r} is mapped twice")
        out[bag.strip()] = joint.strip()
    return out


def check_joint_map(data: Any, source: str) -> dict[str, str]:
    """``data`` (e.g. a YAML file's mapping, read by the caller) as the mapping
    ``bag_name: model_joint``.

    Raises:
        ValueError: not a flat mapping of names to names; the message names ``source``.
    """
    if not isinstance(data, dict) or not all(
        isinstance(k, str) and isinstance(v, str) for k, v in data.items()
    ):
        raise ValueError(f"joint map {source}: must map bag joint names to model joint names")
    return dict(data)


def _open(path: Path) -> Any:
    """An opened ``rosbags`` reader of a bag folder, ``.db3`` or ``.mcap`` file."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError as err:
        raise ValueError(
            f"{path}: reading ROS 2 bags needs the 'rosbags' package: pip install 'mcpilco[logs]'"
        ) from err
    reader = AnyReader([path], default_typestore=get_typestore(Stores.LATEST))
    try:
        reader.open()
    except Exception as err:  # the reader's own errors are of several types
        what = " ".join(str(err).split())[:200] or type(err).__name__
        raise ValueError(
            f"{path}: cannot be read as a ROS 2 bag ({what}); give a bag folder, .db3 or .mcap"
        ) from err
    return reader


def _stamp(msg: Any, received: int) -> int:
    """``header.stamp`` [ns], or the receive time when the message has no stamp."""
    header = getattr(msg, "header", None)
    if header is None:
        return received
    ns = int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
    return ns if ns else received


def _topic_list(topics: Mapping[str, str]) -> str:
    return ", ".join(f"{t} ({m})" for t, m in sorted(topics.items())) or "none"


def _pick_topic(
    path: Path, topics: Mapping[str, str], topic: str | None, what: str, other: str | None = None
) -> str:
    """The JointState topic to read (``topic``, or the bag's only one but ``other``)."""
    if topic is not None:
        if topic not in topics:
            raise ValueError(
                f"{path}: no topic {topic!r} ({what}); the bag has: {_topic_list(topics)}; "
                "name one of them with --topic, or record the joint states"
            )
        return topic
    states = sorted(t for t, m in topics.items() if m == JOINT_STATE and t != other)
    if len(states) != 1:
        found = "no" if not states else f"{len(states)}"
        raise ValueError(
            f"{path}: {found} {JOINT_STATE} topics; the bag has: {_topic_list(topics)}; "
            "name the joint-state topic with --topic (record one, e.g. /joint_states)"
        )
    return states[0]


def _check_times(path: Path, topic: str, ns: NDArray[np.int64]) -> FloatArray:
    """Seconds from the first message; ValueError when the stamps do not increase or a gap
    exceeds :data:`GAP_FACTOR` median intervals."""
    if ns.size < 3:
        raise ValueError(
            f"{path}: topic {topic} holds {ns.size} messages; record the arm moving for a "
            "few seconds or more"
        )
    step = np.diff(ns)
    if (step <= 0).any():
        k = int(np.argmax(step <= 0)) + 1
        raise ValueError(
            f"{path}: topic {topic}: message {k} is stamped {(ns[k] - ns[0]) * 1e-9:.6f} s, "
            f"not after message {k - 1} ({(ns[k - 1] - ns[0]) * 1e-9:.6f} s): messages out of "
            "order or repeated; record with header stamps from one clock"
        )
    med = float(np.median(step))
    if (step > GAP_FACTOR * med).any():
        k = int(np.argmax(step))
        raise ValueError(
            f"{path}: topic {topic}: a gap of {step[k] * 1e-9:.4g} s after "
            f"{(ns[k] - ns[0]) * 1e-9:.4f} s (median interval {med * 1e-9:.4g} s): messages "
            "were dropped; give the parts before and after it as separate files, or record "
            "without drops"
        )
    return (ns - ns[0]) * 1e-9


def _columns(
    path: Path, names: Sequence[str], joints: Sequence[str] | None, joint_map: Mapping[str, str]
) -> tuple[list[int], list[str]]:
    """Indices into the bag's ``names`` of the model joints, in model order, and the bag
    joints left out."""
    if joints is None:
        return list(range(len(names))), []
    model_of = {b: joint_map.get(b, b) for b in names}
    index: dict[str, int] = {}
    for k, (b, m) in enumerate(model_of.items()):
        if m in index:
            raise ValueError(
                f"{path}: bag joints {names[index[m]]!r} and {b!r} both stand for model joint "
                f"{m!r}; map one of them elsewhere with --joint-map"
            )
        if m in joints:
            index[m] = k
    missing = [j for j in joints if j not in index]
    if missing:
        unknown = [m for m in joint_map if m not in names]
        hint = f"; map entries for no bag joint: {unknown}" if unknown else ""
        raise ValueError(
            f"{path}: joint names do not match: model joints {list(missing)} are not in the "
            f"bag; model joints: {list(joints)}; bag joints: {list(names)}{hint}; pair them "
            "with --joint-map bag_name=model_joint"
        )
    left = [b for b in names if model_of[b] not in joints]
    return [index[j] for j in joints], left


def _read_states(
    reader: Any,
    path: Path,
    topic: str,
    field_names: Sequence[str],
    joints: Sequence[str] | None,
    joint_map: Mapping[str, str],
) -> tuple[NDArray[np.int64], dict[str, FloatArray], list[str], list[str]]:
    """Stamps and the ``field_names`` arrays ``(N, n)`` of a JointState topic in model joint
    order (an empty field gives no array), the model's joint names, the bag joints left out."""
    conns = [c for c in reader.connections if c.topic == topic]
    stamps: list[int] = []
    rows: dict[str, list[FloatArray]] = {f: [] for f in field_names}
    order: list[int] | None = None
    names0: list[str] = []
    left: list[str] = []
    for conn, received, raw in reader.messages(connections=conns):
        msg = reader.deserialize(raw, conn.msgtype)
        names = list(msg.name)
        if order is None or names != names0:
            if order is not None and sorted(names) != sorted(names0):
                raise ValueError(
                    f"{path}: topic {topic}: message {len(stamps)} names joints {names}, the "
                    f"first names {names0}; record the same joints in every message"
                )
            names0 = names
            order, left = _columns(path, names, joints, joint_map)
        stamps.append(_stamp(msg, received))
        for f in field_names:
            values = np.asarray(getattr(msg, f), dtype=np.float64)
            if values.size == 0:
                rows[f].append(values)
                continue
            if values.size != len(names):
                raise ValueError(
                    f"{path}: topic {topic}: message {len(stamps) - 1} has {values.size} "
                    f"{f} values for {len(names)} joint names; record one per joint"
                )
            rows[f].append(values[order])
    if order is None:
        raise ValueError(f"{path}: topic {topic} holds no messages; record the joint states")
    n = len(order)
    arrays = {f: np.stack(v) for f, v in rows.items() if v and all(x.size == n for x in v)}
    model_names = list(joints) if joints is not None else [names0[k] for k in order]
    return np.asarray(stamps, dtype=np.int64), arrays, model_names, left


def _read_currents(
    reader: Any, path: Path, topic: str, joints: Sequence[str], joint_map: Mapping[str, str]
) -> tuple[NDArray[np.int64], FloatArray]:
    """Stamps and currents ``(N, n)`` of a current topic (module docstring)."""
    msgtype = {c.topic: c.msgtype for c in reader.connections}[topic]
    if msgtype == JOINT_STATE:
        ns, arrays, _, _ = _read_states(reader, path, topic, ("effort",), joints, joint_map)
        if "effort" not in arrays:
            raise ValueError(
                f"{path}: current topic {topic} has no effort values; record the currents there"
            )
        return ns, arrays["effort"]
    if msgtype != FLOAT_ARRAY:
        raise ValueError(
            f"{path}: current topic {topic} is {msgtype}; give a {JOINT_STATE} (effort = "
            f"current [A]) or {FLOAT_ARRAY} topic"
        )
    conns = [c for c in reader.connections if c.topic == topic]
    stamps, rows = [], []
    for conn, received, raw in reader.messages(connections=conns):
        values = np.asarray(reader.deserialize(raw, conn.msgtype).data, dtype=np.float64)
        if values.size != len(joints):
            raise ValueError(
                f"{path}: current topic {topic}: message {len(rows)} has {values.size} values "
                f"for {len(joints)} joints; record one current per joint, in the model's order"
            )
        stamps.append(received)
        rows.append(values)
    return np.asarray(stamps, dtype=np.int64), np.stack(rows) if rows else np.zeros((0, 0))


def _resample(t: FloatArray, values: FloatArray, grid: FloatArray) -> FloatArray:
    """Linear interpolation of every column of ``values (N, n)`` from ``t`` onto ``grid``."""
    return np.stack([np.interp(grid, t, values[:, j]) for j in range(values.shape[1])], axis=1)


def read_bag(
    path: str | Path,
    joints: Sequence[str] | None = None,
    options: BagOptions | None = None,
    n_joints: int | None = None,
) -> Trajectories:
    """The dataset of one bag (module docstring): ``t`` on a uniform grid from 0, ``q``,
    ``qd`` when recorded, and ``tau`` (``effort``) or ``i`` (the current topic).

    Args:
        path: a bag folder, ``.db3`` or ``.mcap`` file.
        joints: the model's joint names in model order (``None``: the bag's order).
        options: topics and joint map (:class:`BagOptions`).
        n_joints: the model's joint count (checked when ``joints`` is ``None``).

    Raises:
        ValueError: an unreadable bag, a missing topic (the bag's topics are listed), joint
            names that do not match (both lists), messages out of order or with a gap, no
            effort and no current topic, a joint count that differs from ``n_joints``.
    """
    options = options or BagOptions()
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no bag at {path}")
    reader = _open(path)
    try:
        topics = {c.topic: c.msgtype for c in reader.connections}
        topic = _pick_topic(path, topics, options.topic, "joint states", options.current_topic)
        if topics[topic] != JOINT_STATE:
            raise ValueError(
                f"{path}: topic {topic} is {topics[topic]}, not {JOINT_STATE}; the bag has: "
                f"{_topic_list(topics)}; name the joint-state topic with --topic"
            )
        fields = ("position", "velocity", "effort")
        ns, arrays, names, left = _read_states(
            reader, path, topic, fields, joints, options.joint_map
        )
        if "position" not in arrays:
            raise ValueError(f"{path}: topic {topic} has no joint positions; record position")
        if n_joints is not None and len(names) != n_joints:
            raise ValueError(
                f"{path}: joint count mismatch: topic {topic} has {len(names)} joints "
                f"({names}) but the model has {n_joints}; pair them with --joint-map"
            )
        t = _check_times(path, topic, ns)
        current = None
        if options.current_topic is not None:
            ctopic = _pick_topic(path, topics, options.current_topic, "motor currents")
            cns, current = _read_currents(reader, path, ctopic, names, options.joint_map)
            current_t = _check_times(path, ctopic, cns) + (cns[0] - ns[0]) * 1e-9
    finally:
        reader.close()
    if current is None and "effort" not in arrays:
        raise ValueError(
            f"{path}: topic {topic} has no effort values and no --current-topic was given; "
            "record the joint torques (effort) or name the motor-current topic"
        )
    step = float(np.median(np.diff(t)))
    start, stop = t[0], t[-1]
    if current is not None:
        start, stop = max(start, current_t[0]), min(stop, current_t[-1])
    grid = start + step * np.arange(int(math.floor((stop - start) / step + 1e-9)) + 1)
    cols: dict[str, Any] = {"t": grid - grid[0]}
    groups = [("q", "position"), ("qd", "velocity")]
    if current is None:
        groups.append(("tau", "effort"))
    for g, f in groups:
        if f in arrays:
            values = _resample(t, arrays[f], grid)
            cols.update({f"{g}{j + 1}": values[:, j] for j in range(len(names))})
    if current is not None:
        values = _resample(current_t, current, grid)
        cols.update({f"i{j + 1}": values[:, j] for j in range(len(names))})
    ds = from_frame(pd.DataFrame(cols), n_joints=n_joints, source=str(path))
    notes = list(ds.metadata.get("warnings", []))
    if left:
        notes.append(f"{path}: bag joints {left} stand for no model joint; left out")
    ds.metadata.update(
        joint_names=names,
        topic=topic,
        current_topic=options.current_topic,
        start_stamp_ns=int(ns[0]),
        warnings=notes,
    )
    return ds


def write_joint_states(
    path: str | Path,
    dataset: Trajectories,
    joint_names: Sequence[str],
    topic: str = "/joint_states",
    storage: str = "sqlite3",
    start_ns: int = 1_700_000_000_000_000_000,
    current_topic: str | None = None,
) -> Path:
    """Write ``dataset`` as a ROS 2 bag folder of JointState messages, one per row, stamped
    ``start_ns + t`` and received in row order (as a recorder receives them): ``position`` =
    ``q``, ``velocity`` = ``qd`` when the file gave it, ``effort`` = ``tau``; with
    ``current_topic`` the currents ``i`` as a second JointState topic (``effort`` =
    current). ``storage``: ``"sqlite3"`` or ``"mcap"``. Turns a simulated or CSV log into
    what a ROS 2 arm records."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    plugins = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}
    if storage not in plugins:
        raise ValueError(f"storage must be one of {sorted(plugins)}, got {storage!r}")
    if len(joint_names) != dataset.n_joints:
        raise ValueError(f"joint_names has {len(joint_names)} names for {dataset.n_joints} joints")
    store = get_typestore(Stores.LATEST)
    msg_t = store.types[JOINT_STATE]
    header_t = store.types["std_msgs/msg/Header"]
    time_t = store.types["builtin_interfaces/msg/Time"]
    velocity = "qd" not in dataset.metadata.get("computed", [])
    empty = np.zeros(0)

    def message(k: int, stamp: int, effort: FloatArray | None, with_state: bool) -> Any:
        header = header_t(stamp=time_t(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id="")
        return msg_t(
            header=header,
            name=list(joint_names),
            position=dataset.q[k].copy() if with_state else empty,
            velocity=dataset.qd[k].copy() if with_state and velocity else empty,
            effort=empty if effort is None else effort[k].copy(),
        )

    path = Path(path)
    with Writer(path, version=9, storage_plugin=plugins[storage]) as writer:
        conn = writer.add_connection(topic, JOINT_STATE, typestore=store)
        cconn = None
        if current_topic is not None:
            cconn = writer.add_connection(current_topic, JOINT_STATE, typestore=store)
        received = start_ns
        for k, tk in enumerate(dataset.t):
            stamp = start_ns + int(round(tk * 1e9))
            received = max(stamp, received + 1)
            msg = message(k, stamp, None if cconn is not None else dataset.tau, True)
            writer.write(conn, received, store.serialize_cdr(msg, JOINT_STATE))
            if cconn is not None:
                cur = message(k, stamp, dataset.i, False)
                writer.write(cconn, received, store.serialize_cdr(cur, JOINT_STATE))
    return path
