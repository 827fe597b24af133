"""The daemon's settings: a TOML file plus ``WRENCHD_*`` environment overrides (pydantic-settings).

Precedence, highest first: keyword arguments, environment (``WRENCHD_`` prefix, ``__`` between
nesting levels, e.g. ``WRENCHD_LOG__DIRECTORY=/var/lib/wrenchd``,
``WRENCHD_ZENOH__CONNECT='["tcp/10.0.0.2:7447"]'``), the TOML file, the defaults. With no
file and no environment, the settings are the embedded default: one arm ``PSM1`` fed by the
simulated PSM, shipped step-1 weights, loopback zenoh. ``deploy/config/*.toml`` are examples;
``wrenchd config`` prints the effective settings.

A bad value is refused with a message naming it: ``arms.0.encoding: Input should be 'json'
or 'cdr' (got 'xml')``.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator
from pydantic_settings import (BaseSettings, PydanticBaseSettingsSource, SettingsConfigDict,
                               TomlConfigSettingsSource)

from wrenchd.adapters.foxglove_live import FoxgloveConfig
from wrenchd.adapters.mcap_log import LogConfig
from wrenchd.adapters.messages import JOINT_STATE_TYPE, WRENCH_TYPE
from wrenchd.adapters.rmw_zenoh import check_node, check_topic, topic_key
from wrenchd.adapters.zenoh_io import ZenohConfig
from wrenchd.models.errors import ConfigError
from wrenchd.service.pipeline import PipelineConfig
from wrenchd.service.runtime.scheduling import AUTO_REALTIME_PRIORITY

#: Loopback by default: nothing leaves the machine unless the user says so.
DEFAULT_LISTEN = "tcp/127.0.0.1:7447"
_KEY_PART = re.compile(r"^[A-Za-z0-9_\-.{}]+(/[A-Za-z0-9_\-.{}]+)*$")


#: where each key preset puts the two ROS messages of an arm (wrenchd's own JSON keys: events,
#: status, alive, setup, stay under ``{prefix}/{arm}/`` whatever the preset)
KEY_PRESETS: dict[str, dict[str, str]] = {
    # wrenchd's own layout
    "wrenchd": {"measured_js": "{prefix}/{arm}/measured_js",
                "wrench": "{prefix}/{arm}/wrenchd/measured_cf"},
    # zenoh-bridge-ros2dds's default mapping: the ROS topic without its leading slash, no prefix
    "ros2dds": {"measured_js": "{arm}/measured_js", "wrench": "{arm}/wrenchd/measured_cf"},
    # rmw_zenoh: ROS topic names, turned into rmw_zenoh key expressions (adapters/rmw_zenoh.py)
    "rmw_zenoh": {"measured_js": "/{arm}/measured_js", "wrench": "/{arm}/wrenchd/measured_cf"},
}
#: presets whose payloads are ROS 2 CDR
CDR_PRESETS = ("ros2dds", "rmw_zenoh")
_ROS_KEYS = ("measured_js", "wrench")


class KeysConfig(BaseModel):
    """Zenoh key templates; ``{prefix}`` and ``{arm}`` are substituted.

    ``preset`` picks where the joint states come from and the wrench goes
    (:data:`KEY_PRESETS`); ``measured_js`` and ``wrench`` override it (with ``rmw_zenoh``
    they are ROS topic names such as ``/{arm}/measured_js``). ``keys = "ros2dds"`` is short
    for ``[arms.keys] preset = "ros2dds"``.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    preset: Literal["wrenchd", "ros2dds", "rmw_zenoh"] = Field(
        default="wrenchd", description="where the joint states come from and the wrench goes: "
                                       "wrenchd, ros2dds or rmw_zenoh (KEY_PRESETS)")
    measured_js: str | None = Field(default=None,
                                    description="joint states in; unset: the preset's")
    wrench: str | None = Field(default=None, description="the wrench out; unset: the preset's")
    events: str = Field(default="{prefix}/{arm}/wrenchd/events", description="events out")
    status: str = Field(default="{prefix}/{arm}/wrenchd/status", description="status out")
    alive: str = Field(default="{prefix}/{arm}/wrenchd/alive",
                       description="liveliness token of the arm")
    setup: str = Field(default="{prefix}/{arm}/setup",
                       description="set-up changes in (robot side, like measured_js)")

    @model_validator(mode="before")
    @classmethod
    def _shorthand(cls, data: Any) -> Any:
        return {"preset": data} if isinstance(data, str) else data

    @field_validator("measured_js", "wrench", "events", "status", "alive", "setup")
    @classmethod
    def _template(cls, v: str | None) -> str | None:
        if v is not None and ("*" in v or "$" in v or "//" in v):
            raise ValueError(f"not a plain zenoh key expression: {v!r}")
        return v

    @model_validator(mode="after")
    def _keys(self) -> KeysConfig:
        for name in ("measured_js", "wrench", "events", "status", "alive", "setup"):
            example = self.template(name).format(prefix="dvrk", arm="PSM1")
            if self.preset == "rmw_zenoh" and name in _ROS_KEYS:
                try:
                    check_topic(example)
                except ConfigError as exc:
                    raise ValueError(f"{name}: {exc}") from None
            elif not _KEY_PART.match(self.template(name)):
                raise ValueError(f"{name}: not a plain zenoh key expression: "
                                 f"{self.template(name)!r}")
        return self

    def template(self, name: str) -> str:
        """The template of key ``name`` (the preset's where not given)."""
        value = getattr(self, name)
        return KEY_PRESETS[self.preset][name] if value is None else value

    def topics(self, prefix: str, arm: str) -> dict[str, str]:
        """With ``rmw_zenoh``: the ROS topic names of ``measured_js`` and ``wrench``."""
        return {k: self.template(k).format(prefix=prefix, arm=arm) for k in _ROS_KEYS}

    def resolve(self, prefix: str, arm: str, domain_id: int = 0) -> dict[str, str]:
        """Every key of the arm; with ``rmw_zenoh`` the two ROS topics' key expressions in
        ROS domain ``domain_id``."""
        keys = {k: self.template(k).format(prefix=prefix, arm=arm)
                for k in ("measured_js", "wrench", "events", "status", "alive", "setup")}
        if self.preset == "rmw_zenoh":
            keys["measured_js"] = topic_key(domain_id, keys["measured_js"], JOINT_STATE_TYPE)
            keys["wrench"] = topic_key(domain_id, keys["wrench"], WRENCH_TYPE)
        return keys


