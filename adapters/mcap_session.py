"""The MCAP session format: topics, their ROS 2 message types and the session metadata record.

Sessions are ROS 2 MCAP files (profile ``ros2``, CDR messages with ``ros2msg`` schemas, see
:mod:`wrenchd.adapters.ros2_msgs`), readable by ``ros2 bag``, Foxglove and ``rosbags``;
:mod:`wrenchd.adapters.mcap_session_writer` writes them and
:mod:`wrenchd.adapters.mcap_session_reader` reads them, and the JSON sessions (JSON messages
with JSON Schemas) that earlier versions wrote.

Layout (every message has ``log_time == publish_time == round(t * 1e9)`` ns, sim time from 0,
equal to its header stamp):

- ``/psm/measured_js`` (``sensor_msgs/msg/JointState``): six joints, names, position, velocity,
  effort.
- ``/psm/truth/wrench`` and, where the scenario has a sensor, ``/psm/truth/sensor_wrench``
  (``geometry_msgs/msg/WrenchStamped``, frame ``psm_base``): true and sensed tip wrench.
- ``/psm/truth/torques`` (``wrenchd_msgs/msg/JointTorqueTruth``): in_contact, true joint
  position / velocity / acceleration, internal and external joint torque, and the torque of
  each modelled effect (``effects``, by name).
- Metadata record ``wrenchd.session``: ``{"format": "wrenchd.session/1", "json": <metadata>}``.

Chunks are zstd-compressed and self-contained, so a file whose writer was killed still yields
every complete chunk (:func:`~wrenchd.adapters.mcap_session_reader.read_session_report`).
Output bytes depend only on the session: no wall-clock time is written and the header's
library string is fixed.
"""

from __future__ import annotations

from wrenchd.adapters import ros2_msgs as ros2

TOPIC_JOINT_STATES = "/psm/measured_js"
TOPIC_WRENCH = "/psm/truth/wrench"
TOPIC_SENSOR_WRENCH = "/psm/truth/sensor_wrench"
TOPIC_TORQUES = "/psm/truth/torques"
SESSION_METADATA_NAME = "wrenchd.session"
SESSION_FORMAT = "wrenchd.session/1"
WRENCH_FRAME = "psm_base"

#: the ROS 2 message type of each topic
TOPIC_TYPES: dict[str, str] = {
    TOPIC_JOINT_STATES: ros2.JOINT_STATE,
    TOPIC_WRENCH: ros2.WRENCH_STAMPED,
    TOPIC_SENSOR_WRENCH: ros2.WRENCH_STAMPED,
    TOPIC_TORQUES: ros2.JOINT_TORQUE_TRUTH,
}
