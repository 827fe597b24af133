"""``wrenchd replay`` and ``wrenchd compare``; ``wrenchd bench replay`` runs :func:`run_replay_bench`.

SESSION is an ``.mcap`` (simulated or a daemon log), ``sim:SCENARIO:DURATION[:SEED]`` or a
real ``.csv`` (see :mod:`wrenchd.service.replay.source`). ``--config`` is a TOML or JSON file with
the pipeline's settings: a ``PipelineConfig`` table, or a daemon settings file (its first
arm's ``pipeline``). ``--seed`` sets the adaptation's seed. Torch runs on one thread, so a
replay repeats bit for bit.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

from wrenchd.models.errors import ConfigError


def load_pipeline_config(path: str | None, seed: int | None = None):
    """The base ``PipelineConfig`` of a replay (see the module docstring)."""
    from wrenchd.service.pipeline.arm import PipelineConfig

    data: dict = {}
    if path:
        text = Path(path).read_text()
        if path.endswith(".json"):
            data = json.loads(text)
        else:
            import tomllib

            data = tomllib.loads(text)
        if "arms" in data:
            data = (data["arms"] or [{}])[0].get("pipeline", {})
        elif "pipeline" in data:
            data = data["pipeline"]
    if seed is not None:
        data = {**data, "adaptation": {**data.get("adaptation", {}), "seed": seed}}
    try:
        return PipelineConfig.model_validate(data)
    except ValueError as exc:
        raise ConfigError(f"pipeline config {path}: {exc}") from exc


def _setup() -> None:
    """One thread for torch and for NumPy's BLAS (see :mod:`wrenchd.service.runtime.scheduling`)."""
    from wrenchd.service.runtime.scheduling import one_compute_thread

    one_compute_thread()


def _cmd_replay(args: argparse.Namespace) -> int:
    _setup()
    from wrenchd.service.runtime.daemon import load_free_space
    from wrenchd.service.replay.policies import get_policy
    from wrenchd.service.replay.loop import replay
    from wrenchd.service.replay.metrics import metrics_markdown, replay_metrics
    from wrenchd.service.replay.output import _finite, write_replay_mcap
    from wrenchd.service.replay.source import announced_changes, load_session

    config = get_policy(args.policy).configure(load_pipeline_config(args.config, args.seed))
    session = load_session(args.session)
    r = replay(session, load_free_space(args.model), config, policy=args.policy,
               batched=not args.streaming, adaptation=args.adaptation,
               result_delay_s=args.result_delay,
               setup_changes=announced_changes(session) if args.announce else ())
    if args.output:
        Path(args.output).parent.mkdir(parents=True, exist_ok=True)
        write_replay_mcap(args.output, r, {"model": args.model})
    m = replay_metrics(r, session)
    if args.report:
        out = Path(args.report)
        out.mkdir(parents=True, exist_ok=True)
        (out / "metrics.json").write_text(json.dumps(_finite(m), indent=1, default=str) + "\n")
        (out / "metrics.md").write_text(metrics_markdown(m))
    print(metrics_markdown(m))
    return 0


def _cmd_compare(args: argparse.Namespace) -> int:
    _setup()
    from wrenchd.service.replay.compare import run_compare
    from wrenchd.service.runtime.daemon import load_free_space

    policies = [p for p in args.policies.split(",") if p]
    sessions = [s for part in args.sessions for s in part.split(",") if s]
    run_compare(policies, sessions, args.out, load_free_space(args.model),
                load_pipeline_config(args.config, args.seed))
    print(f"wrote {args.out}/compare.md, compare.json and plots")
    return 0


