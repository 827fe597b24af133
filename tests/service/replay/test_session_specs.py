"""Session specs at the edge: ``concat:`` and ``inject:`` parsing, the refusals a user meets
(a bad count, a missing file, an empty list, a bad seed) and how ``compare --sessions`` splits
its arguments."""

from __future__ import annotations

import subprocess
import sys

import pytest

from wrenchd.models.errors import ConfigError
from wrenchd.service.replay.source import (load_session, parse_concat, parse_inject,
                                           split_sessions)


@pytest.fixture
def two_files(tmp_path):
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    a.write_text("")
    b.write_text("")
    return a, b


def test_concat_items_and_counts(two_files):
    a, b = two_files
    assert parse_concat(f"concat:{a}*6,{b}*2") == [(str(a), 6), (str(b), 2)]
    assert parse_concat(f"concat:{a}, {b} * 3") == [(str(a), 1), (str(b), 3)]


@pytest.mark.parametrize("tail, message", [
    ("", "names no recording"),
    (" , ", "names no recording"),
    ("{a}*0", "integer >= 1, got 0"),
    ("{a}*-2", "integer >= 1, got -2"),
    ("{a}*two", "integer >= 1, got 'two'"),
    ("{a}*", "integer >= 1, got ''"),
    ("{a},,{b}", "an empty recording between commas"),
    ("*3", "names no file"),
    ("{a},{a}.missing*2", "no such recording"),
])
def test_concat_refusals_name_the_problem(two_files, tail, message):
    a, b = two_files
    with pytest.raises(ConfigError, match=message):
        parse_concat("concat:" + tail.format(a=a, b=b))


def test_inject_seed_and_inner_session(two_files):
    a, b = two_files
    assert parse_inject(f"inject:5:concat:{a}*2,{b}") == (5, f"concat:{a}*2,{b}")
    for bad in ("inject:-1:x.csv", "inject:x:x.csv", "inject:1.5:x.csv", "inject::x.csv"):
        with pytest.raises(ConfigError, match="seed must be an integer >= 0"):
            parse_inject(bad)
    for bad in ("inject:3", "inject:3:", "inject:"):
        with pytest.raises(ConfigError, match="expected inject:SEED:SESSION"):
            parse_inject(bad)


def test_missing_files_and_directories_that_are_no_bag_are_refused(tmp_path):
    with pytest.raises(ConfigError, match="no such file or directory"):
        load_session(str(tmp_path / "nothing.csv"))
    with pytest.raises(ConfigError, match="without metadata.yaml"):
        load_session(str(tmp_path))
    (tmp_path / "x.txt").write_text("1")
    with pytest.raises(ConfigError, match="unknown recording type .txt"):
        load_session(f"concat:{tmp_path / 'x.txt'}")


def test_compare_sessions_split_on_commas_outside_a_concat_spec():
    assert split_sessions(["a.mcap,sim:trocar:10:2", "b.csv"]) == \
        ["a.mcap", "sim:trocar:10:2", "b.csv"]
    # a concat: spec (also inside inject:) runs to the end of its argument
    assert split_sessions(["x.csv,inject:3:concat:a.csv*4,b.csv*4", "concat:c.csv,d.csv"]) == \
        ["x.csv", "inject:3:concat:a.csv*4,b.csv*4", "concat:c.csv,d.csv"]
    with pytest.raises(ConfigError, match="no session"):
        split_sessions([" , "])


def test_the_cli_says_what_is_wrong_without_a_traceback(tmp_path):
    done = subprocess.run([sys.executable, "-m", "wrenchd", "replay",
                           f"concat:{tmp_path / 'gone.csv'}*2"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert "no such recording" in done.stderr and "Traceback" not in done.stderr
