"""The daemon's stop under bursts of stop signals, measured (a benchmark, not a test).

Each try starts ``wrenchd serve`` on its embedded default (simulated PSM, its own log directory
and loopback port), waits for its first status line, waits a random 0-1 s more, then sends the
process group SIGINT and, ``U(0, max_gap_us)`` later (a busy wait), SIGTERM: the two signals of
a process-group stop arriving close together. A try passes when the daemon exits 0 within
``hang_s``, and every MCAP file it wrote has its summary (finished, not truncated).

    python -m wrenchd.service.bench.stop_signals --tries 200 --json bench/stop-signals.json
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _finished(path: Path) -> bool:
    """Whether an MCAP file ends with its summary and footer (a finished file)."""
    from mcap.reader import make_reader

    try:
        with path.open("rb") as f:
            return make_reader(f).get_summary() is not None
    except Exception:  # noqa: BLE001 - a truncated file is the finding, not an error
        return False


def one_try(rng: random.Random, max_gap_us: float, hang_s: float) -> dict:
    with tempfile.TemporaryDirectory(prefix="wrenchd-stop-") as tmp:
        env = dict(os.environ, WRENCHD_LOG__DIRECTORY=tmp,
                   WRENCHD_ZENOH__LISTEN=json.dumps([f"tcp/127.0.0.1:{_free_port()}"]))
        t0 = time.monotonic()
        proc = subprocess.Popen([sys.executable, "-m", "wrenchd", "serve", "--duration", "300"],
                                env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True, start_new_session=True)
        for line in proc.stdout:                  # the first status line: serving
            if " Hz " in line:
                break
        started_s = time.monotonic() - t0
        time.sleep(rng.uniform(0.0, 1.0))
        gap_s = rng.uniform(0.0, max_gap_us * 1e-6)
        sent = time.monotonic()
        os.killpg(proc.pid, signal.SIGINT)
        until = time.perf_counter() + gap_s
        while time.perf_counter() < until:
            pass
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            out, _ = proc.communicate(timeout=hang_s)
            hung = False
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            out, _ = proc.communicate()
            hung = True
        stop_s = time.monotonic() - sent
        logs = sorted(Path(tmp).rglob("*.mcap"))
        unfinished = [p.name for p in logs if not _finished(p)]
        return {"gap_us": gap_s * 1e6, "start_s": started_s, "stop_s": stop_s, "hung": hung,
                "rc": proc.returncode, "logs": len(logs), "unfinished": unfinished,
                "tail": out[-300:] if hung or proc.returncode or unfinished else ""}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m wrenchd.service.bench.stop_signals",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--tries", type=int, default=200)
    parser.add_argument("--max-gap-us", type=float, default=200.0)
    parser.add_argument("--hang-s", type=float, default=30.0,
                        help="a daemon still running this long after the signals has hung")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", help="write the result here")
    args = parser.parse_args(argv)
    rng = random.Random(args.seed)
    tries = []
    for k in range(args.tries):
        tries.append(one_try(rng, args.max_gap_us, args.hang_s))
        t = tries[-1]
        print(f"try {k + 1}/{args.tries}: gap {t['gap_us']:6.1f} us  stop {t['stop_s']:.3f} s  "
              f"rc {t['rc']}  logs {t['logs']} ({len(t['unfinished'])} unfinished)"
              f"{'  HUNG' if t['hung'] else ''}", flush=True)
    stop = np.array([t["stop_s"] for t in tries])
    result = {
        "tries": len(tries), "max_gap_us": args.max_gap_us, "seed": args.seed,
        "hangs": sum(t["hung"] for t in tries),
        "nonzero_exit": sum(t["rc"] != 0 for t in tries),
        "unfinished_logs": sum(len(t["unfinished"]) for t in tries),
        "logs_checked": sum(t["logs"] for t in tries),
        "stop_s": {"min": float(stop.min()), "p50": float(np.median(stop)),
                   "p99": float(np.quantile(stop, 0.99)), "max": float(stop.max())},
        "over_1s": int((stop > 1.0).sum()),
        "loadavg": os.getloadavg(),
        "failures": [t for t in tries if t["hung"] or t["rc"] or t["unfinished"]],
    }
    text = json.dumps(result, indent=1)
    print(text)
    if args.json:
        Path(args.json).write_text(text + "\n")
    return 0 if not result["failures"] and not result["over_1s"] else 1


if __name__ == "__main__":
    sys.exit(main())