class RosSettings(BaseModel):
    """The daemon as a ROS 2 node over rmw_zenoh (arms whose keys preset is ``rmw_zenoh``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    domain_id: int = Field(default=0, ge=0, le=232,
                           description="the ROS graph's domain (ROS_DOMAIN_ID): the first chunk "
                                       "of every rmw_zenoh key and token")
    node: str = Field(default="wrenchd", description="the node's name")
    namespace: str = Field(default="/", description="the node's namespace")

    @model_validator(mode="after")
    def _names(self) -> RosSettings:
        try:
            check_node(self.node, self.namespace)
        except ConfigError as exc:
            raise ValueError(str(exc)) from None
        return self


class ArmConfig(BaseModel):
    """One arm served by the daemon."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(default="PSM1", pattern=r"^[A-Za-z0-9_\-]+$", description="arm name")
    encoding: Literal["json", "cdr"] = Field(
        default="json", description="wire encoding of inputs and wrenches (default: cdr with the "
                                    "keys presets ros2dds and rmw_zenoh, else json)")
    frame_id: str = Field(default="psm_base", description="frame of the published wrench")
    express: bool = Field(
        default=True,
        description="publish each wrench at once (zenoh express), not in a batch that zenoh's "
                    "transport may hold for up to its batching time limit (1 ms by default), "
                    "as it does with the arms' wrenches of one pass; false: batched, a little "
                    "less CPU per sample, and fewer messages for a full transmit queue to drop "
                    "(docs/results.md, benchmarks)")
    model: str = Field(default="seal",
                       description="step-1 weights: a shipped name (base, seal, paper-base, paper-seal) or a checkpoint")
    corr_checkpoint: str | None = Field(default=None,
                                        description="start from this Corr (e.g. a saved version)")
    keys: KeysConfig = Field(default_factory=KeysConfig)
    pipeline: PipelineConfig = Field(default_factory=PipelineConfig)

    @model_validator(mode="before")
    @classmethod
    def _cdr_by_default(cls, data: Any) -> Any:
        """The ROS presets' encoding is CDR unless the file says otherwise (then refused)."""
        if isinstance(data, dict) and "encoding" not in data:
            keys = data.get("keys")
            preset = (keys if isinstance(keys, str) else keys.get("preset")
                      if isinstance(keys, dict) else getattr(keys, "preset", None))
            if preset in CDR_PRESETS:
                data = {**data, "encoding": "cdr"}
        return data

    @model_validator(mode="after")
    def _preset_encoding(self) -> ArmConfig:
        if self.keys.preset in CDR_PRESETS and self.encoding != "cdr":
            raise ValueError(f"keys preset {self.keys.preset!r} carries ROS 2 CDR: encoding "
                             f"must be 'cdr', got {self.encoding!r}")
        return self


