"""Helpers for tests that run real processes: loopback ports, bounded waits, daemon configs,
bounded reads of a child's output, and the topics of an MCAP log.

Every wait here has a deadline. A child that does not answer in time is killed and the test
fails with an AssertionError naming what it waited for and the tail of the child's stderr, so
that no test can hang CI on a silent subprocess.
"""

from __future__ import annotations

import signal
import socket
import subprocess
import threading
import time
from pathlib import Path

#: A zenoh router as a Python process (the zenoh wheel ships no ``zenohd``): it listens on the
#: endpoint given as its argument, prints ``ready`` and runs until its stdin is closed.
ROUTER = """
import json, sys, zenoh
conf = zenoh.Config()
conf.insert_json5("mode", '"router"')
conf.insert_json5("listen/endpoints", json.dumps([sys.argv[1]]))
conf.insert_json5("scouting/multicast/enabled", "false")
session = zenoh.open(conf)
print("ready", flush=True)
sys.stdin.read()             # until the test closes stdin (or kills this process)
session.close()
"""

#: how much of a child's stderr an assertion message quotes [characters]
STDERR_TAIL = 2000


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for(predicate, timeout: float, what: str) -> None:
    """Poll ``predicate`` every 50 ms; AssertionError naming ``what`` after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def write_config(path: Path, endpoint: str, encoding: str, log_dir: Path,
                 arms: tuple[str, ...] = ("PSM2",), model: str | None = None,
                 express: bool | None = None) -> Path:
    """An external-robot daemon config listening on ``endpoint``; each arm calibrates 2 s and
    serves ``model`` (default: the settings' default step 1), its wrenches ``express`` or
    not (default: the settings')."""
    text = f"""
robot = "external"
[zenoh]
listen = ["{endpoint}"]
[log]
directory = "{log_dir}"
"""
    for arm in arms:
        text += f"""[[arms]]
name = "{arm}"
encoding = "{encoding}"
{f'model = "{model}"' if model else ""}
{f'express = {str(express).lower()}' if express is not None else ""}
[arms.pipeline]
calibration_s = 2.0
"""
    path.write_text(text)
    return path


def children_of(pid: int) -> list[int]:
    """The child processes of ``pid`` (Linux /proc)."""
    return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]


def read_mcap(path: Path) -> dict[str, list[bytes]]:
    """Every message of an MCAP file, by topic, in file order, as JSON text: a JSON log's
    message as stored; of a ROS 2 (CDR) log, an event's or status's JSON, any other
    message's fields (:func:`wrenchd.adapters.mcap_log.message_fields`)."""
    import orjson
    from mcap.reader import make_reader

    from wrenchd.adapters.mcap_log import message_fields

    out: dict[str, list[bytes]] = {}
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            data = message.data
            if channel.message_encoding != "json":
                data = orjson.dumps(message_fields(channel.message_encoding, schema.name, data,
                                                   schema.data))
            out.setdefault(channel.topic, []).append(data)
    return out


def _kill_and_stderr(proc: subprocess.Popen) -> str:
    """Kill ``proc`` and return the tail of its stderr, giving up after a few seconds (a
    grandchild that inherited the pipes may keep them open)."""
    if proc.poll() is None:
        proc.kill()
    try:
        _, err = proc.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        return "(its pipes stayed open 10 s after SIGKILL: a child of it holds them)"
    except ValueError:                      # its pipes were already read to the end
        return ""
    if isinstance(err, bytes):
        err = err.decode(errors="replace")
    return (err or "")[-STDERR_TAIL:]


def readline_within(proc: subprocess.Popen, timeout: float, what: str) -> str:
    """The next line of ``proc``'s stdout (text mode), waiting at most ``timeout`` seconds.

    The line is read on a helper thread through the pipe's own buffered reader, so lines
    the child printed together are all seen, one per call. When no line comes in time, or the
    child closes its stdout first, the child is killed and AssertionError says so, with the
    tail of its stderr.
    """
    box: list[str] = []
    reader = threading.Thread(target=lambda: box.append(proc.stdout.readline()), daemon=True)
    reader.start()
    reader.join(timeout)
    if reader.is_alive():
        err = _kill_and_stderr(proc)
        raise AssertionError(f"no line from {what} within {timeout} s; killed it. "
                             f"stderr:\n{err}")
    line = box[0]
    if not line:
        try:
            rc = proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            rc = None
        err = _kill_and_stderr(proc)
        raise AssertionError(f"{what} closed its output (rc {rc}) before printing a line. "
                             f"stderr:\n{err}")
    return line


def expect_line(proc: subprocess.Popen, text: str, timeout: float, what: str) -> str:
    """The next line of ``proc``'s stdout, which must contain ``text``; otherwise the child
    is killed and AssertionError quotes the line and its stderr."""
    line = readline_within(proc, timeout, what)
    if text not in line:
        err = _kill_and_stderr(proc)
        raise AssertionError(f"{what} printed {line!r}, expected a line with {text!r}. "
                             f"stderr:\n{err}")
    return line


def stop_within(proc: subprocess.Popen, timeout: float, what: str,
                sig: int = signal.SIGINT) -> tuple[str, str]:
    """Send ``sig`` to ``proc`` (if it still runs) and collect its output within ``timeout``
    seconds: ``(stdout, stderr)``. A child that does not stop in time is killed and
    AssertionError says so."""
    if proc.poll() is None:
        proc.send_signal(sig)
    try:
        return proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        err = _kill_and_stderr(proc)
        raise AssertionError(f"{what} did not stop within {timeout} s of signal {sig}; "
                             f"killed it. stderr:\n{err}") from None


def communicate_within(proc: subprocess.Popen, timeout: float, what: str) -> tuple[str, str]:
    """``proc.communicate()`` within ``timeout`` seconds, for a child that ends on its own; a
    child still running then is killed and AssertionError says so."""
    try:
        return proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        err = _kill_and_stderr(proc)
        raise AssertionError(f"{what} did not finish within {timeout} s; killed it. "
                             f"stderr:\n{err}") from None


#: A lab's wall-clock stamps (ns) for recordings written in the tests.
LAB_EPOCH_NS = 1_764_000_000_000_000_000


def ros2_bag_from(js, path: Path, topic: str = "/PSM1/measured_js") -> Path:
    """A rosbag2 directory (MCAP storage) written by rosbags alone, as a dVRK ROS 2 system
    records ``measured_js``."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore
    from wrenchd.models.series import JOINT_NAMES

    store = get_typestore(Stores.ROS2_HUMBLE)
    t, js_type = store.types, "sensor_msgs/msg/JointState"
    with Writer(path, version=9) as writer:
        conn = writer.add_connection(topic, js_type, typestore=store)
        for i in range(len(js)):
            stamp = LAB_EPOCH_NS + round(js.t[i] * 1e9)
            msg = t[js_type](header=t["std_msgs/msg/Header"](
                stamp=t["builtin_interfaces/msg/Time"](sec=stamp // 10**9,
                                                       nanosec=stamp % 10**9), frame_id=""),
                name=list(JOINT_NAMES), position=js.position[i], velocity=js.velocity[i],
                effort=js.effort[i])
            writer.write(conn, stamp, store.serialize_cdr(msg, js_type))
    return path
