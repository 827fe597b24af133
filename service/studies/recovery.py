"""The insufflation-recovery measure (``wrenchd recovery``), per seed and per setting.

Insufflation changes the body wall's stiffness during surgery; the lifelong adaptation is
worth having if, a minute after such a change, the estimate is as good as before it. The
measure simulates ``insufflation-change`` (the pressure steps 12 -> 20 mmHg at 40 % of the
session) for each seed, replays it through the daemon's pipeline once per setting (a JSON
object of ``PipelineConfig`` overrides merged into the defaults), and reports per seed the
free-motion force RMSE [N] before the change and after 60 s of free motion
(:func:`wrenchd.service.replay.metrics.recovery_levels`), their ratio (target <= 1.10), how
many samples offered to training were truly in contact (target 0) and what share of the truly
free motion in the minute after the change was offered; then per setting the mean ratio, how
many seeds are within 1.10 and the worst. Its options (a settled replay, bins, an announced
change, recorded sessions) are at :func:`run_recovery` and in docs/replay-and-policies.md
("The insufflation-recovery measure").

Example::

    wrenchd recovery --seeds 3,4,5 --set '{}' --set '{"adaptation": {"refit_shrink": 0}}'
    wrenchd recovery --seeds 3,4,5,6,7,8 --settled --announce
"""

from __future__ import annotations

import json
import time

from wrenchd.models.errors import ConfigError

SCENARIO = "insufflation-change"
SETTLED_SCENARIO = "insufflation-high"     # the same seeds at the new pressure throughout
CHANGE_FRACTION = 0.4                    # adapters/sim/scenarios.py: the step at 40 %
TARGET_RATIO = 1.10
SETTLE_S = 60.0                          # free motion after the change before "post" [s]


def pipeline_settings(texts: list[str]):
    """``[(text, PipelineConfig)]``: each JSON object of overrides merged into the defaults
    (none: the defaults alone).

    Raises:
        ConfigError: a text that is not a JSON object, or overrides the config refuses.
    """
    from wrenchd.service.pipeline import PipelineConfig
    from wrenchd.service.replay.policies import merge_nested

    out = []
    for text in texts or ["{}"]:
        try:
            overrides = json.loads(text)
            if not isinstance(overrides, dict):
                raise ValueError("not a JSON object")
            config = PipelineConfig.model_validate(merge_nested(PipelineConfig().model_dump(),
                                                                overrides))
        except ValueError as exc:
            raise ConfigError(f"--set {text!r}: {exc}") from exc
        out.append((text, config))
    return out


def _rounded(values) -> list[float | None]:
    """JSON-ready: 4 decimals, None for NaN (an empty bin)."""
    return [None if v != v else round(float(v), 4) for v in values]


def _given_sessions(specs: list[str]) -> tuple[dict, dict]:
    """The sessions named by ``specs`` and the time of each one's first set-up change [s].

    Raises:
        ConfigError: a session without truth or without a set-up change.
    """
    from wrenchd.models.physics.effects.drift import drift_onsets
    from wrenchd.service.replay.source import load_session

    sessions, changes = {}, {}
    for spec in specs:
        session = load_session(spec)
        if session.truth is None:
            raise ConfigError(f"--session {spec!r} has no truth to measure against (a "
                              "concat:, inject: or sim: session has)")
        onsets = drift_onsets(session)
        if not onsets:
            raise ConfigError(f"--session {spec!r} records no set-up change to recover from")
        sessions[spec], changes[spec] = session, onsets[0][1]
    return sessions, changes


