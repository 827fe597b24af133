"""Several policies over several sessions: a side-by-side table and error-over-time plots.

Each session (any form :func:`~wrenchd.service.replay.source.load_session` takes) is loaded
once and every policy replays it from the same start (same step-1 model, same seed). Each row
carries the session's ``setup_changes`` (free-motion tip force around each set-up change,
:mod:`wrenchd.service.replay.events_scored`). Written to ``out_dir``: ``compare.json`` (every replay's metrics and provenance),
``compare.md`` (the table) and one ``<session>.png`` per session with truth: the free-motion
force error over time (1 s bins, top) and the contact force error (bottom), one line per
policy, set-up changes as dashed lines and true contacts shaded.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from wrenchd.models.estimator.free_space import FreeSpaceModel
from wrenchd.models.series import Session
from wrenchd.service.pipeline import PipelineConfig
from wrenchd.service.provenance import RunMeter, stamp
from wrenchd.service.replay.policies import get_policy
from wrenchd.service.replay.loop import replay
from wrenchd.service.replay.detector import detector_table
from wrenchd.service.replay.metrics import free_error_series, replay_metrics, true_runs
from wrenchd.service.replay.output import nan_to_none
from wrenchd.models.physics.effects.drift import drift_onsets
from wrenchd.service.replay.source import announced_changes, load_session


def _slug(spec: str) -> str:
    if spec.startswith("sim:"):
        spec = spec[4:]
    else:                                   # every path in the spec by its name alone
        spec = re.sub(r"[^,:*]*/(?=[^/,:*]+)", "", spec.rstrip("/"))
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", spec).strip("_")


def _get(m: dict, *keys) -> Any:
    for k in keys:
        if not isinstance(m, dict) or k not in m:
            return None
        m = m[k]
    return m


def _cell(x: Any) -> str:
    return "n/a" if x is None else (f"{x:.3g}" if isinstance(x, float) else str(x))


def table_markdown(rows: list[dict[str, Any]]) -> str:
    head = ("| session | policy | free-motion force err. after change [N] | recovery [s] | "
            "contact force RMSE [N] (truth) | vs sensor [N] | false force mean [N] | "
            "gate precision | gate recall | contaminated offers | contacts > 2 N found | "
            "set-up change: tip force before / after [N] (ratio) | final version |")
    out = [head, "|" + "---|" * 13]
    for m in rows:
        d = (m.get("drifts") or [{}])[0]
        c = m.get("contamination") or {}
        f = m.get("contacts_found") or {}
        sc = (m.get("setup_changes") or [{}])[0]
        out.append("| " + " | ".join([
            m["session"], m["policy"], _cell(d.get("free_force_error_after_N")),
            _cell(d.get("recovery_s")), _cell(_get(m, "truth", "force_rmse_N", "contact")),
            _cell(_get(m, "sensor", "force_rmse_N", "contact")),
            _cell(_get(m, "false_force_N", "mean")), _cell(_get(m, "gate", "precision")),
            _cell(_get(m, "gate", "recall")),
            f"{c.get('in_contact', 'n/a')}/{c.get('offered', 'n/a')} "
            f"({c.get('in_contact_after_calibration', 'n/a')} after calibration)",
            f"{f.get('found', 'n/a')}/{f.get('episodes', 'n/a')}",
            f"{_cell(sc.get('before_N'))} / {_cell(sc.get('after_N'))} "
            f"({_cell(sc.get('ratio'))})",
            str(m["final_model_version"])]) + " |")
    return "\n".join(out) + "\n"


def plot_session(path: Path, title: str, session: Session, series: dict[str, dict]) -> None:
    """Error over time per policy, changes and contacts marked (matplotlib Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(11, 6.5), sharex=True)
    truth = session.truth
    t = session.joint_states.t
    for ax in axes:
        if truth is not None and truth.in_contact.any():
            for a, b in zip(*true_runs(truth.in_contact)):
                ax.axvspan(t[a], t[b - 1], color="0.85", lw=0)
        for name, start, end in drift_onsets(session):
            ax.axvline(start, color="k", ls="--", lw=1)
            if end is not None:
                ax.axvline(end, color="k", ls=":", lw=1)
    for policy, s in series.items():
        axes[0].plot(s["t"], s["free"], lw=1, label=policy)
        axes[1].plot(s["t"], s["contact"], lw=1, marker=".", ms=2, label=policy)
    axes[0].set_ylabel("free-motion |F err| [N]")
    axes[1].set_ylabel("contact |F err| [N]")
    axes[1].set_xlabel("t [s] (grey: true contact; dashed: set-up change)")
    axes[0].set_title(title)
    axes[0].legend(loc="upper left", fontsize=8, ncol=5)
    axes[0].set_yscale("log")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def run_compare(policies: list[str], sessions: list[str], out_dir: str | Path,
                free_space: FreeSpaceModel, base: PipelineConfig | None = None,
                log=print, announce: bool = False) -> list[dict[str, Any]]:
    """Replay every policy on every session; write the table, JSON and plots; the rows.
    ``announce``: tell the pipeline of each session's set-up changes at their time
    (:func:`~wrenchd.service.replay.source.announced_changes`), as the daemon's setup key
    would."""
    base = base if base is not None else PipelineConfig()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    configs = {p: get_policy(p).configure(base) for p in policies}     # fail early
    for spec in sessions:
        session = load_session(spec)
        changes = announced_changes(session) if announce else ()
        series = {}
        for policy in policies:
            meter = RunMeter()
            r = replay(session, free_space, configs[policy], policy=policy,
                       setup_changes=changes)
            m = replay_metrics(r, session)
            m["session"] = spec
            m["announced"] = bool(announce)
            stamp(m, run=meter)                  # where this replay's numbers came from
            rows.append(m)
            series[policy] = free_error_series(r, session)
            d = (m.get("drifts") or [{}])[0]
            sc = (m.get("setup_changes") or [{}])[0]
            log(f"{spec} {policy}: {len(r.t)} samples in {r.wall_s:.1f} s; free err after "
                f"change {_cell(d.get('free_force_error_after_N'))} N, contact RMSE "
                f"{_cell(_get(m, 'truth', 'force_rmse_N', 'contact'))} N, set-up change "
                f"ratio {_cell(sc.get('ratio'))}")
        if session.truth is not None:
            plot_session(out / f"{_slug(spec)}.png", spec, session, series)
    (out / "compare.json").write_text(json.dumps(nan_to_none(rows), indent=1, default=str) + "\n")
    (out / "compare.md").write_text(table_markdown(rows) + "\n## The gate as a detector\n\n"
                                    + detector_table(rows))
    return rows
