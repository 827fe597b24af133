"""How a wrenchd process's zenoh configuration is composed: zenoh's own file, wrenchd's fields,
then any zenoh key, so that everything zenoh can be told (TLS, access control, endpoints,
timeouts...) can be told to wrenchd too.

Layers, each written over the one before:

1. ``config_file``: a zenoh configuration file (``.json5``, ``.json``, ``.yaml``), read by zenoh
   itself exactly as ``zenohd -c`` reads it; without one, zenoh's defaults;
2. wrenchd's own fields (``mode``, ``listen``, ``connect``, ``multicast_scouting``, the
   connect timeout and retry periods, the send queue's depth), those that are set. A field
   left unset keeps the file's value; where the file says nothing either, wrenchd's default
   applies (peer mode, multicast scouting off, retries every 250 ms growing to 1 s), so a file
   that leaves scouting out does not turn multicast on. Without a file the send queue holds 8
   data batches (zenoh's default: 2);
3. ``config``: zenoh configuration keys (paths such as ``transport/link/tls/root_ca_certificate``)
   and their values, set last: a key written there always wins. A value replaces the key's
   whole subtree (``transport = {}`` resets every transport setting).

Every layer is checked by zenoh when the configuration is built, which :class:`ZenohConfig`
does when it is validated: a missing or unreadable file, an unknown key or a value zenoh
refuses is a :class:`ConfigError` that names the file, field or key, not a zenoh traceback.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from wrenchd.models.errors import ConfigError

#: wrenchd's defaults, for the fields neither the settings nor a config file set
DEFAULTS: dict[str, Any] = {"mode": "peer", "multicast_scouting": False,
                            "retry_period_init_ms": 250, "retry_period_max_ms": 1000,
                            "retry_period_increase_factor": 2.0, "tx_queue_batches": 8}
#: each retry field's name inside zenoh's ``connect/retry``
_RETRY = {"retry_period_init_ms": "period_init_ms", "retry_period_max_ms": "period_max_ms",
          "retry_period_increase_factor": "period_increase_factor"}
#: a zenoh value that differs by mode (``{router: ..., peer: ..., client: ...}``)
_MODES = frozenset(("router", "peer", "client"))

_RUST_SOURCE = re.compile(r" at /\S+?\.rs:\d+\.?")
_MESSAGE = re.compile(r'msg: "((?:[^"\\]|\\.)*)"(?:, location: Some\(Location \{ line: (\d+), '
                      r'column: (\d+) \}\))?')
_STR = re.compile(r'^Str\("(.*)"\)$', re.S)


class ZenohConfig(BaseModel):
    """How this process joins the zenoh network (layers: see the module docstring)."""

    model_config = ConfigDict(extra="forbid")

    config_file: str | None = Field(
        default=None,
        description="zenoh configuration file (.json5, .json, .yaml) read as zenoh's own tools "
                    "read it; the fields set here and `config` apply over it")
    mode: Literal["peer", "client", "router"] | None = Field(
        default=None, description="zenoh mode (unset: the config file's, else peer)")
    listen: list[str] = Field(default_factory=list,
                              description="endpoints to listen on, e.g. tcp/127.0.0.1:7447 "
                                          "(empty: the config file's, else zenoh's)")
    connect: list[str] = Field(default_factory=list,
                               description="endpoints to connect to (empty: the config "
                                           "file's, else none)")
    multicast_scouting: bool | None = Field(
        default=None, description="discover peers by multicast (unset: the config file's, "
                                  "else off)")
    connect_timeout_ms: int | None = Field(
        default=None, ge=-1,
        description="how long opening waits for a connect endpoint [ms]: -1 forever, 0 try once; "
                    "default zenoh's (client 0: the daemon fails to start without its router)")
    retry_period_init_ms: int | None = Field(
        default=None, gt=0,
        description="first wait before re-trying a lost connect endpoint [ms] (default 250)")
    retry_period_max_ms: int | None = Field(
        default=None, gt=0,
        description="longest wait between re-tries [ms] (default 1000; zenoh's 4000): bounds "
                    "the silence after a router or peer comes back")
    retry_period_increase_factor: float | None = Field(
        default=None, ge=1.0,
        description="each failed try multiplies the wait by this (default 2)")
    tx_queue_batches: int | None = Field(
        default=None, ge=1,
        description="batches zenoh's send queue holds for data messages "
                    "(transport/link/tx/queue/size/data; default 8, zenoh's 2). Each express "
                    "message (an arm's wrench, [[arms]] express) takes a batch: with 2, a pass "
                    "of more arms than that loses the rest when the send thread is held over "
                    "zenoh's wait_before_drop (1 ms); 8 hold a pass of 6 arms and more")
    config: dict[str, Any] = Field(
        default_factory=dict,
        description="zenoh configuration keys (e.g. transport/link/tls/root_ca_certificate, "
                    "access_control, id) and their values, set last: they win over the file "
                    "and the fields above")

    @model_validator(mode="after")
    def _compose(self) -> ZenohConfig:
        if self.config_file is None:          # no file to defer to: show wrenchd's defaults
            for name, value in DEFAULTS.items():
                if getattr(self, name) is None:
                    setattr(self, name, value)
        if (self.retry_period_init_ms is not None and self.retry_period_max_ms is not None
                and self.retry_period_max_ms < self.retry_period_init_ms):
            raise ValueError(f"retry_period_max_ms ({self.retry_period_max_ms}) must not be "
                             f"below retry_period_init_ms ({self.retry_period_init_ms})")
        try:
            self.to_zenoh()
        except ConfigError as exc:
            raise ValueError(str(exc)) from None
        return self

    def to_zenoh(self):
        """The ``zenoh.Config`` of the three layers.

        Raises:
            ConfigError: the file is missing or refused by zenoh, or a field or key is refused
                (named, with zenoh's reason).
        """
        import zenoh

        conf = zenoh.Config() if self.config_file is None else _read_file(self.config_file)
        for what, key, value in self._own_keys(conf):
            _insert(conf, key, value, what)
        for key, value in self.config.items():
            _insert(conf, key, value, f"config key {key!r}")
        return conf

    def _own_keys(self, conf):
        """(field, zenoh key, value) of wrenchd's fields to write over ``conf``."""
        mode = self.mode if self.mode is not None else _unset_default(conf, "mode", "mode")
        if mode is not None:
            yield "mode", "mode", mode
        scouting = self.multicast_scouting
        if scouting is None:
            scouting = _unset_default(conf, "scouting/multicast/enabled", "multicast_scouting")
        if scouting is not None:
            yield "multicast_scouting", "scouting/multicast/enabled", scouting
        if self.listen:
            yield "listen", "listen/endpoints", self.listen
        if self.connect:
            yield "connect", "connect/endpoints", self.connect
        if self.connect_timeout_ms is not None:
            yield "connect_timeout_ms", "connect/timeout_ms", self.connect_timeout_ms
        if self.tx_queue_batches is not None:
            yield "tx_queue_batches", "transport/link/tx/queue/size/data", self.tx_queue_batches
        retry = self._retry(_get(conf, "connect/retry"))
        if retry is not None:
            yield "retry_period_*", "connect/retry", retry

    def _retry(self, current: Any) -> dict | None:
        """``connect/retry``: each period set here, else the file's, else wrenchd's default;
        None to leave a file's per-mode retry settings as they are when none is set here."""
        given = {zkey: getattr(self, name) for name, zkey in _RETRY.items()
                 if getattr(self, name) is not None}
        if isinstance(current, dict) and _MODES & set(current) and not given:
            return None
        current = current if isinstance(current, dict) and not _MODES & set(current) else {}
        return {zkey: given.get(zkey, current.get(zkey) if current.get(zkey) is not None
                                else DEFAULTS[name]) for name, zkey in _RETRY.items()}


def zenoh_config(**fields: Any) -> ZenohConfig:
    """A :class:`ZenohConfig` from keyword fields (a command line's options).

    Raises:
        ConfigError: a field, the config file or a key is refused (named).
    """
    try:
        return ZenohConfig(**fields)
    except ValidationError as exc:
        reasons = "; ".join(
            (".".join(str(p) for p in err["loc"]) + ": " if err["loc"] else "")
            + err["msg"].removeprefix("Value error, ") for err in exc.errors())
        raise ConfigError(f"zenoh settings: {reasons}") from None


def has_endpoints(config: ZenohConfig, kind: Literal["listen", "connect"]) -> bool:
    """Whether ``config`` ends up with ``kind`` endpoints, from its fields, its file or a key
    (a verb adds its loopback default only where none is configured)."""
    return bool(_get(config.to_zenoh(), f"{kind}/endpoints"))


def describe(config: ZenohConfig) -> str:
    """A short account of ``config`` for an error message (the keys of ``config``, not their
    values, which can be a whole access control list)."""
    fields = config.model_dump(exclude={"config"}, exclude_none=True, exclude_defaults=True)
    if config.config:
        fields["config"] = sorted(config.config)
    return ", ".join(f"{k}={v}" for k, v in fields.items()) or "zenoh's defaults"


def _read_file(path: str):
    import zenoh

    if not Path(path).is_file():
        raise ConfigError(f"config_file {path!r}: no such file")
    try:
        return zenoh.Config.from_file(path)
    except zenoh.ZError as exc:
        raise ConfigError(f"config_file {path!r}: refused by zenoh: "
                          f"{zenoh_reason(exc, located=True)}") from None


def _insert(conf, key: str, value: Any, what: str) -> None:
    import zenoh

    try:
        text = json.dumps(value)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{what}: not a JSON value: {exc}") from None
    if not key.strip("/"):
        raise ConfigError(f"{what}: empty zenoh key")
    try:
        conf.insert_json5(key, text)
    except zenoh.ZError as exc:
        reason = zenoh_reason(exc)
        if reason == "unknown key":
            reason = "no such zenoh configuration key"
        raise ConfigError(f"{what} = {_short(text)}: refused by zenoh: {reason}") from None


def _get(conf, key: str) -> Any:
    return json.loads(conf.get_json(key))


def _unset_default(conf, key: str, field: str) -> Any:
    """wrenchd's default of ``field`` if ``conf`` leaves ``key`` unset (null), else None."""
    return DEFAULTS[field] if _get(conf, key) is None else None


def _short(text: str, limit: int = 80) -> str:
    return text if len(text) <= limit else text[:limit - 3] + "..."


def zenoh_reason(exc: Exception, located: bool = False) -> str:
    """zenoh's reason in one of its errors, without the Rust debug wrapping and source paths;
    with ``located``, the line and column it gives (those of a file)."""
    text = _RUST_SOURCE.sub("", str(exc)).strip()
    found = _MESSAGE.search(text)
    if found:
        reason = found.group(1).replace('\\"', '"').replace("\\\\", "\\")
        if located and found.group(2):
            reason += f" (line {found.group(2)}, column {found.group(3)})"
        return reason
    found = _STR.match(text)
    return found.group(1) if found else text
