"""``--measured``, ``--format``, ``--rate`` and ``--topic``: the recording ``identify`` and
``discrepancy`` read, through the one recording reader of ``wrenchd fit``
(:func:`wrenchd.adapters.recordings.read_recording`)."""

from __future__ import annotations

from wrenchd.adapters.recordings import DEFAULT_TOPIC
from wrenchd.models.errors import ConfigError

FORMATS = ("auto", "wpi", "paper", "mcap")


def add_measured_options(parser) -> None:
    """Add ``--measured`` (required), ``--format``, ``--rate`` and ``--topic`` to ``parser``."""
    parser.add_argument("--measured", required=True,
                        help="CSV (WPI or paper layout), MCAP (wrenchd's or a ROS 2 bag's) or a "
                             "rosbag2 directory")
    parser.add_argument("--format", default="auto", choices=FORMATS,
                        help="auto: from what the path is; wpi, paper: a CSV of that layout "
                             "whatever its suffix; mcap: an MCAP file or a rosbag2 directory")
    parser.add_argument("--rate", type=float, default=None,
                        help="sample rate of a WPI CSV [Hz] (default: inferred from its "
                             "velocity columns)")
    parser.add_argument("--topic", default=DEFAULT_TOPIC,
                        help=f"joint-state topic of a ROS 2 bag (default {DEFAULT_TOPIC})")


def read_measured(path: str, fmt: str = "auto", rate_hz: float | None = None,
                  topic: str = DEFAULT_TOPIC):
    """Joint states (``JointStates``) of a recording (see :func:`add_measured_options`).

    Raises:
        ConfigError: an unknown format, or ``mcap`` for a CSV file.
        AdapterError, DataError: the recording cannot be read, with the reason.
    """
    if fmt not in FORMATS:
        raise ConfigError(f"--format must be one of {FORMATS}, got {fmt!r}")
    if fmt in ("wpi", "paper"):
        from wrenchd.adapters.csv_psm import read_psm_csv

        return read_psm_csv(path, fmt, rate_hz=rate_hz)
    from wrenchd.adapters.recordings import read_recording

    recording = read_recording(path, topic=topic, rate_hz=rate_hz)
    if fmt == "mcap" and recording.kind == "csv":
        raise ConfigError(f"--format mcap, but {path} is a CSV file")
    return recording.joint_states
