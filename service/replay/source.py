"""Where a replay's joint states come from: recordings, simulator specs and their combinations.

Every command that reads a session (``wrenchd replay``, ``compare``, ``recovery --session``,
``inspect``) names it with one ``SESSION`` string, so a recording, a simulation and a mix of
the two are replayed, scored and compared the same way. The forms (:func:`load_session` lists
them; ``docs/replay-and-policies.md``, "Sessions", says what each one's truth holds):

* ``path/to/file.mcap``: a simulated session (with truth), a daemon log or another
  recorder's ROS 2 bag;
* ``path/to/rosbag2_dir/`` or a bare ``.db3``: a rosbag2 directory
  (:mod:`wrenchd.adapters.recordings`);
* ``path/to/file.csv``: a WPI (21 columns, 200 Hz) or paper (19 columns) recording
  (:mod:`wrenchd.adapters.csv_psm`);
* ``sim:SCENARIO:DURATION[:SEED]``: simulated now (duration in s, seed default 0);
* ``concat:PATH[*N][,PATH[*N]...]``: recordings played one after another, each ``N`` times,
  time continuous, each change of recording a set-up change (:mod:`wrenchd.models.recorded`);
* ``inject:SEED:SESSION``: a session with a simulated trocar and tip contacts added to its
  efforts (:mod:`wrenchd.adapters.sim.injection`).

A ``concat:`` spec runs to the end of its argument: its commas separate recordings, so
where a command takes several sessions (``compare --sessions``) give the sessions after it
as further space-separated arguments (:func:`split_sessions`). Paths in a ``concat:`` spec
cannot contain commas.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from wrenchd.models.errors import ConfigError
from wrenchd.models.physics.effects.drift import drift_onsets
from wrenchd.models.series import JointSample, JointStates, Session

CONCAT, INJECT, SIM = "concat:", "inject:", "sim:"
_TIMES = re.compile(r"^(.*)\*\s*([^*]*)$")


def split_sessions(arguments: list[str]) -> list[str]:
    """Session specs from command-line arguments, each holding one or several specs
    separated by commas; a ``concat:`` spec (also inside ``inject:``) runs to the end of its
    argument, so only the commas before it separate sessions.

    Raises:
        ConfigError: no session at all.
    """
    out: list[str] = []
    for arg in arguments:
        at = arg.find(CONCAT)
        head, tail = (arg, "") if at < 0 else (arg[:at], arg[at:])
        if tail:                                   # back to the start of the spec holding it
            cut = head.rfind(",") + 1
            head, tail = head[:cut], head[cut:] + tail
        out += [s.strip() for s in head.split(",") if s.strip()]
        if tail:
            out.append(tail.strip())
    if not out:
        raise ConfigError("no session given")
    return out


def parse_concat(spec: str) -> list[tuple[str, int]]:
    """``(path, times)`` of each recording of a ``concat:`` spec, the paths checked to exist.

    Raises:
        ConfigError: an empty list, an empty item, a count that is not an integer >= 1, or a
            path that does not exist.
    """
    body = spec[len(CONCAT):] if spec.startswith(CONCAT) else spec
    items = [item.strip() for item in body.split(",")]
    if not body.strip() or not any(items):
        raise ConfigError(f"session {spec!r}: concat: names no recording; expected "
                          "concat:PATH[*N][,PATH[*N]...]")
    out = []
    for item in items:
        if not item:
            raise ConfigError(f"session {spec!r}: an empty recording between commas")
        path, times = item, 1
        m = _TIMES.match(item)
        if m:
            path, count = m.group(1).strip(), m.group(2).strip()
            try:
                times = int(count)
            except ValueError:
                raise ConfigError(f"session {spec!r}: {item!r}: the count after '*' must be an "
                                  f"integer >= 1, got {count!r}") from None
            if times < 1:
                raise ConfigError(f"session {spec!r}: {item!r}: the count after '*' must be "
                                  f"an integer >= 1, got {times}")
        if not path:
            raise ConfigError(f"session {spec!r}: {item!r} names no file")
        if not Path(path).exists():
            raise ConfigError(f"session {spec!r}: no such recording {path!r}")
        out.append((path, times))
    return out


def parse_inject(spec: str) -> tuple[int, str]:
    """The seed and the inner session of an ``inject:SEED:SESSION`` spec.

    Raises:
        ConfigError: a missing part or a seed that is not an integer >= 0.
    """
    parts = spec.split(":", 2)
    if len(parts) != 3 or not parts[2].strip():
        raise ConfigError(f"session {spec!r}: expected inject:SEED:SESSION")
    try:
        seed = int(parts[1])
    except ValueError:
        seed = -1
    if seed < 0:
        raise ConfigError(f"session {spec!r}: the seed must be an integer >= 0, got "
                          f"{parts[1]!r}")
    return seed, parts[2].strip()


def _simulated(spec: str) -> Session:
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
    return Session(session.joint_states, session.truth, {**session.metadata, "source": spec})


def load_recording(path: str) -> Session:
    """One recording file or directory as a session: a wrenchd ``.mcap`` with its truth and
    metadata, else what :func:`~wrenchd.adapters.recordings.read_recording` reads (a rosbag2
    directory, ``.db3``, another recorder's ``.mcap``, ``.csv``), without truth.

    Raises:
        ConfigError: a path that is no recording.
        AdapterError, DataError: the recording cannot be read.
    """
    from wrenchd.adapters.recordings import read_recording, recording_kind

    kind = recording_kind(path)
    if kind == "session":
        from wrenchd.adapters.mcap_session_reader import read_session

        session = read_session(path)
        return Session(session.joint_states, session.truth, {**session.metadata, "source": path})
    rec = read_recording(path)
    meta = {"source": path, "recording": {"kind": rec.kind, "detail": rec.detail}}
    if rec.kind == "csv":
        meta["csv"] = True
    return Session(rec.joint_states, None, meta)


def load_session(spec: str) -> Session:
    """The session named by ``spec``.

    ``SESSION`` strings accepted by ``wrenchd replay``, ``compare``, ``recovery --session`` and
    ``inspect``:

    =================================  =======================================================
    ``path/to/file.mcap``              a simulated session (with truth) or a daemon log (its
                                       ``/psm/measured_js``; no truth), ROS 2 (CDR) or the
                                       former JSON format; a ROS 2 bag another recorder wrote
    ``path/to/rosbag2_dir/``           a rosbag2 directory (MCAP or sqlite3 storage, also a
                                       bare ``.db3``): ``sensor_msgs/msg/JointState`` on
                                       ``/PSM1/measured_js`` (:mod:`wrenchd.adapters.recordings`);
                                       no truth
    ``path/to/file.csv``               a real recording, WPI (21 columns, 200 Hz) or the
                                       paper's 19-column layout (:mod:`wrenchd.adapters.csv_psm`);
                                       no truth
    ``sim:SCENARIO:DURATION[:SEED]``   simulate now, e.g. ``sim:insufflation-change:300:3``
                                       (duration in s, seed default 0); truth included
    ``concat:PATH[*N][,PATH[*N]...]``  recordings (any of the files above) played one after
                                       another, each ``N`` times (default 1), time continuous;
                                       each change of recording is a set-up change
                                       (announced with ``--announce``); truth: free motion
                                       unless a recording has its own
                                       (:mod:`wrenchd.models.recorded`)
    ``inject:SEED:SESSION``            ``SESSION`` (any form here) with a simulated trocar and
                                       tip contacts drawn with ``SEED`` added to its efforts,
                                       truth included (:mod:`wrenchd.adapters.sim.injection`)
    =================================  =======================================================

    Raises:
        ConfigError: a malformed spec, a missing file or an unknown file type.
        AdapterError, DataError: a file cannot be read.
    """
    spec = spec.strip()
    if spec.startswith(SIM):
        return _simulated(spec)
    if spec.startswith(INJECT):
        from wrenchd.adapters.sim.injection import inject

        seed, inner = parse_inject(spec)
        session = inject(load_session(inner), seed)
        return Session(session.joint_states, session.truth, {**session.metadata, "source": spec})
    if spec.startswith(CONCAT):
        from wrenchd.models.recorded import Part, concatenate

        parts = parse_concat(spec)
        loaded = {path: load_recording(path) for path in dict.fromkeys(p for p, _ in parts)}
        return concatenate([Part(path, loaded[path], times)
                            for path, times in parts], source=spec)
    if not spec:
        raise ConfigError("empty session spec")
    if not Path(spec).exists():
        raise ConfigError(f"session {spec!r}: no such file or directory (expected a .mcap, "
                          f".db3 or .csv file, a rosbag2 directory, sim:..., concat:... or "
                          f"inject:...)")
    return load_recording(spec)


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
    drift effects (their start) and a ``concat:`` session's changes of recording
    (:func:`drift_onsets`)."""
    source = str(session.metadata.get("source") or "")
    if source.lower().endswith(".mcap") and Path(source).is_file():
        logged = logged_setup_changes(source)
        if logged:
            return sorted(logged, key=lambda c: c[0])
    return [(start, {"id": name, "source": "scenario"})
            for name, start, _ in drift_onsets(session)]


def logged_setup_changes(path: str) -> list[tuple[float, dict]]:
    """The ``setup_change`` events of a daemon log (MCAP, ``/wrenchd/events``, read by
    :func:`~wrenchd.adapters.replay_mcap.logged_events`): their sample time [s] and detail.
    Files without that topic give an empty list."""
    from wrenchd.adapters.replay_mcap import logged_events

    return [(float(event["t"]), {k: v for k, v in event.items() if k not in ("t", "kind")})
            for event in logged_events(path) if event.get("kind") == "setup_change"]
