"""A replay's estimates and events as MCAP (the daemon log's topics and ROS 2 messages).

``/wrenchd/estimate`` per estimated sample and ``/wrenchd/events``, the ROS 2 messages of
:mod:`wrenchd.adapters.mcap_log` (a ROS 2 bag: ``ros2`` profile, CDR); metadata
``wrenchd.replay`` holds the policy, the pipeline config and the source. No wall-clock time is
written: equal replays give equal bytes.
"""

from __future__ import annotations

import json
import os

import numpy as np
from mcap.writer import CompressionType, Writer

from wrenchd.adapters.mcap_log import (TOPIC_ESTIMATE, TOPIC_EVENTS, TOPIC_TYPES, estimate_record,
                                       event_record)
from wrenchd.adapters.ros2_msgs import PROFILE, Ros2Channels
from wrenchd.models.errors import AdapterError
from wrenchd.service.replay.loop import ReplayResult

def write_replay_mcap(path: str | os.PathLike[str], r: ReplayResult,
                      metadata: dict | None = None) -> None:
    """Write ``r`` to ``path`` (overwritten).

    Raises:
        AdapterError: the file cannot be written.
    """
    try:
        with open(path, "wb") as f:
            w = Writer(f, compression=CompressionType.ZSTD)
            w.start(profile=PROFILE, library="wrenchd.service.replay.loop/2")
            w.add_metadata("wrenchd.replay", {"json": json.dumps(
                {"policy": r.policy, "config": r.config, "source": r.meta.get("source"),
                 **(metadata or {})}, sort_keys=True, default=str)})
            channels = Ros2Channels(w)
            ids = {topic: channels.add(topic, TOPIC_TYPES[topic])
                   for topic in (TOPIC_ESTIMATE, TOPIC_EVENTS)}
            stamps = r.stamp_ns
            score = np.minimum(r.score, 1e9)
            events = sorted(((max(int(round(e.t * 1e9)), 0), n, e) for n, e in
                             enumerate(r.events)), key=lambda x: (x[0], x[1]))
            ei = 0
            for k in range(len(stamps)):
                s = int(stamps[k])
                while ei < len(events) and events[ei][0] <= s:
                    _event(w, ids[TOPIC_EVENTS], events[ei])
                    ei += 1
                payload = estimate_record(s, "psm_base", r.wrench[k], r.free[k], score[k],
                                          r.model_version[k], r.restarted[k], r.external[k])
                w.add_message(ids[TOPIC_ESTIMATE], s, payload, s)
            for ev in events[ei:]:
                _event(w, ids[TOPIC_EVENTS], ev)
            w.finish()
    except OSError as exc:
        raise AdapterError(f"cannot write {path}: {exc}") from exc


def _event(w: Writer, channel: int, item) -> None:
    stamp, _, ev = item
    body = json.dumps(nan_to_none(ev.to_json()), sort_keys=True, default=str)
    w.add_message(channel, stamp, event_record(stamp, body), stamp)


def nan_to_none(x):
    """JSON has no NaN: non-finite floats become null."""
    if isinstance(x, float):
        return x if np.isfinite(x) else None
    if isinstance(x, dict):
        return {k: nan_to_none(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [nan_to_none(v) for v in x]
    return x
