"""Free-motion recordings of a PSM, whatever wrote them: one reader for ``wrenchd fit``.

Accepted, by what the path is:

* a rosbag2 directory (``metadata.yaml``; MCAP or sqlite3 storage), a bare ``.db3``, or a bare
  ``.mcap`` that another recorder wrote: ``sensor_msgs/msg/JointState`` in CDR on ``topic``,
  as a dVRK ROS 2 system records it (:mod:`wrenchd.adapters.rosbag`);
* an ``.mcap`` that wrenchd wrote: its sessions and daemon logs
  (:mod:`wrenchd.adapters.mcap_session_reader`);
* ``.csv``: the WPI and paper layouts (:mod:`wrenchd.adapters.csv_psm`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from wrenchd.models.errors import AdapterError, ConfigError
from wrenchd.models.series import JointStates

DEFAULT_TOPIC = "/PSM1/measured_js"


@dataclass(frozen=True)
class Recording:
    """A recording's six arm joints and where they came from.

    Attributes:
        joint_states: positions, velocities, efforts; ``t`` [s] from the recording's start.
        path: the file or directory read.
        kind: ``"rosbag"``, ``"session"`` (the project's MCAP) or ``"csv"``.
        detail: what was read, for reports (the topic, the CSV layout...).
    """

    joint_states: JointStates
    path: str
    kind: str
    detail: str


def recording_kind(path: str | os.PathLike[str]) -> str:
    """``"rosbag"``, ``"session"`` or ``"csv"`` for ``path``, from what it is.

    Raises:
        AdapterError: no such file or directory, or an MCAP file that cannot be read.
        ConfigError: a file type that is none of these.
    """
    p = Path(path)
    if p.is_dir():
        if (p / "metadata.yaml").is_file():
            return "rosbag"
        raise ConfigError(f"{p} is a directory without metadata.yaml: not a rosbag2 recording")
    if not p.is_file():
        raise AdapterError(f"{p}: no such recording")
    suffix = p.suffix.lower()
    if suffix == ".db3":
        return "rosbag"
    if suffix == ".mcap":
        from wrenchd.adapters.mcap_session_reader import is_wrenchd_file

        return "session" if is_wrenchd_file(p) else "rosbag"
    if suffix == ".csv":
        return "csv"
    raise ConfigError(f"{p}: unknown recording type {suffix or '(none)'}; expected a rosbag2 "
                      f"directory, .mcap, .db3 or .csv")


def read_recording(path: str | os.PathLike[str], *, topic: str = DEFAULT_TOPIC,
                   csv_format: str = "auto", rate_hz: float | None = None) -> Recording:
    """The arm's joint states in ``path`` (see the module docstring).

    Args:
        topic: the joint-state topic of a ROS 2 bag.
        csv_format: ``auto``, ``wpi`` or ``paper`` (:func:`~wrenchd.adapters.csv_psm.read_psm_csv`).
        rate_hz: the sample rate of a WPI CSV, which has no time column [Hz]; None:
            inferred from its velocity columns.

    Raises:
        AdapterError, DataError, ConfigError: the recording cannot be read, with the reason.
    """
    kind = recording_kind(path)
    if kind == "rosbag":
        from wrenchd.adapters.rosbag import read_joint_states_bag

        bag = read_joint_states_bag(path, topic=topic)
        return Recording(bag.joint_states, os.fspath(path), kind,
                         f"{bag.topic} ({bag.time_source} stamps)")
    if kind == "session":
        from wrenchd.adapters.mcap_session_reader import read_session

        return Recording(read_session(path).joint_states, os.fspath(path), kind,
                         "wrenchd MCAP joint states")
    from wrenchd.adapters.csv_psm import read_psm_csv

    js = read_psm_csv(path, csv_format, rate_hz=rate_hz)
    return Recording(js, os.fspath(path), kind, f"CSV ({csv_format} layout)")
