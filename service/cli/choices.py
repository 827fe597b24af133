"""Argparse ``choices`` whose names load on first use, and the two the verbs share."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator


class LazyChoices:
    """An argparse ``choices`` whose names are loaded on first use.

    The scenario and policy registries live beside torch, pinocchio and scipy, which take
    seconds to import. With these, building the parser imports none of them: ``wrenchd
    announce`` and ``wrenchd echo`` start at once (an announcement's stamp is the arm's latest
    sample when it arrives), and a command that names a scenario loads the registry when
    argparse checks the name. Give the argument a ``metavar``: argparse formats one from the
    choices when the argument is added, and list them in its help with ``%(choices)s``.
    """

    def __init__(self, load: Callable[[], Iterable[str]]) -> None:
        self._load = load
        self._names: list[str] | None = None

    def _get(self) -> list[str]:
        if self._names is None:
            self._names = list(self._load())
        return self._names

    def __contains__(self, name: object) -> bool:
        return name in self._get()

    def __iter__(self) -> Iterator[str]:
        return iter(self._get())


def _scenario_names() -> list[str]:
    from wrenchd.adapters.sim.scenarios import SCENARIOS

    return sorted(SCENARIOS)


def _policy_names() -> list[str]:
    from wrenchd.service.replay.policies import policy_names

    return policy_names()


SCENARIO_CHOICES = LazyChoices(_scenario_names)
"""The simulator's scenario names (``wrenchd.adapters.sim.scenarios.SCENARIOS``)."""

POLICY_CHOICES = LazyChoices(_policy_names)
"""The replay's adaptation policy names (``wrenchd.service.replay.policies``)."""
