"""Zenoh session set-up: one session per process, loopback peer by default.

Multicast scouting is off unless asked for, so a wrenchd on a hospital network never
announces itself or joins strangers' sessions by accident. Every session must be closed
explicitly (a callback subscriber left open keeps the interpreter from exiting). What a
session is configured with, zenoh's own configuration file and keys included, is composed in
:mod:`wrenchd.adapters.zenoh_config`.

Reconnection: a session whose router or peer goes away keeps its subscribers, publishers,
queryables and liveliness tokens and re-declares them when the link comes back; zenoh retries
each ``connect`` endpoint with a growing wait (``retry_period_*``). zenoh's own defaults
(1 s growing to 4 s) mean up to ~4 s of silence after a router restart; wrenchd retries every
0.25 s growing to 1 s, so wrenches flow again within about a second of a router's restart
(``tests/service/runtime/test_zenoh_restart.py`` kills and restarts one). A client opens
only if its router answers within ``connect_timeout_ms`` (zenoh's default for clients: try
once, fail at once); a peer opens at once and connects when the other side appears.

Encodings: every sample wrenchd puts is marked with zenoh's encoding of its payload,
``application/json`` or ``application/cdr`` (:func:`zenoh_encoding`). A received sample is
decoded by the encoding it is marked with, and by the arm's configured one when it is
unmarked (zenoh's default ``zenoh/bytes``, as rmw_zenoh and plain publishers leave it);
a sample marked with anything else is refused (:func:`wire_encoding`).
"""

from __future__ import annotations

import time
from functools import lru_cache

from wrenchd.adapters.messages import check_encoding
from wrenchd.adapters.zenoh_config import ZenohConfig, describe, zenoh_reason
from wrenchd.models.errors import AdapterError, DataError

#: zenoh's encoding of each wire encoding
ZENOH_ENCODINGS = {"json": "application/json", "cdr": "application/cdr"}
#: what a sample's zenoh encoding (its part before any ``;schema``) says about the payload
_MARKED = {"application/json": "json", "text/json": "json", "application/cdr": "cdr"}
#: encodings that say nothing about the payload: the arm's configured encoding applies
_UNMARKED = frozenset(("", "zenoh/bytes", "application/octet-stream"))


def open_session(config: ZenohConfig):
    """Open a zenoh session.

    Raises:
        ConfigError: the configuration is refused (a config file gone since it was validated).
        AdapterError: zenoh cannot open it (no router, a port in use, a certificate missing),
            with the endpoints.
    """
    import zenoh

    conf = config.to_zenoh()
    try:
        return zenoh.open(conf)
    except Exception as exc:  # zenoh.ZError and friends
        raise AdapterError(f"cannot open zenoh session ({describe(config)}): "
                           f"{zenoh_reason(exc)}") from exc


def wait_for_subscriber(publisher, timeout_s: float, pause=None) -> bool:
    """Wait until zenoh reports a matching subscriber (the daemon's route is in place), so
    the first samples are not published into the void; gives up after ``timeout_s``, or when
    ``pause(0.01)`` (default: a sleep) between looks returns true (a stop request)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if publisher.matching_status.matching:
            return True
        if pause is None:
            time.sleep(0.01)
        elif pause(0.01):
            return False
    return False


def ring_subscriber(session, key: str, capacity: int):
    """A subscriber on ``key`` whose samples queue inside zenoh (its ring channel of
    ``capacity`` samples, in Rust: no Python callback, no GIL per sample; the oldest is
    dropped when full), taken with its ``recv`` (blocking) and ``try_recv`` (None when empty)."""
    import zenoh

    return session.declare_subscriber(key, zenoh.handlers.RingChannel(capacity))


def local_publisher(session, key: str, encoding: str):
    """A publisher on ``key`` whose samples, marked with the zenoh encoding ``encoding``, reach
    only this session's own subscribers (``Locality.SESSION_LOCAL``)."""
    import zenoh

    return session.declare_publisher(key, encoding=zenoh.Encoding(encoding),
                                     allowed_destination=zenoh.Locality.SESSION_LOCAL)


def zenoh_encoding(encoding: str):
    """The ``zenoh.Encoding`` to put payloads of wire encoding ``encoding`` (json, cdr) with."""
    import zenoh

    return zenoh.Encoding(ZENOH_ENCODINGS[check_encoding(encoding)])


def sample_mark(sample) -> str | None:
    """A received sample's encoding as text, None when it is zenoh's default (unmarked); cheap
    enough for a subscriber callback (~0.2 us when unmarked)."""
    encoding = sample.encoding
    if encoding == _default_encoding():
        return None
    return str(encoding)


def wire_encoding(mark: str | None, configured: str) -> str:
    """The wire encoding to decode a sample with: the one its zenoh encoding ``mark`` names,
    ``configured`` when it is unmarked.

    Raises:
        DataError: the sample is marked with an encoding that is neither JSON nor CDR.
    """
    if mark is None:
        return configured
    base = mark.split(";", 1)[0].strip().lower()
    if base in _UNMARKED:
        return configured
    found = _MARKED.get(base)
    if found is None:
        raise DataError(f"sample encoding {mark[:60]!r} is neither JSON nor CDR (expected "
                        f"{' or '.join(sorted(_MARKED))}, or none)")
    return found


@lru_cache(maxsize=1)
def _default_encoding():
    import zenoh

    return zenoh.Encoding.ZENOH_BYTES
