"""The disk budget of the log directory, on real files written by real McapLogs: the total
stays under it at every check, the oldest closed files go first, an open file never goes,
files that are no daemon log are left alone, and each removal is a notice for the daemon."""

import os
import time

import numpy as np
import pytest

from wrenchd.adapters.log_budget import LOG_FILE_NAME, LogBudgets
from wrenchd.adapters.mcap_log import TOPIC_ESTIMATE, LogConfig, McapLog, estimate_record
from wrenchd.adapters.mcap_session import TOPIC_JOINT_STATES
from wrenchd.adapters.messages import encode_joint_state
from wrenchd.models.errors import ConfigError
from wrenchd.models.series import JOINT_NAMES
from wrenchd.service.runtime.settings import load_settings

BUDGET = 60_000
TINY = {"rotate_mb": 0.02, "chunk_size": 4096, "max_total_bytes": BUDGET,
        "budget_check_s": 3600.0}                  # only rotations check, unless told


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def log_files(directory) -> dict[str, int]:
    return {p.name: p.stat().st_size for p in directory.iterdir()
            if p.is_file() and LOG_FILE_NAME.match(p.name)}


def write(logs: list[McapLog], budgets: LogBudgets, clock: Clock, start: int, n: int,
          after_check=None) -> None:
    """``n`` samples (a joint state and an estimate each) to every log at 200 Hz, ticking as
    the log writer process does; ``after_check()`` after every budget check."""
    rng = np.random.default_rng(start)
    for i in range(start, start + n):
        ns = int(i * 5e6)
        for log in logs:
            q = rng.normal(size=6)                   # noise: chunks that hardly compress
            log.write(TOPIC_JOINT_STATES, ns, encode_joint_state(
                "cdr", ns, JOINT_NAMES, q, rng.normal(size=6), rng.normal(size=6)))
            log.write(TOPIC_ESTIMATE, ns, estimate_record(ns, "psm_base", q, True, 0.5, 0,
                                                          False, rng.normal(size=6)))
        clock.now = (i + 1) / 200.0
        rotated = False
        for log in logs:
            rotated |= log.tick()
        if budgets.tick(rotated) and after_check is not None:
            after_check()


def test_the_budget_holds_after_every_rotation_and_the_open_files_survive(tmp_path):
    clock = Clock()
    # what an earlier run left (oldest), and what is no daemon log (never counted nor removed)
    earlier = tmp_path / "PSM1-20250101-000000-999-001.mcap"
    earlier.write_bytes(os.urandom(30_000))
    os.utime(earlier, (time.time() - 86400, time.time() - 86400))
    other = [tmp_path / "notes.mcap", tmp_path / "PSM1-copy.mcap", tmp_path / "models" /
             "PSM1-20250101-000000-999-002.mcap"]
    for path in other:
        path.parent.mkdir(exist_ok=True)
        path.write_bytes(os.urandom(50_000))
    logs = [McapLog(arm, LogConfig(directory=str(tmp_path), **TINY), clock=clock)
            for arm in ("PSM1", "PSM2")]
    budgets = LogBudgets(logs, clock=clock)
    checks = []

    def after_check():
        files = log_files(tmp_path)
        open_names = {log.open_path.name for log in logs if log.open_path is not None}
        assert open_names <= set(files)                    # the open files are still there
        checks.append(sum(files.values()))
        assert checks[-1] <= BUDGET, files
        # in use: what is on disk, and what the open files still buffer (at most a chunk)
        assert all(checks[-1] <= log.bytes_used <= checks[-1] + 2 * 8192 for log in logs), (
            checks[-1], [log.bytes_used for log in logs])

    write(logs, budgets, clock, 0, 1500, after_check)
    for log in logs:
        log.close()
    assert len(checks) >= 10                                  # a check per rotation
    assert not earlier.exists() and all(p.exists() for p in other)
    notices = {log.arm: list(log.removed) for log in logs}
    removed = [n for arm_notices in notices.values() for n in arm_notices]
    assert all(what == "removed" for what, _, _ in removed)
    # each arm is told of its own files; the earlier run's PSM1 file is PSM1's
    for arm, arm_notices in notices.items():
        assert arm_notices and all(os.path.basename(p).startswith(arm + "-")
                                   for _, p, _ in arm_notices)
    assert notices["PSM1"][0] == ("removed", str(earlier), 30_000)
    for _, path, size in removed:
        assert not os.path.exists(path) and size > 0
    # the oldest first: every file removed of an arm came before every file kept of it
    for log in logs:
        gone = {p for _, p, _ in notices[log.arm]}
        order = [str(p) for p in log.paths]
        kept = [i for i, p in enumerate(order) if p not in gone]
        assert kept and all(order.index(p) < kept[0] for p in gone if p in order)
        assert log.paths[-1].exists()                         # the newest is kept
    assert sum(log_files(tmp_path).values()) <= BUDGET + 2 * 20_000 + 8_000   # + the open ones