class SimulatorSettings(BaseModel):
    """The simulated PSM started beside the daemon when ``robot = "simulated"``."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    scenario: str = Field(default="trocar-contact", description="wrenchd.adapters.sim scenario")
    seed: int = Field(default=0, description="seed of the simulated session")
    rate_hz: float = Field(default=200.0, gt=0.0, le=5000.0,
                           description="joint-state rate of the simulated PSM [Hz]")

    @field_validator("scenario")
    @classmethod
    def _known(cls, value: str) -> str:
        from wrenchd.adapters.sim.scenarios import SCENARIOS

        if value not in SCENARIOS:
            raise ValueError(f"unknown scenario {value!r}; choose one of {sorted(SCENARIOS)}")
        return value


class RingConfig(BaseModel):
    """How joint states reach the estimation thread, and the backpressure on the way."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    intake: Literal["channel", "callback"] = Field(
        default="channel",
        description="channel: one zenoh subscriber for all arms queues the samples inside "
                    "zenoh, and the estimation thread takes them when it is ready (no Python "
                    "callback per sample; the arms' keys must fit one key expression); "
                    "callback: a Python callback per sample puts it in the arm's ring "
                    "(service/runtime/intake.py says what each costs)")
    capacity: int = Field(default=2000, ge=1,
                          description="queued samples per arm; beyond, the oldest is dropped "
                                      "(callback: each counted; channel: each pass that found "
                                      "the channel full is counted)")
    gather_us: float = Field(
        default=0.0, ge=0.0, le=5000.0,
        description="how long the estimation thread, woken by one arm's sample, waits for "
                    "the other streaming arms' samples so that one pass steps them together "
                    "(step 1's cost is per pass, not per arm) [us]; 0: no wait. At most this "
                    "much latency for CPU (callback intake only): docs/results.md has the "
                    "measured trade")


