"""The estimates a daemon log or a replay output holds, whichever version of wrenchd wrote them.

``/wrenchd/estimate`` has been written in three layouts, all read here:

* today's ``wrenchd_msgs/msg/Estimate``: float32 ``force[3]``, ``torque[3]``, ``score`` and
  ``external[6]``, and no predicted joint torques: they are the effort of the
  ``/psm/measured_js`` joint state logged with the same stamp minus ``external``;
* the ROS 2 layout before it: float64 ``wrench`` (``geometry_msgs/Wrench``), ``score``,
  ``predicted[6]`` and ``external[6]``;
* the JSON messages of the earliest logs, with the fields of the float64 layout.

Each message is decoded with the definition its own file stores
(:func:`wrenchd.adapters.ros2_msgs.deserialize`). A file is read in order, to its end or to
where a crashed writer's file stops.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from wrenchd.adapters.mcap_log import TOPIC_ESTIMATE, message_fields
from wrenchd.adapters.mcap_session import TOPIC_JOINT_STATES
from wrenchd.adapters.ros2_msgs import NS_PER_S
from wrenchd.models.errors import AdapterError, DataError


@dataclass(frozen=True)
class LoggedEstimates:
    """The estimates of one file, in file order.

    Attributes:
        stamp_ns: (n,) sample stamps [ns].
        wrench: (n, 6) tip force [N] then torque [N m].
        free: (n,) the gate's verdict (free motion).
        score: (n,) the gate's score (capped at 1e9).
        model_version: (n,) the correction net's version.
        restarted: (n,) the estimator's state restarted at the sample.
        external: (n, 6) measured minus predicted joint torques [N m; N on the insertion joint].
        predicted: (n, 6) predicted joint torques [N m; N]: as stored by the older layouts,
            else the logged effort minus ``external`` (NaN for a sample whose joint state the
            file does not hold, as in a replay's output).
        predicted_stored: the file stored ``predicted`` (an older layout).
    """

    stamp_ns: np.ndarray
    wrench: np.ndarray
    free: np.ndarray
    score: np.ndarray
    model_version: np.ndarray
    restarted: np.ndarray
    external: np.ndarray
    predicted: np.ndarray
    predicted_stored: bool

    def __len__(self) -> int:
        return len(self.stamp_ns)


def _stamp_ns(fields: dict[str, Any]) -> int:
    stamp = fields["header"]["stamp"]
    return int(stamp["sec"]) * NS_PER_S + int(stamp["nanosec"])


def _wrench(fields: dict[str, Any]) -> list[float]:
    if "force" in fields:                                   # today's float32 layout
        return [*fields["force"], *fields["torque"]]
    force, torque = fields["wrench"]["force"], fields["wrench"]["torque"]
    return [force["x"], force["y"], force["z"], torque["x"], torque["y"], torque["z"]]


def read_logged_estimates(path: str | os.PathLike[str]) -> LoggedEstimates:
    """Every ``/wrenchd/estimate`` of the MCAP file at ``path`` (see the module docstring).

    Raises:
        AdapterError: the file cannot be opened or is not MCAP.
        DataError: an estimate or joint state cannot be decoded (names its log time).
    """
    from mcap.exceptions import InvalidMagic, McapError
    from mcap.reader import NonSeekingReader

    rows: list[tuple] = []
    effort: dict[int, list[float]] = {}
    try:
        file = open(path, "rb")
    except OSError as exc:
        raise AdapterError(f"cannot open {path}: {exc}") from exc
    with file:
        messages = NonSeekingReader(file).iter_messages(
            topics=[TOPIC_ESTIMATE, TOPIC_JOINT_STATES], log_time_order=False)
        while True:
            try:
                schema, channel, message = next(messages)
            except StopIteration:
                break
            except InvalidMagic as exc:
                raise AdapterError(f"{path} is not an MCAP file: {exc}") from exc
            except (McapError, EOFError, ValueError):      # where a crashed writer stopped
                break
            fields = message_fields(channel.message_encoding, schema.name if schema else "",
                                    message.data, schema.data if schema else None)
            try:
                if channel.topic == TOPIC_JOINT_STATES:
                    effort[_stamp_ns(fields)] = fields["effort"]
                    continue
                rows.append((_stamp_ns(fields), _wrench(fields), bool(fields["free"]),
                             float(fields["score"]), int(fields["model_version"]),
                             bool(fields["restarted"]), fields["external"],
                             fields.get("predicted")))
            except (KeyError, TypeError, ValueError) as exc:
                raise DataError(f"{path}: {channel.topic} message at log time "
                                f"{message.log_time} ns: missing or malformed field: "
                                f"{exc!r}") from None
    n = len(rows)
    stamps = np.array([r[0] for r in rows], dtype=np.int64)
    external = np.array([r[6] for r in rows], dtype=np.float64).reshape(n, 6)
    stored = n > 0 and all(r[7] is not None for r in rows)
    if stored:
        predicted = np.array([r[7] for r in rows], dtype=np.float64).reshape(n, 6)
    else:
        nan = [np.nan] * 6
        predicted = np.array([effort.get(int(s), nan) for s in stamps],
                             dtype=np.float64).reshape(n, 6) - external
    return LoggedEstimates(
        stamp_ns=stamps, wrench=np.array([r[1] for r in rows], dtype=np.float64).reshape(n, 6),
        free=np.array([r[2] for r in rows], dtype=bool),
        score=np.array([r[3] for r in rows], dtype=np.float64),
        model_version=np.array([r[4] for r in rows], dtype=np.int64),
        restarted=np.array([r[5] for r in rows], dtype=bool), external=external,
        predicted=predicted, predicted_stored=stored)
