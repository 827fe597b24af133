"""MCAP files of replays: the output a replay writes, and the events a daemon log holds.

The output (:func:`write_replay_file`) has the daemon log's topics and ROS 2 messages
(:mod:`wrenchd.adapters.mcap_log`: a ROS 2 bag, ``ros2`` profile, CDR): ``/wrenchd/estimate``
per estimated sample and ``/wrenchd/events``, each event written before the first estimate
stamped at or after it, and the metadata record ``wrenchd.replay``. No wall-clock time is
written and the header's library string is fixed, so equal replays give equal bytes.

A replay of a daemon's log announces the set-up changes the daemon was told of; they are read
back from the log's events (:func:`logged_events`).
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Mapping
from typing import Any

from mcap.well_known import Profile
from mcap.writer import CompressionType, Writer

from wrenchd.adapters.mcap_log import (TOPIC_ESTIMATE, TOPIC_EVENTS, TOPIC_TYPES, estimate_record,
                                       event_record, message_fields)
from wrenchd.adapters.ros2_msgs import Ros2Channels
from wrenchd.models.errors import AdapterError, DataError

#: the header's library string of replay outputs (unchanged since they were first written)
LIBRARY = "wrenchd.service.replay.loop/2"
METADATA_NAME = "wrenchd.replay"
_FRAME = "psm_base"


def write_replay_file(path: str | os.PathLike[str], estimates: Any,
                      events: Iterable[tuple[int, str]], metadata: Mapping[str, Any]) -> None:
    """Write a replay's output to ``path`` (overwritten).

    Args:
        estimates: the estimates, in stamp order: per sample, the arrays ``stamp_ns``,
            ``wrench``, ``free``, ``score``, ``model_version``, ``restarted`` and ``external``
            as a replay's result and :class:`~wrenchd.adapters.log_estimates.LoggedEstimates`
            hold them.
        events: ``(stamp [ns], the event's JSON object as text)``; equal stamps keep their
            order.
        metadata: the ``wrenchd.replay`` record (JSON; values JSON cannot hold as text).

    Raises:
        AdapterError: the file cannot be written.
    """
    events = sorted(events, key=lambda item: item[0])
    try:
        with open(path, "wb") as f:
            writer = Writer(f, compression=CompressionType.ZSTD)
            writer.start(profile=Profile.ROS2, library=LIBRARY)
            writer.add_metadata(METADATA_NAME, {"json": json.dumps(
                dict(metadata), sort_keys=True, default=str)})
            channels = Ros2Channels(writer)
            estimate_id, events_id = (channels.add(topic, TOPIC_TYPES[topic])
                                      for topic in (TOPIC_ESTIMATE, TOPIC_EVENTS))
            e = estimates
            at = 0
            for k, stamp in enumerate(e.stamp_ns.tolist()):
                while at < len(events) and events[at][0] <= stamp:
                    _write_event(writer, events_id, *events[at])
                    at += 1
                writer.add_message(estimate_id, stamp, estimate_record(
                    stamp, _FRAME, e.wrench[k], e.free[k], e.score[k], e.model_version[k],
                    e.restarted[k], e.external[k]), stamp)
            for stamp, body in events[at:]:
                _write_event(writer, events_id, stamp, body)
            writer.finish()
    except OSError as exc:
        raise AdapterError(f"cannot write {path}: {exc}") from exc


def _write_event(writer: Writer, channel: int, stamp: int, body: str) -> None:
    writer.add_message(channel, stamp, event_record(stamp, body), stamp)


def logged_events(path: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """The events of an MCAP log (``/wrenchd/events``: a ROS 2 log's
    ``wrenchd_msgs/msg/Event`` or a JSON log's message) as JSON objects, in file order.

    The file is read to its end or to where it stops (a crashed daemon's), without sorting
    (that would read the whole file first and keep nothing of a crashed file); an event that
    cannot be decoded is passed over. A file without the topic gives an empty list.

    Raises:
        OSError: the file cannot be opened.
    """
    from mcap.exceptions import McapError
    from mcap.reader import NonSeekingReader

    out = []
    with open(path, "rb") as f:
        try:
            for schema, channel, message in NonSeekingReader(f).iter_messages(
                    topics=[TOPIC_EVENTS], log_time_order=False):
                try:
                    event = message_fields(channel.message_encoding,
                                           schema.name if schema else "", message.data,
                                           schema.data if schema else None)
                except DataError:
                    continue
                if isinstance(event, dict):
                    out.append(event)
        except (McapError, EOFError, ValueError):
            pass
    return out
