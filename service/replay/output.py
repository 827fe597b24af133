"""A replay's estimates and events as MCAP (the daemon log's topics and ROS 2 messages).

``/wrenchd/estimate`` per estimated sample and ``/wrenchd/events``, the ROS 2 messages of
:mod:`wrenchd.adapters.mcap_log`, written by :func:`wrenchd.adapters.replay_mcap.write_replay_file`;
metadata ``wrenchd.replay`` holds the policy, the pipeline config and the source. No
wall-clock time is written: equal replays give equal bytes.
"""

from __future__ import annotations

import json
import os

from wrenchd.adapters.messages import nan_to_none
from wrenchd.adapters.replay_mcap import write_replay_file
from wrenchd.service.replay.loop import ReplayResult

#: :func:`nan_to_none` is imported from here by the studies and the replay commands
__all__ = ["nan_to_none", "write_replay_mcap"]


def write_replay_mcap(path: str | os.PathLike[str], r: ReplayResult,
                      metadata: dict | None = None) -> None:
    """Write ``r`` to ``path`` (overwritten): each event at its time (not before 0), JSON
    without NaN.

    Raises:
        AdapterError: the file cannot be written.
    """
    events = [(max(int(round(e.t * 1e9)), 0),
               json.dumps(nan_to_none(e.to_json()), sort_keys=True, default=str))
              for e in r.events]
    write_replay_file(path, r, events, {"policy": r.policy, "config": r.config,
                                        "source": r.meta.get("source"), **(metadata or {})})
