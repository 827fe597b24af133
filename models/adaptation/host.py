"""Every arm's :class:`Adapter` and the calls its pipeline makes on it, on a clock of the caller's.

The one adaptation loop body that the daemon's worker process and replay's worker share: the
daemon calls it with wall-clock seconds since the worker started (rounds pace themselves in
real time), replay with the sample time of each call (deterministic). Pure: no I/O, no clock.

Calls, by ``kind``:

* ``"samples"``: payload ``(windows (n, W, 12), step1 (n, 6), measured (n, 6), t (n,))``
  (:meth:`Adapter.add`); ``"rows"``: payload ``(rows (n, W * 12 + 12) float32, t (n,))``
  (:meth:`Adapter.add_rows`).
* ``"drift"``: a drift detected at the sample time ``payload`` (None: ``now``): adapt eagerly
  from ``now``, forget the held-out samples (:meth:`Adapter.on_drift`).
* ``"setup"``: payload the announced change's sample time [s]; a ``"pressure"`` change, eager
  from ``now`` (:meth:`Adapter.on_setup_change`); ``"instrument"``: the same for an instrument
  change (the adapter's training data restart). :data:`SETUP_CALLS` names the call of each
  set-up change kind.
* ``"reset"``: back to a fresh adapter (the periodic-reset policy).
* ``"tick"``: a round at ``now`` if one is due; its :class:`RoundResult` or None.
* ``"fail"``: fault injection for tests: the arm's next round raises.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from wrenchd.models.adaptation.adapter import SETUP_KINDS, Adapter
from wrenchd.models.adaptation.config import AdaptationConfig, RoundResult

CALLS = ("samples", "rows", "drift", "setup", "instrument", "reset", "tick", "fail")
#: the call of each announced set-up change kind (``SETUP_KINDS``)
SETUP_CALLS = {"pressure": "setup", "instrument": "instrument"}
assert set(SETUP_CALLS) == set(SETUP_KINDS)


class AdapterHost:
    """The adapters of one worker, one per arm.

    Args:
        configs: the adaptation settings per arm.
        normalisations: the ``Corr`` normalisation per arm (from its step-1 model).
    """

    def __init__(self, configs: dict[str, AdaptationConfig],
                 normalisations: dict[str, dict[str, np.ndarray] | None] | None = None) -> None:
        norms = normalisations or {}
        self.adapters = {arm: Adapter(cfg, normalisation=norms.get(arm))
                         for arm, cfg in configs.items()}
        self._fail_next: set[str] = set()

    @property
    def arms(self) -> list[str]:
        return list(self.adapters)

    def idle_tick(self, arm: str, now: float) -> bool:
        """Whether a ``"tick"`` at ``now`` would do nothing, however many samples came before
        it (no round can be due and no failure is injected): the caller may skip it and add
        those samples later, in one call."""
        adapter = self.adapters.get(arm)
        return adapter is None or (arm not in self._fail_next and not adapter.may_be_due(now))

    def call(self, arm: str, kind: str, now: float, payload: Any = None) -> RoundResult | None:
        """Apply one call at ``now`` [s, the caller's clock]; a round's result for ``tick``.

        Raises:
            ValueError: an unknown ``kind``.
            RuntimeError: an injected failure (``"fail"`` before this ``"tick"``).
        """
        adapter = self.adapters.get(arm)
        if adapter is None:
            return None                       # not an adapting arm: nothing to do
        if kind == "tick":
            if arm in self._fail_next:
                self._fail_next.discard(arm)
                raise RuntimeError("injected adaptation failure")
            return adapter.round(now)
        if kind == "samples":
            adapter.add(*payload)
        elif kind == "rows":
            adapter.add_rows(*payload)
        elif kind == "drift":
            adapter.on_drift(now if payload is None else float(payload), now)
        elif kind == "setup":
            adapter.on_setup_change(float(payload), now, "pressure")
        elif kind == "instrument":
            adapter.on_setup_change(float(payload), now, "instrument")
        elif kind == "reset":
            self.adapters[arm] = Adapter(adapter.config, normalisation=adapter.normalisation)
        elif kind == "fail":
            self._fail_next.add(arm)
        else:
            raise ValueError(f"unknown adaptation call {kind!r}; one of {', '.join(CALLS)}")
        return None