class CpuPlacement(BaseModel):
    """Which CPUs the daemon and its adaptation worker may run on (Linux affinity).

    A bedside machine gives the estimator a core of its own: ``daemon = [1]``,
    ``worker = [0]`` keeps training, the robot's other software and the cache traffic they
    bring off the core that estimates. Unset: the scheduler decides. ``realtime_priority``
    lets a sample's threads preempt everything else the machine runs (as the dVRK's own
    controller runs); by default wherever the process is permitted to.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    daemon: list[int] | None = Field(default=None, description="CPUs of the daemon's threads")
    worker: list[int] | None = Field(default=None, description="CPUs of the adaptation worker")
    realtime_priority: int | Literal["auto", "off"] = Field(
        default="auto",
        description="SCHED_FIFO priority (1-99) of the threads a sample passes through "
                    "(zenoh's, the callbacks', estimation); the daemon's other Python threads "
                    "one step below; the adaptation worker and the simulated robots stay in "
                    "the normal class. An explicit "
                    "priority needs CAP_SYS_NICE or an rtprio limit and is refused without; "
                    f"auto: {AUTO_REALTIME_PRIORITY} where permitted, else the normal class "
                    "(said once at start); off: the normal class")

    @field_validator("realtime_priority")
    @classmethod
    def _priority(cls, value: int | str) -> int | str:
        if isinstance(value, int) and not 1 <= value <= 99:
            raise ValueError(f"{value} is not a SCHED_FIFO priority (1-99), 'auto' or 'off'")
        return value

    @field_validator("daemon", "worker")
    @classmethod
    def _cpus(cls, value: list[int] | None) -> list[int] | None:
        if value is None:
            return None
        if not value:
            raise ValueError("an empty CPU list would leave no CPU to run on")
        count = os.cpu_count() or 1
        bad = [c for c in value if not 0 <= c < count]
        if bad:
            raise ValueError(f"CPUs {bad} do not exist on this machine (it has {count}: "
                             f"0..{count - 1})")
        return sorted(set(value))


class ServiceSettings(BaseSettings):
    """Everything ``wrenchd serve`` needs (see the module docstring for the sources)."""

    model_config = SettingsConfigDict(env_prefix="WRENCHD_", env_nested_delimiter="__",
                                      extra="forbid", frozen=True)

    robot: Literal["simulated", "external"] = Field(
        default="simulated", description="simulated: start the simulated PSM beside the daemon")
    prefix: str = Field(default="dvrk", pattern=r"^[A-Za-z0-9_\-]+(/[A-Za-z0-9_\-]+)*$",
                        description="first part of every key: {prefix}/{arm}/...")
    arms: list[ArmConfig] = Field(default_factory=lambda: [ArmConfig()])
    zenoh: ZenohConfig = Field(default_factory=lambda: ZenohConfig(listen=[DEFAULT_LISTEN]))
    ring: RingConfig = Field(default_factory=RingConfig)
    log: LogConfig = Field(default_factory=LogConfig)
    simulator: SimulatorSettings = Field(default_factory=SimulatorSettings)
    models_dir: str | None = Field(default=None,
                                   description="adapted Corr versions (default: log dir/models)")
    keep_checkpoints: int | None = Field(
        default=None, ge=1,
        description="keep each arm's newest N adapted Corr versions in models_dir, and the one "
                    "being served; older ones are removed at each new version (None: keep "
                    "every one)")
    status_interval_s: float = Field(default=1.0, gt=0.0, description="status log period [s]")
    cpus: CpuPlacement = Field(default_factory=CpuPlacement)
    ros: RosSettings = Field(default_factory=RosSettings)
    foxglove: FoxgloveConfig = Field(default_factory=FoxgloveConfig)   # live view (off by default)
    duration_s: float | None = Field(default=None, gt=0.0, description="stop after [s]")

    @model_validator(mode="after")
    def _unique_arms(self) -> ServiceSettings:
        names = [a.name for a in self.arms]
        if not names:
            raise ValueError("at least one arm is needed")
        if len(set(names)) != len(names):
            raise ValueError(f"arm names must be unique, got {names}")
        return self

    @model_validator(mode="after")
    def _simulated_robot_keys(self) -> ServiceSettings:
        if self.robot == "simulated":
            other = [a.name for a in self.arms if a.keys.preset != "wrenchd"]
            if other:
                raise ValueError(f"the simulated robot publishes JSON on "
                                 f"{{prefix}}/{{arm}}/measured_js: arms {other} with another "
                                 f"keys preset need robot = \"external\"")
        return self

    @classmethod
    def settings_customise_sources(cls, settings_cls: type[BaseSettings],
                                   init_settings: PydanticBaseSettingsSource,
                                   env_settings: PydanticBaseSettingsSource,
                                   dotenv_settings: PydanticBaseSettingsSource,
                                   file_secret_settings: PydanticBaseSettingsSource):
        toml = settings_cls.model_config.get("toml_file")
        sources: list[PydanticBaseSettingsSource] = [init_settings, env_settings]
        if toml:
            sources.append(TomlConfigSettingsSource(settings_cls, toml_file=toml))
        return tuple(sources)

    def effective_models_dir(self) -> str:
        return self.models_dir or str(Path(self.log.directory) / "models")


def _describe(exc: ValidationError) -> str:
    lines = []
    for err in exc.errors():
        where = ".".join(str(p) for p in err["loc"]) or "(settings)"
        got = err.get("input")
        shown = repr(got) if not isinstance(got, dict) else "{...}"
        lines.append(f"{where}: {err['msg']} (got {shown[:80]})")
    return "; ".join(lines)


def load_settings(path: str | Path | None = None, **overrides: Any) -> ServiceSettings:
    """Settings from ``path`` (TOML) + environment + ``overrides``.

    Raises:
        ConfigError: the file is missing or not TOML, or a value is invalid (named).
    """
    if path is not None:
        p = Path(path)
        if not p.is_file():
            raise ConfigError(f"{p}: no such config file")
        import tomllib

        try:
            tomllib.loads(p.read_text())
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{p}: not valid TOML: {exc}") from exc

        class _FromFile(ServiceSettings):
            model_config = SettingsConfigDict(**{**ServiceSettings.model_config,
                                                 "toml_file": str(p)})
        cls: type[ServiceSettings] = _FromFile
    else:
        cls = ServiceSettings
    try:
        settings = cls(**overrides)
    except ValidationError as exc:
        where = f"{path}: " if path is not None else ""
        raise ConfigError(f"{where}invalid settings: {_describe(exc)}") from None
    return settings
