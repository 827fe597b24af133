"""ROS 2 bags (rosbag2) of PSM joint states: read a lab's recording, write set-points.

A dVRK ROS 2 system publishes the arm's CRTK state as ``sensor_msgs/msg/JointState`` in CDR:
``/PSM1/measured_js`` (six joints ``outer_yaw .. outer_wrist_yaw``, older releases a seventh,
``jaw``) and the jaw apart on ``/PSM1/jaw/measured_js`` (one joint, ``jaw``); ``ros2 bag
record`` stores them as a rosbag2 directory (``metadata.yaml`` plus MCAP or sqlite3 storage).
Both, and a bare ``.mcap`` file with the ``ros2`` profile, are read through the maintained
``rosbags`` library (its :class:`rosbags.rosbag2.Reader`); the payloads are decoded by
:func:`wrenchd.adapters.messages.decode_joint_state`.

Time: each message's header stamp, or the bag's log (receive) time where every header stamp
is zero (a publisher that leaves the header empty). Times are returned relative to the first
stamp, ``t = (stamp - start_ns) / 1e9`` [s], so a float64 keeps nanosecond steps whatever the
clock's epoch; ``start_ns`` keeps the absolute origin.

Units: rad, rad, m, rad, rad, rad; velocities per second; efforts N m (N on the insertion).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wrenchd.adapters.messages import (
    JOINT_STATE_TYPE, decode_joint_state, encode_joint_state, stamp_ns_of,
)
from wrenchd.adapters.ros2_msgs import NS_PER_S, typestore
from wrenchd.models.errors import AdapterError, DataError
from wrenchd.models.series import JOINT_NAMES, N_JOINTS, JointStates

DEFAULT_TOPIC = "/PSM1/measured_js"
DEFAULT_JAW_TOPIC = "/PSM1/jaw/measured_js"
#: The CRTK joint-position command of a dVRK arm (set-points streamed at the servo rate).
SETPOINT_TOPIC = "/PSM1/servo_jp"
JAW_NAME = "jaw"
STORAGES = ("mcap", "sqlite3")


@dataclass(frozen=True)
class BagJointStates:
    """Joint states read from a bag.

    Attributes:
        joint_states: the six arm joints, ``t`` relative to ``start_ns`` [s].
        jaw: (M, 3) jaw position [rad], velocity [rad/s], effort [N m], or None.
        jaw_t: (M,) jaw sample times on the same origin [s], or None.
        start_ns: the first arm stamp [ns] (header stamp or log time, see ``time_source``).
        time_source: ``"header"`` or ``"log"``.
        topic: the topic the arm's states came from.
    """

    joint_states: JointStates
    jaw: np.ndarray | None
    jaw_t: np.ndarray | None
    start_ns: int
    time_source: str
    topic: str


@dataclass
class _Series:
    """Decoded messages of one topic, in bag order."""

    topic: str
    stamps: np.ndarray          # (N,) int64 [ns], header or log time
    time_source: str
    position: np.ndarray        # (N, n)
    velocity: np.ndarray
    effort: np.ndarray
    names: tuple[str, ...]


def _open(path: Path):
    from rosbags.rosbag2 import Reader

    try:
        reader = Reader(path)
        reader.open()
    except FileNotFoundError as exc:
        raise AdapterError(f"cannot read ROS 2 bag {path}: {exc}") from None
    except Exception as exc:     # rosbags' ReaderError and storage errors (yaml, sqlite, mcap)
        raise AdapterError(f"cannot read ROS 2 bag {path}: {type(exc).__name__}: {exc}") from None
    return reader


def _check_path(path: Path) -> None:
    if not path.exists():
        raise AdapterError(f"no ROS 2 bag at {path}")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        raise AdapterError(f"{path} is a directory without metadata.yaml: not a rosbag2 "
                           f"directory (give the bag's directory or a bare .mcap file)")
    if path.is_file() and path.suffix not in (".mcap", ".db3"):
        raise AdapterError(f"{path}: expected a rosbag2 directory, a .mcap or a .db3 file")


def _topic_series(reader, path: Path, topic: str, joints: tuple[int, ...]) -> _Series:
    """Decode every message of ``topic``; ``joints`` lists the joint counts accepted."""
    topics = reader.topics
    if topic not in topics:
        found = ", ".join(f"{name} ({info.msgtype})" for name, info in sorted(topics.items()))
        raise DataError(f"{path}: no topic {topic!r}; the bag has: {found or 'no topics'}")
    msgtype = topics[topic].msgtype
    if msgtype != JOINT_STATE_TYPE:
        raise DataError(f"{path}: topic {topic!r} carries {msgtype}, expected {JOINT_STATE_TYPE}")
    header_ns, log_ns, rows, names = [], [], [], None
    for index, (_, log_time, raw) in enumerate(reader.messages(topics[topic].connections)):
        try:
            msg = decode_joint_state("cdr", raw)
        except DataError as exc:
            raise DataError(f"{path}: {topic} message {index}: {exc}") from None
        n = len(msg.position)
        if n not in joints:
            want = " or ".join(str(j) for j in joints)
            raise DataError(f"{path}: {topic} message {index} has {n} joints, expected {want}")
        if names is None:
            names = msg.name
        elif msg.name != names:
            raise DataError(f"{path}: {topic} message {index} names the joints {list(msg.name)}, "
                            f"earlier messages {list(names)}")
        block = np.stack([msg.position, msg.velocity, msg.effort])
        if not np.isfinite(block).all():
            field, joint = np.argwhere(~np.isfinite(block))[0]
            what = ("position", "velocity", "effort")[field]
            raise DataError(f"{path}: {topic} message {index}: {what} of joint {joint + 1} is "
                            f"{block[field, joint]} (not finite)")
        header_ns.append(msg.stamp_ns)
        log_ns.append(log_time)
        rows.append(block)
    if not rows:
        raise DataError(f"{path}: topic {topic!r} has no messages")
    header = np.array(header_ns, dtype=np.int64)
    if not header.any():             # no publisher stamp at all: the recorder's clock
        stamps, source = np.array(log_ns, dtype=np.int64), "log"
    else:                            # a zero among stamps fails the increase check below
        stamps, source = header, "header"
    step = np.diff(stamps)
    if (step <= 0).any():
        i = int(np.argmax(step <= 0)) + 1
        raise DataError(f"{path}: {topic} {source} stamps must increase: message {i} at "
                        f"{int(stamps[i])} ns is not after message {i - 1} at "
                        f"{int(stamps[i - 1])} ns")
    data = np.stack(rows)                                       # (N, 3, n)
    return _Series(topic, stamps, source, data[:, 0], data[:, 1], data[:, 2], names or ())


def _check_arm_names(path: Path, series: _Series) -> None:
    names = series.names
    expected = JOINT_NAMES + ((JAW_NAME,) if series.position.shape[1] == N_JOINTS + 1 else ())
    if tuple(names) != expected:
        shown = list(names) if names else "no names"
        raise DataError(f"{path}: {series.topic} joints are {shown}; a dVRK PSM publishes "
                        f"{list(expected)}")


def read_joint_states_bag(path: str | os.PathLike[str], topic: str = DEFAULT_TOPIC,
                          jaw_topic: str | None = DEFAULT_JAW_TOPIC) -> BagJointStates:
    """Reads a PSM's joint states from a ROS 2 bag (directory, bare ``.mcap`` or ``.db3``).

    Args:
        path: the bag directory (with ``metadata.yaml``) or a storage file.
        topic: the arm's ``sensor_msgs/msg/JointState`` topic, 6 joints (or 7, the last the jaw).
        jaw_topic: the jaw's topic (one joint ``jaw``), read where the bag has it; None skips it.

    Returns:
        :class:`BagJointStates`; the jaw comes from ``jaw_topic`` if the bag has it, else from a
        seventh joint of ``topic``, else it is None.

    Raises:
        AdapterError: the path is not a readable rosbag2.
        DataError: the topic is missing (the message lists those the bag has), carries another
            type, has messages with the wrong joint count or names, non-finite values, or
            stamps that do not increase.
    """
    path = Path(path)
    _check_path(path)
    reader = _open(path)
    try:
        arm = _topic_series(reader, path, topic, (N_JOINTS, N_JOINTS + 1))
        jaw_series = None
        if jaw_topic is not None and jaw_topic in reader.topics:
            jaw_series = _topic_series(reader, path, jaw_topic, (1,))
    except (AdapterError, DataError):
        raise
    except Exception as exc:     # a corrupt chunk found while iterating
        raise AdapterError(f"cannot read ROS 2 bag {path}: {type(exc).__name__}: {exc}") from None
    finally:
        reader.close()
    _check_arm_names(path, arm)
    start = int(arm.stamps[0])
    t = (arm.stamps - start) / NS_PER_S
    js = JointStates(t, arm.position[:, :N_JOINTS], arm.velocity[:, :N_JOINTS],
                     arm.effort[:, :N_JOINTS])
    jaw = jaw_t = None
    if jaw_series is not None:
        if jaw_series.names not in ((JAW_NAME,), ()):
            raise DataError(f"{path}: {jaw_topic} names its joint {list(jaw_series.names)}, "
                            f"expected ['{JAW_NAME}']")
        if jaw_series.time_source != arm.time_source:
            raise DataError(f"{path}: {jaw_topic} is timed by {jaw_series.time_source} stamps, "
                            f"{topic} by {arm.time_source} stamps")
        jaw_t = (jaw_series.stamps - start) / NS_PER_S
        jaw = np.column_stack([jaw_series.position[:, 0], jaw_series.velocity[:, 0],
                               jaw_series.effort[:, 0]])
    elif arm.position.shape[1] == N_JOINTS + 1:
        jaw_t = t.copy()
        jaw = np.column_stack([arm.position[:, -1], arm.velocity[:, -1], arm.effort[:, -1]])
    return BagJointStates(js, jaw, jaw_t, start, arm.time_source, topic)


def bag_topics(path: str | os.PathLike[str]) -> dict[str, tuple[str, int]]:
    """``{topic: (message type, message count)}`` of a bag."""
    path = Path(path)
    _check_path(path)
    reader = _open(path)
    try:
        return {name: (info.msgtype, int(info.msgcount)) for name, info in reader.topics.items()}
    finally:
        reader.close()


def write_joint_states_bag(path: str | os.PathLike[str], js: JointStates,
                           topic: str = DEFAULT_TOPIC, storage: str = "mcap", *,
                           start_ns: int = 0, jaw: np.ndarray | None = None,
                           jaw_topic: str = DEFAULT_JAW_TOPIC, with_effort: bool = True,
                           frame_id: str = "") -> Path:
    """Writes ``js`` as ``sensor_msgs/msg/JointState`` messages (CDR) into a new ROS 2 bag.

    Each message is stamped ``start_ns + round(t * 1e9)`` in its header and as its log time,
    with the PSM's joint names.

    Args:
        path: a new directory (rosbag2, version 9), or a path ending in ``.mcap`` for a bare
            MCAP file (``storage`` must then be ``"mcap"``).
        topic: where the arm's states go (``/PSM1/servo_jp`` for set-points).
        storage: ``"mcap"`` or ``"sqlite3"``.
        start_ns: stamp of ``t = 0`` [ns].
        jaw: optional (N, 3) jaw position, velocity, effort on ``jaw_topic``, same stamps.
        with_effort: False leaves ``effort`` empty (a position/velocity set-point).

    Returns:
        The path written.

    Raises:
        AdapterError: the path exists or the bag cannot be written.
        DataError: bad ``storage``, ``jaw`` shape, or stamps out of range.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer

    if storage not in STORAGES:
        raise DataError(f"storage must be one of {list(STORAGES)}, got {storage!r}")
    path = Path(path)
    bare = path.suffix == ".mcap"
    if bare and storage != "mcap":
        raise DataError(f"{path}: a bare .mcap file needs storage 'mcap', got {storage!r}")
    if path.exists():
        raise AdapterError(f"{path} exists; a bag is written to a new path")
    stamps = np.array([start_ns + stamp_ns_of(float(t)) for t in js.t], dtype=np.int64)
    if len(js) and (stamps[0] < 0 or stamps[-1] >= 2**31 * NS_PER_S):
        raise DataError("stamps must lie in [0, 2^31) s (ROS builtin_interfaces/Time)")
    if jaw is not None:
        jaw = np.asarray(jaw, dtype=np.float64)
        if jaw.shape != (len(js), 3):
            raise DataError(f"jaw must have shape ({len(js)}, 3), got {jaw.shape}")
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    target = Path(tempfile.mkdtemp(prefix=".bag-", dir=path.parent)) / "bag" if bare else path
    store = typestore()
    empty = np.zeros(0)
    try:
        with Writer(target, version=9, storage_plugin=plugin) as writer:
            arm = writer.add_connection(topic, JOINT_STATE_TYPE, typestore=store)
            jaw_conn = (writer.add_connection(jaw_topic, JOINT_STATE_TYPE, typestore=store)
                        if jaw is not None else None)
            for i, stamp in enumerate(stamps.tolist()):
                effort = js.effort[i] if with_effort else empty
                writer.write(arm, stamp, encode_joint_state(
                    "cdr", stamp, JOINT_NAMES, js.position[i], js.velocity[i], effort, frame_id))
                if jaw_conn is not None:
                    writer.write(jaw_conn, stamp, encode_joint_state(
                        "cdr", stamp, (JAW_NAME,), jaw[i, :1], jaw[i, 1:2],
                        jaw[i, 2:3] if with_effort else empty, frame_id))
        if bare:
            (mcap_file,) = target.glob("*.mcap")
            shutil.move(mcap_file, path)
    except (AdapterError, DataError):
        raise
    except Exception as exc:     # rosbags' WriterError, OSError, sqlite errors
        raise AdapterError(f"cannot write ROS 2 bag {path}: {type(exc).__name__}: {exc}") from None
    finally:
        if bare:
            shutil.rmtree(target.parent, ignore_errors=True)
    return path
