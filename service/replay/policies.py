"""Adaptation policies for replay and comparison: a name, a description and a config change.

A policy decides which samples reach the lifelong adaptation and when it may run; comparing
policies on the same sessions shows what the daemon's choice (``gated``) buys. The mechanisms
live in :class:`wrenchd.service.pipeline.arm.ArmPipeline` (the daemon's own code, so a replay
proves something about the daemon); a :class:`Policy` here selects one of them by name and may
tune any part of the :class:`~wrenchd.service.pipeline.arm.PipelineConfig` (gate bounds, delay
line, round interval, ...). Built in: ``gated`` (the daemon's default), ``frozen``,
``ungated``, ``drift-triggered`` and ``periodic-reset``; what each does, and how to register
your own (:func:`register_policy`), is in docs/replay-and-policies.md ("Policies").

``overrides`` is merged into the pipeline config (nested dicts, validated by pydantic, so a
bad value is refused with its name). A policy needing a behaviour the pipeline does not have
(a new ``mechanism``) needs a change in ``ArmPipeline``; a subclass of :class:`Policy` may
also override :meth:`Policy.configure` to compute the config.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from wrenchd.models.errors import ConfigError
from wrenchd.service.pipeline import POLICIES as MECHANISMS
from wrenchd.service.pipeline import PipelineConfig


def merge_nested(base: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``extra`` merged in: nested dicts key by key, anything else replaced."""
    out = dict(base)
    for key, value in extra.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge_nested(out[key], value)
        else:
            out[key] = value
    return out


@dataclass(frozen=True)
class Policy:
    """A named adaptation policy.

    Attributes:
        name: what users type (``--policy NAME``).
        description: one line for tables and ``--help``.
        mechanism: the pipeline's behaviour it uses, one of ``wrenchd.service.pipeline.config.POLICIES``.
        overrides: nested dict merged into the pipeline config (``{"gate": {...}}``).
    """

    name: str
    description: str
    mechanism: str
    overrides: dict[str, Any] = field(default_factory=dict)

    def configure(self, base: PipelineConfig) -> PipelineConfig:
        """The pipeline config of this policy, starting from ``base``.

        Raises:
            ConfigError: an unknown mechanism, or overrides the config refuses.
        """
        if self.mechanism not in MECHANISMS:
            raise ConfigError(f"policy {self.name!r}: unknown mechanism {self.mechanism!r}; "
                              f"the pipeline has {list(MECHANISMS)}")
        data = merge_nested(base.model_dump(), self.overrides)
        data["policy"] = {**data.get("policy", {}), "name": self.mechanism}
        try:
            return PipelineConfig.model_validate(data)
        except ValueError as exc:
            raise ConfigError(f"policy {self.name!r}: {exc}") from exc


_REGISTRY: dict[str, Policy] = {}


def register_policy(policy: Policy, *, replace: bool = False) -> Policy:
    """Make ``policy`` available by name.

    Raises:
        ConfigError: the name is taken (unless ``replace``).
    """
    if policy.name in _REGISTRY and not replace:
        raise ConfigError(f"policy {policy.name!r} is already registered")
    _REGISTRY[policy.name] = policy
    return policy


def get_policy(name: str) -> Policy:
    """The registered policy ``name``.

    Raises:
        ConfigError: unknown name (the message lists the known ones).
    """
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ConfigError(f"unknown policy {name!r}; choose one of {policy_names()}") from None


def policy_names() -> list[str]:
    return list(_REGISTRY)


for _p in (
    Policy("gated", "free-motion samples after a contact-onset delay line (daemon default)",
           "gated"),
    Policy("frozen", "never adapt: step 1 and the initial zero correction", "frozen"),
    Policy("ungated", "every sample trains, contacts included", "ungated"),
    Policy("drift-triggered", "gated, only for eager_s after a detected drift",
           "drift-triggered"),
    Policy("periodic-reset", "gated, back to the initial correction every reset_every_s",
           "periodic-reset"),
):
    register_policy(_p)