def run_replay_bench(json_path: str | None, duration_s: float = 120.0,
                     policy: str = "gated", seed: int = 3) -> dict:
    """Replay a 200 Hz ``insufflation-change`` session of ``duration_s`` with ``policy``.

    Returns ``{"samples_per_s", "realtime_factor", ...}`` (also written to ``json_path``) of
    the default replay (batched, torch step 1, adaptation in the forked worker): the replay
    call itself (pipeline, adaptation, batched pre-pass), not simulating or writing. The same
    run also times inline adaptation, the kernel step 1 and the frozen policy.
    """
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    _setup()
    from wrenchd.adapters.sim.scenarios import run_scenario
    from wrenchd.models.estimator.pretrained import load_pretrained
    from wrenchd.service.pipeline.arm import PipelineConfig
    from wrenchd.service.replay.policies import get_policy
    from wrenchd.service.replay.loop import replay

    session = run_scenario("insufflation-change", duration_s, seed)
    fs = load_pretrained("seal")
    config = get_policy(policy).configure(PipelineConfig())
    result: dict = {"policy": policy, "session": f"sim:insufflation-change:{duration_s:g}:{seed}",
                    "rate_hz": session.joint_states.rate_hz, "threads": 1}
    frozen = get_policy("frozen").configure(PipelineConfig())
    # the default first; the others measured in the same run for comparison
    for name, cfg, kwargs in (("default", config, {}),
                              ("inline_adaptation", config, {"adaptation": "inline"}),
                              ("kernel_step1", config, {"step1": "kernel"}),
                              ("frozen_no_adaptation", frozen, {})):
        start = time.perf_counter()
        r = replay(session, fs, cfg, policy=policy, **kwargs)
        wall = time.perf_counter() - start
        sps = len(r.t) / wall
        result[name] = {"samples_per_s": round(sps), "wall_s": round(wall, 2),
                        "rounds": r.status["counters"]["rounds"],
                        "waited_for_worker": r.meta.get("rounds_waited")}
    best = result["default"]["samples_per_s"]
    result["samples"] = len(session.joint_states)
    result["samples_per_s"] = best
    result["realtime_factor"] = round(best / session.joint_states.rate_hz, 2)
    text = json.dumps(result, indent=2)
    print(text)
    if json_path:
        Path(json_path).parent.mkdir(parents=True, exist_ok=True)
        Path(json_path).write_text(text + "\n")
    return result


def _policy_names() -> list[str]:
    from wrenchd.service.replay.policies import policy_names

    return policy_names()


def register(sub) -> None:
    from wrenchd.service.cli import LazyChoices

    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--config", help="pipeline settings (TOML/JSON; a daemon file works)")
    common.add_argument("--seed", type=int, default=None, help="adaptation seed")
    common.add_argument("--model", default="seal",
                        help="step-1 model: shipped name (base, seal) or checkpoint")

    rep = sub.add_parser("replay", parents=[common],
                         help="replay a session through the daemon's pipeline, with metrics")
    rep.add_argument("session", help="file.mcap, file.csv or sim:SCENARIO:DURATION[:SEED]")
    rep.add_argument("--policy", default="gated", choices=LazyChoices(_policy_names),
                     metavar="NAME", help="adaptation policy: %(choices)s (default %(default)s)")
    rep.add_argument("--announce", action="store_true",
                     help="announce the session's set-up changes to the pipeline as the "
                          "daemon's setup key would: a scenario's (its drift steps) or, for "
                          "a daemon log, the notices it logged")
    rep.add_argument("-o", "--output", help="write estimates and events to this MCAP")
    rep.add_argument("--report", help="directory for metrics.json and metrics.md")
    rep.add_argument("--streaming", action="store_true",
                     help="estimate sample by sample (slow; the batched path gives the same)")
    rep.add_argument("--adaptation", choices=["worker", "inline"], default="worker",
                     help="rounds in a forked worker (default; their nets serve "
                          "--result-delay s later) or inline at their sample")
    rep.add_argument("--result-delay", type=float, default=1.0,
                     help="worker: sample time from a round falling due to its net serving [s]")
    rep.set_defaults(func=_cmd_replay)

    cmp_ = sub.add_parser("compare", parents=[common],
                          help="several policies over several sessions: table and plots")
    cmp_.add_argument("--policies", default="gated,frozen,ungated",
                      help="comma-separated policy names")
    cmp_.add_argument("--sessions", nargs="+", required=True,
                      help="sessions (space- or comma-separated)")
    cmp_.add_argument("--out", required=True, help="output directory")
    cmp_.set_defaults(func=_cmd_compare)