def run_recovery(seeds: list[int], settings: list[str], duration_s: float = 220.0,
                 model: str = "seal", progress=print, settled: bool = False,
                 bin_s: float | None = None, announce: bool = False,
                 sessions_given: list[str] | None = None) -> dict:
    """The measure for every seed and setting (``settings``: JSON texts; none: the defaults).

    ``settled``: each seed is also replayed as ``insufflation-high`` (the same motion, contacts
    and noise at 20 mmHg from the start), and the row gives that replay's error over the same
    window after the change (``settled_post_n``) and ``excess`` = post / settled: how far the
    adapted net is from one that learnt the new pressure from the start. Post / pre mixes that
    with how much harder the new set-up is and how much the net keeps improving anyway; excess
    does not. ``bin_s``: each row also gives the free-motion error per bin from the change to
    the end (``post_bins_n``; settled: ``settled_bins_n`` and their ratio, ``excess_bins``).
    ``announce``: the step is announced to the pipeline at its time, as the daemon's ``setup``
    key would be (:meth:`wrenchd.service.pipeline.arm.ArmPipeline.setup_change`), so the
    adapter carries its buffer over (:mod:`wrenchd.models.body_wall_tracker`).
    ``sessions_given`` (session specs, :mod:`wrenchd.service.replay.source`): the measure runs
    on those instead of the simulated seeds, around each one's first set-up change.
    """
    if bin_s is not None and not 0 < bin_s < float("inf"):
        raise ConfigError(f"--bins must be a positive number of seconds, got {bin_s:g}")
    if sessions_given and settled:
        raise ConfigError("--settled needs the simulated scenario; it does not apply to "
                          "--session")
    after_s = (1.0 - CHANGE_FRACTION) * duration_s
    if not sessions_given and not after_s > SETTLE_S:     # refused before minutes of simulation
        raise ConfigError(f"--duration {duration_s:g}: the change comes at "
                          f"{CHANGE_FRACTION:.0%} of it, which leaves {after_s:g} s after it; "
                          f"the measure needs more than {SETTLE_S:g} s of free motion after "
                          "the change (contacts take some of it)")
    import numpy as np

    from wrenchd.adapters.sim.scenarios import run_scenario
    from wrenchd.service.pipeline.step1 import load_free_space
    from wrenchd.service.replay.loop import replay
    from wrenchd.service.replay.metrics import free_error_series, recovery_levels
    from wrenchd.service.replay.source import announced_changes
    from wrenchd.service.runtime.scheduling import one_compute_thread

    one_compute_thread()
    configs = pipeline_settings(settings)
    free_space = load_free_space(model)
    if sessions_given:
        sessions, change_at = _given_sessions(sessions_given)
    else:
        sessions = {seed: run_scenario(SCENARIO, duration_s, seed) for seed in seeds}
        change_at = {seed: CHANGE_FRACTION * duration_s for seed in seeds}
    references = ({seed: run_scenario(SETTLED_SCENARIO, duration_s, seed) for seed in seeds}
                  if settled else {})
    rows = []
    for text, config in configs:
        for seed, session in sessions.items():
            change_s = change_at[seed]
            t0 = time.perf_counter()
            r = replay(session, free_space, config, step1="torch",
                       setup_changes=announced_changes(session) if announce else ())
            try:
                pre, post = recovery_levels(r, session, change_s, settle_s=SETTLE_S)
            except ValueError as exc:
                what = f"--session {seed!r}" if sessions_given else f"--duration {duration_s:g}"
                raise ConfigError(f"{what}: {exc}") from exc
            t = session.joint_states.t
            idx = np.searchsorted(t, r.offered_t)
            after = ~session.truth.in_contact & (t >= change_s) & (t < change_s + 60.0)
            offered = np.zeros(len(t), bool)
            offered[idx] = True
            row = {"set": text, ("session" if sessions_given else "seed"): seed,
                   "change_s": change_s, "pre_n": round(pre, 4), "post_n": round(post, 4),
                   "ratio": round(post / pre, 4),
                   "contact_offered": int(session.truth.in_contact[idx].sum()),
                   "offered": int(len(idx)),
                   # how much of the free motion in the minute after the change reached
                   # training (the gate calls some of it contact once the residual grew)
                   "free_offered_after": round(float(offered[after].mean()), 4),
                   "drifts": r.status["counters"]["drifts"],
                   "setup_changes": r.status["counters"]["setup_changes"],
                   "seconds": round(time.perf_counter() - t0, 1)}
            line = (f"{text} {'session' if sessions_given else 'seed'} {seed}: pre {pre:.3f} N, post {post:.3f} N, ratio "
                    f"{post / pre:.3f}, contact samples offered {row['contact_offered']} of "
                    f"{row['offered']}, free motion offered in the minute after the change "
                    f"{row['free_offered_after']:.0%}")
            if bin_s is not None:
                bins = free_error_series(r, session, bin_s, start_s=change_s, rms=True)
                post_bins = bins["free"]
                row.update(bins_start_s=_rounded(bins["t"]), post_bins_n=_rounded(post_bins))
            if settled:
                reference = references[seed]
                r_ref = replay(reference, free_space, config, step1="torch")
                _, post_ref = recovery_levels(r_ref, reference, change_s, settle_s=SETTLE_S)
                row.update(settled_post_n=round(post_ref, 4),
                           excess=round(post / post_ref, 4),
                           seconds=round(time.perf_counter() - t0, 1))
                line += f"; settled {post_ref:.3f} N, excess {post / post_ref:.3f}"
                if bin_s is not None:
                    ref_bins = free_error_series(r_ref, reference, bin_s, start_s=change_s,
                                                 rms=True)["free"]
                    n = min(len(post_bins), len(ref_bins))
                    with np.errstate(invalid="ignore"):
                        excess_bins = post_bins[:n] / ref_bins[:n]
                    row.update(settled_bins_n=_rounded(ref_bins),
                               excess_bins=_rounded(excess_bins))
            rows.append(row)
            progress(line)
            if bin_s is not None:
                shown = row.get("excess_bins", row["post_bins_n"])
                what = "excess over settled" if settled else "free-motion error [N]"
                progress(f"{text} seed {seed}: {what} per {bin_s:g} s bin from "
                         f"{change_s:g} s: " + " ".join("-" if v is None else f"{v:.2f}"
                                                       for v in shown))
    summary = []
    for text, _ in configs:
        ratios = [r["ratio"] for r in rows if r["set"] == text]
        summary.append({"set": text, "mean_ratio": round(float(np.mean(ratios)), 4),
                        "within_target": sum(x <= TARGET_RATIO for x in ratios),
                        "seeds": len(ratios), "worst_ratio": max(ratios),
                        "contact_offered": sum(r["contact_offered"] for r in rows
                                               if r["set"] == text)})
        if settled:
            excess = [r["excess"] for r in rows if r["set"] == text]
            summary[-1].update(mean_excess=round(float(np.mean(excess)), 4),
                               worst_excess=max(excess))
    return {"scenario": None if sessions_given else SCENARIO,
            "sessions": sessions_given or None,
            "duration_s": None if sessions_given else duration_s,
            "change_s": None if sessions_given else CHANGE_FRACTION * duration_s,
            "announced": announce,
            "target_ratio": TARGET_RATIO, "rows": rows, "summary": summary}
