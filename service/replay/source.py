"""Where a replay's joint states come from: an MCAP session, a simulator spec or a CSV.

``SESSION`` strings accepted by ``wrenchd replay`` and ``wrenchd compare``:

=================================  ==========================================================
``path/to/file.mcap``              a simulated session (with truth) or a daemon log (its
                                   ``/psm/measured_js``; no truth), ROS 2 (CDR) or the
                                   former JSON format
``sim:SCENARIO:DURATION[:SEED]``   simulate now, e.g. ``sim:insufflation-change:300:3``
                                   (duration in s, seed default 0); truth included
``path/to/file.csv``               a real recording, WPI (21 columns, 200 Hz) or the paper's
                                   19-column layout (:mod:`wrenchd.adapters.csv_psm`); no truth
=================================  ==========================================================
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wrenchd.models.errors import ConfigError
from wrenchd.models.physics.effects.drift import drift_onsets
from wrenchd.models.series import JointSample, JointStates, Session


def load_session(spec: str) -> Session:
    """The session named by ``spec`` (see the module docstring).

    Raises:
        ConfigError: a malformed ``sim:`` spec or an unknown file type.
        AdapterError, DataError: the file cannot be read.
    """
    if spec.startswith("sim:"):
        parts = spec.split(":")
        if len(parts) not in (3, 4):
            raise ConfigError(f"simulator spec {spec!r}: expected sim:SCENARIO:DURATION[:SEED]")
        try:
            duration = float(parts[2])
            seed = int(parts[3]) if len(parts) == 4 else 0
        except ValueError:
            raise ConfigError(f"simulator spec {spec!r}: duration must be a number [s] and "
                              f"seed an integer") from None
        from wrenchd.adapters.sim.scenarios import run_scenario

        session = run_scenario(parts[1], duration, seed)
        return Session(session.joint_states, session.truth,
                       {**session.metadata, "source": spec})
    suffix = Path(spec).suffix.lower()
    if suffix == ".mcap":
        from wrenchd.adapters.mcap_session_reader import read_session

        session = read_session(spec)
        return Session(session.joint_states, session.truth, {**session.metadata, "source": spec})
    if suffix == ".csv":
        from wrenchd.adapters.csv_psm import read_psm_csv

        return Session(read_psm_csv(spec), None, {"source": spec, "csv": True})
    raise ConfigError(f"session {spec!r}: expected a .mcap or .csv file or "
                      f"sim:SCENARIO:DURATION[:SEED]")


def stamps_ns(js: JointStates) -> np.ndarray:
    """Integer sample stamps [ns] as the session files store them."""
    return np.rint(js.t * 1e9).astype(np.int64)


def joint_state_messages(js: JointStates) -> list[JointSample]:
    """The samples as the decoded messages the daemon's pipeline receives."""
    stamps = stamps_ns(js).tolist()
    names = tuple(js.names)
    return [JointSample(s, "", names, p, v, e)
            for s, p, v, e in zip(stamps, js.position, js.velocity, js.effort)]


def announced_changes(session: Session) -> list[tuple[float, dict]]:
    """The set-up changes a replay of ``session`` can announce to the pipeline, as the
    daemon's ``setup`` key would have (``(time [s], detail)``, oldest first): the
    ``setup_change`` events a daemon logged (a session loaded from a daemon's MCAP log, read
    again here, only when asked: :func:`logged_setup_changes`), else a simulated session's
    drift effects (their start; :func:`drift_onsets`)."""
    source = str(session.metadata.get("source") or "")
    if source.lower().endswith(".mcap") and Path(source).is_file():
        logged = logged_setup_changes(source)
        if logged:
            return sorted(logged, key=lambda c: c[0])
    return [(start, {"id": name, "source": "scenario"})
            for name, start, _ in drift_onsets(session)]


def logged_setup_changes(path: str) -> list[tuple[float, dict]]:
    """The ``setup_change`` events of a daemon log (MCAP, ``/wrenchd/events``; a ROS 2 log's
    ``wrenchd_msgs/msg/Event`` or a JSON log's message): their sample time [s] and detail.
    Files without that topic give an empty list."""
    from mcap.exceptions import McapError
    from mcap.reader import NonSeekingReader

    from wrenchd.adapters.mcap_log import TOPIC_EVENTS, message_fields
    from wrenchd.models.errors import DataError

    out = []
    with open(path, "rb") as f:
        # read in file order (sorting by log time would read the whole file first and keep
        # nothing of a crashed daemon's), to the end or to where the file stops
        try:
            for schema, channel, message in NonSeekingReader(f).iter_messages(
                    topics=[TOPIC_EVENTS], log_time_order=False):
                try:
                    event = message_fields(channel.message_encoding,
                                           schema.name if schema else "", message.data,
                                           schema.data if schema else None)
                except DataError:
                    continue
                if isinstance(event, dict) and event.get("kind") == "setup_change":
                    detail = {k: v for k, v in event.items() if k not in ("t", "kind")}
                    out.append((float(event["t"]), detail))
        except (McapError, EOFError, ValueError):
            pass
    return out
