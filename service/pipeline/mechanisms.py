"""What each adaptation policy does in the pipeline: which samples it offers, and when.

A :class:`Mechanism` is chosen by ``PolicyConfig.name`` (a replay :class:`Policy
<wrenchd.service.replay.policies.Policy>` names one and tunes the config around it):

==================  ======================================================================
``gated``           free samples, after the delay line (a contact's onset is dropped)
``frozen``          nothing: no adaptation backend at all
``ungated``         every sample at once, contact included
``drift-triggered`` gated, and only within ``eager_s`` of a drift, a set-up change or the
                    calibration
``periodic-reset``  gated, and back to the initial correction net every ``reset_every_s``
==================  ======================================================================

>>> [m.name for m in MECHANISMS.values()]
['gated', 'ungated', 'frozen', 'drift-triggered', 'periodic-reset']
>>> mechanism("drift-triggered").may_offer(t=50.0, eager_until=30.0, calibrating=False)
False
"""

from __future__ import annotations

from typing import ClassVar

from wrenchd.models.errors import ConfigError


class Mechanism:
    """The gated behaviour; subclasses change one rule each."""

    name: ClassVar[str] = "gated"
    #: the pipeline has an adaptation backend
    adapts: ClassVar[bool] = True
    #: every sample is offered at once (no gate, no delay line)
    offers_everything: ClassVar[bool] = False

    def may_offer(self, t: float, eager_until: float, calibrating: bool) -> bool:
        """Whether a sample at ``t`` [s] may be offered at all."""
        return True

    def reset_due(self, t: float, every_s: float) -> bool:
        """Whether the correction net goes back to its initial weights at ``t`` [s]."""
        return False


class Ungated(Mechanism):
    name = "ungated"
    offers_everything = True


class Frozen(Mechanism):
    name = "frozen"
    adapts = False


class DriftTriggered(Mechanism):
    name = "drift-triggered"

    def may_offer(self, t: float, eager_until: float, calibrating: bool) -> bool:
        return calibrating or t <= eager_until


class PeriodicReset(Mechanism):
    name = "periodic-reset"

    def __init__(self) -> None:
        self._next: float | None = None

    def reset_due(self, t: float, every_s: float) -> bool:
        if self._next is None:                 # the clock starts at the first round's tick
            self._next = t + every_s
            return False
        if t < self._next:
            return False
        self._next = t + every_s
        return True


MECHANISMS: dict[str, type[Mechanism]] = {
    m.name: m for m in (Mechanism, Ungated, Frozen, DriftTriggered, PeriodicReset)}


def mechanism(name: str) -> Mechanism:
    """A fresh mechanism (its own state) for ``name``.

    Raises:
        ConfigError: an unknown name (the message lists the known ones).
    """
    try:
        return MECHANISMS[name]()
    except KeyError:
        raise ConfigError(f"unknown policy mechanism {name!r}; one of {list(MECHANISMS)}") from None