def test_the_budget_is_checked_periodically_between_rotations(tmp_path):
    clock = Clock()
    cfg = {**TINY, "rotate_mb": 0.05, "max_total_bytes": 100_000, "budget_check_s": 0.5}
    log = McapLog("PSM1", LogConfig(directory=str(tmp_path), **cfg), clock=clock)
    budgets = LogBudgets([log], clock=clock)
    seen = []
    write([log], budgets, clock, 0, 2000, lambda: seen.append(
        (clock.now, sum(log_files(tmp_path).values()), log.open_bytes, log.bytes_used)))
    log.close()
    assert len(seen) >= 2000 / 200 / 0.5 - 1                 # every 0.5 s of the clock
    assert all(total <= 100_000 for _, total, _, _ in seen)
    assert any(0 < open_bytes for _, _, open_bytes, _ in seen)   # checks with a file open
    # between checks the bytes in use follow the open file: closed at the check + open now
    budgets.refresh()
    assert log.bytes_used == sum(log_files(tmp_path).values())
    assert log.bytes_free is not None and log.bytes_free > 0


def test_without_a_budget_nothing_is_removed_and_the_total_is_counted(tmp_path):
    clock = Clock()
    cfg = {**TINY, "max_total_bytes": None}
    log = McapLog("PSM1", LogConfig(directory=str(tmp_path), **cfg), clock=clock)
    budgets = LogBudgets([log], clock=clock)
    write([log], budgets, clock, 0, 600)
    log.close()
    budgets.check()
    assert not log.removed and len(log.paths) >= 5
    assert all(p.exists() for p in log.paths)
    assert log.bytes_used == sum(log_files(tmp_path).values()) > BUDGET


def test_the_budget_settings_and_a_budget_smaller_than_one_file_is_refused(tmp_path,
                                                                          monkeypatch):
    with pytest.raises(ValueError, match=r"max_total_bytes \(1000000 B\) is smaller than one "
                                         r"file \(rotate_mb = 512 MB\)"):
        LogConfig(max_total_bytes=1_000_000)
    with pytest.raises(ConfigError, match="log.max_total_bytes"):
        load_settings(log={"max_total_bytes": 0})
    with pytest.raises(ConfigError, match="keep_checkpoints"):
        load_settings(keep_checkpoints=0)
    assert LogConfig().max_total_bytes is None and load_settings().keep_checkpoints is None
    path = tmp_path / "wrenchd.toml"
    path.write_text("keep_checkpoints = 20\n[log]\nmax_total_bytes = 20_000_000_000\n"
                    "rotate_mb = 256\n")
    settings = load_settings(path)
    assert (settings.log.max_total_bytes, settings.keep_checkpoints) == (20_000_000_000, 20)
    monkeypatch.setenv("WRENCHD_LOG__MAX_TOTAL_BYTES", "3000000000")
    monkeypatch.setenv("WRENCHD_KEEP_CHECKPOINTS", "5")
    settings = load_settings(path)
    assert (settings.log.max_total_bytes, settings.keep_checkpoints) == (3_000_000_000, 5)
