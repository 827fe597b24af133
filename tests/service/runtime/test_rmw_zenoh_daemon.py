"""A real ``wrenchd serve`` (external robot) as a ROS 2 node over rmw_zenoh, driven by this
test's own publisher speaking what rmw_zenoh puts on the wire, read by this test's own
subscriber; every key, attachment and token is built and parsed here from rmw_zenoh's design
document (ros2/rmw_zenoh ``docs/design.md``), not with wrenchd's module.

One daemon serves two arms for all tests of this module:

* PSM1, ``keys = "rmw_zenoh"`` in ROS domain 17: JointState CDR on
  ``17/PSM1/measured_js/sensor_msgs::msg::dds_::JointState_/RIHS01_...`` with an attachment
  on every sample and no zenoh encoding (as rmw_zenoh publishes), stamped with the wall
  clock (``time.time_ns()``, real epoch stamps);
* PSM2, JSON with wrenchd's keys: unmarked JSON samples, then CDR samples marked
  ``application/cdr`` (decoded as CDR), then one marked ``image/png`` (refused);
* PSM3, ``keys = "ros2dds"``: unmarked CDR on ``PSM3/measured_js``, as zenoh-bridge-ros2dds
  maps the ROS topic ``/PSM3/measured_js``; wrenches on ``PSM3/wrenchd/measured_cf``.
"""

from __future__ import annotations

import json
import re
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import orjson
import pytest
import xxhash
import zenoh
from mcap.reader import make_reader
from rosbags.typesys import Stores, get_typestore

from wrenchd.adapters.sim.scenarios import run_scenario
from wrenchd.adapters.sim.simulator import SimulatorConfig
from tests.support import free_port, readline_within, stop_within, wait_for

DOMAIN = 17
JS_HASH = "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"
WRENCH_HASH = "RIHS01_8dc3deaf06b2ab281f9f9a742a8961c328ca7cec16e3fd6586d3a5c83fa78f77"
# <domain_id>/<fully qualified name>/<type name>/<type hash>, the design document's mapping
JS_KEY = f"{DOMAIN}/PSM1/measured_js/sensor_msgs::msg::dds_::JointState_/{JS_HASH}"
WRENCH_KEY = (f"{DOMAIN}/PSM1/wrenchd/measured_cf/geometry_msgs::msg::dds_::WrenchStamped_/"
              f"{WRENCH_HASH}")
QOS = "::,10:,:,:,,"          # reliable, volatile, keep last 10: all else rmw_zenoh's default
SECONDS = 10.0                # of PSM1 samples at 200 Hz
PSM2_SAMPLES = 60             # half JSON unmarked, half CDR marked, then one bad sample
STORE = get_typestore(Stores.ROS2_JAZZY)
T = STORE.types


def cdr_joint_state(stamp_ns: int, names, position, velocity, effort) -> bytes:
    msg = T["sensor_msgs/msg/JointState"](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
            sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9), frame_id=""),
        name=list(names), position=np.asarray(position, float),
        velocity=np.asarray(velocity, float), effort=np.asarray(effort, float))
    return bytes(STORE.serialize_cdr(msg, "sensor_msgs/msg/JointState"))


def json_joint_state(stamp_ns: int, names, position, velocity, effort) -> bytes:
    return orjson.dumps({"header": {"stamp": {"sec": stamp_ns // 10**9,
                                              "nanosec": stamp_ns % 10**9}, "frame_id": ""},
                         "name": list(names), "position": list(map(float, position)),
                         "velocity": list(map(float, velocity)),
                         "effort": list(map(float, effort))})


def attachment(seq: int, stamp_ns: int, gid: bytes) -> bytes:
    """int64 LE sequence number, int64 LE timestamp [ns], GID length (1 byte), GID."""
    return struct.pack("<qqB", seq, stamp_ns, len(gid)) + gid


def parse_attachment(raw: bytes) -> tuple[int, int, bytes]:
    assert len(raw) == 33, len(raw)
    seq, stamp, size = struct.unpack_from("<qqB", raw)
    assert size == 16
    return seq, stamp, raw[17:]


def mcap_event_times(log_dir: Path, arm: str) -> list[int]:
    """log_time [ns] of every record on the events channel of ``arm``'s log files."""
    times = []
    for path in sorted(log_dir.glob(f"{arm}-*.mcap")):
        with open(path, "rb") as f:
            for _s, _c, message in make_reader(f).iter_messages(topics=["/wrenchd/events"]):
                times.append(message.log_time)
    return times


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("rmw")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = tmp / "wrenchd.toml"
    config.write_text(f"""
robot = "external"
[zenoh]
listen = ["{endpoint}"]
[log]
directory = "{tmp / 'logs'}"
[ros]
domain_id = {DOMAIN}
[[arms]]
name = "PSM1"
keys = "rmw_zenoh"
[arms.pipeline]
calibration_s = 2.0
[arms.pipeline.adaptation]
min_train_samples = 200
[[arms]]
name = "PSM2"
encoding = "json"
[[arms]]
name = "PSM3"
keys = "ros2dds"
""")
    js = run_scenario("trocar", SECONDS, 5, config=SimulatorConfig(publish_rate_hz=200.0),
                      contact_free_s=60.0).joint_states
    daemon = subprocess.Popen([sys.executable, "-m", "wrenchd", "serve", "--config",
                               str(config)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True)
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = None
    got: dict[str, list] = {"wrench": [], "events": [], "psm2": [], "psm3": []}
    lock = threading.Lock()

    def keep(name):
        def on_sample(sample):
            att = sample.attachment
            with lock:
                got[name].append((sample.payload.to_bytes(), str(sample.encoding),
                                  None if att is None else att.to_bytes()))
        return on_sample

    try:
        lines = [readline_within(daemon, 180.0, "the daemon") for _ in range(3)]
        assert JS_KEY in lines[0] and WRENCH_KEY in lines[0], lines
        session = zenoh.open(conf)
        subs = [session.declare_subscriber(WRENCH_KEY, keep("wrench")),
                session.declare_subscriber("dvrk/*/wrenchd/events", keep("events")),
                session.declare_subscriber("dvrk/PSM2/wrenchd/measured_cf", keep("psm2")),
                session.declare_subscriber("PSM3/wrenchd/measured_cf", keep("psm3"))]
        pub = session.declare_publisher(JS_KEY)          # no encoding, like rmw_zenoh
        pub2 = session.declare_publisher("dvrk/PSM2/measured_js")
        pub3 = session.declare_publisher("PSM3/measured_js")
        wait_for(lambda: all(p.matching_status.matching for p in (pub, pub2, pub3)),
                 30.0, "the daemon's subscribers")
        time.sleep(0.5)                                   # our subscribers' routes too
        gid = bytes(range(200, 216))                      # this publisher's (any 16 bytes)
        t0_ns = time.time_ns()
        start = time.monotonic()
        stamps = []
        for i in range(len(js)):
            delay = start + js.t[i] - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            stamp = t0_ns + int(round(js.t[i] * 1e9))
            stamps.append(stamp)
            row = (js.names, js.position[i], js.velocity[i], js.effort[i])
            pub.put(cdr_joint_state(stamp, *row), attachment=attachment(i + 1, time.time_ns(),
                                                                         gid))
            if i < PSM2_SAMPLES:
                pub3.put(cdr_joint_state(stamp, *row))
            if i < PSM2_SAMPLES // 2:
                pub2.put(json_joint_state(stamp, *row))
            elif i < PSM2_SAMPLES:
                pub2.put(cdr_joint_state(stamp, *row), encoding=zenoh.Encoding.APPLICATION_CDR)
            elif i == PSM2_SAMPLES:
                pub2.put(json_joint_state(stamp, *row), encoding=zenoh.Encoding.IMAGE_PNG)
        wait_for(lambda: len(got["wrench"]) >= len(js) - 5, 60.0, "the last wrenches")
        time.sleep(1.0)
        tokens = [str(r.ok.key_expr) for r in
                  session.liveliness().get(f"@ros2_lv/{DOMAIN}/**", timeout=5.0)
                  if r.ok is not None]
        status = [json.loads(r.ok.payload.to_bytes()) | {"_encoding": str(r.ok.encoding)}
                  for r in session.get("dvrk/PSM2/wrenchd/status", timeout=5.0)
                  if r.ok is not None]
        end_ns = time.time_ns()
        for sub in subs:
            sub.undeclare()
        out, err = stop_within(daemon, 120.0, "the daemon")
        assert daemon.returncode == 0, err
    finally:
        if daemon.poll() is None:
            daemon.kill()
            daemon.communicate(timeout=30)
        if session is not None:
            session.close()
    return {"got": got, "stamps": stamps, "tokens": tokens, "status": status,
            "t0_ns": t0_ns, "end_ns": end_ns, "logs": tmp / "logs", "n": len(js)}


def test_every_wrench_is_a_wrenchstamped_of_a_published_sample(run):
    wrenches = run["got"]["wrench"]
    assert len(wrenches) >= run["n"] - 5
    published = set(run["stamps"])
    for payload, encoding, _ in wrenches:
        msg = STORE.deserialize_cdr(payload, "geometry_msgs/msg/WrenchStamped")
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        assert stamp in published
        assert msg.header.frame_id == "psm_base"
        assert encoding.split(";")[0] == "application/cdr"
        force = [msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z]
        assert np.isfinite(force).all()


def test_every_wrench_carries_rmw_zenohs_attachment(run):
    parsed = [parse_attachment(att) for _, _, att in run["got"]["wrench"]]
    seqs = [p[0] for p in parsed]
    assert seqs == list(range(1, len(seqs) + 1))          # from 1, none skipped, in order
    times = [p[1] for p in parsed]
    assert run["t0_ns"] <= times[0] and times[-1] <= run["end_ns"]
    assert all(a <= b for a, b in zip(times, times[1:]))
    gids = {p[2] for p in parsed}
    assert len(gids) == 1
    publisher = [t for t in run["tokens"] if t.split("/")[5] == "MP"]
    assert len(publisher) == 1
    digest = xxhash.xxh3_128_intdigest(publisher[0].encode())   # GID: XXH3-128 of the token
    assert gids == {digest.to_bytes(16, "little")}


def test_liveliness_tokens_of_the_node_its_subscription_and_publisher(run):
    parts = sorted((t.split("/") for t in run["tokens"]), key=lambda p: p[5])
    assert [p[5] for p in parts] == ["MP", "MS", "NN"], run["tokens"]
    zids = {p[2] for p in parts}
    assert len(zids) == 1 and re.fullmatch(r"[0-9a-f]{1,32}", zids.pop())
    mp, ms, nn = parts
    assert nn[:2] == ["@ros2_lv", str(DOMAIN)]
    assert nn[3:] == ["0", "0", "NN", "%", "%", "wrenchd"]
    for token, kind, topic, typename, digest in (
            (ms, "MS", "%PSM1%measured_js", "sensor_msgs::msg::dds_::JointState_", JS_HASH),
            (mp, "MP", "%PSM1%wrenchd%measured_cf", "geometry_msgs::msg::dds_::WrenchStamped_",
             WRENCH_HASH)):
        assert token[:2] == ["@ros2_lv", str(DOMAIN)] and token[3] == "0"
        assert token[5:] == [kind, "%", "%", "wrenchd", topic, typename, digest, QOS]
    assert {ms[4], mp[4]} == {"1", "2"}                    # entities of node 0


def test_json_arm_honours_the_samples_encoding(run):
    psm2 = run["got"]["psm2"]
    assert len(psm2) == PSM2_SAMPLES                     # JSON and CDR-marked samples alike
    for payload, encoding, _ in psm2:
        assert encoding.split(";")[0] == "application/json"
        assert json.loads(payload)["header"]["stamp"]["sec"] >= run["t0_ns"] // 10**9
    refusals = [json.loads(p) for p, _, _ in run["got"]["events"]
                if json.loads(p)["kind"] == "error" and json.loads(p)["arm"] == "PSM2"]
    assert len(refusals) == 1
    assert refusals[0]["error"] == "decode" and "image/png" in refusals[0]["reason"]
    assert "neither JSON nor CDR" in refusals[0]["reason"]
    [status] = run["status"]
    assert status["_encoding"].split(";")[0] == "application/json"
    assert status["counters"]["received"] == PSM2_SAMPLES + 1
    assert status["counters"]["error_kinds"] == {"decode": 1}


def test_events_are_json_on_the_arms_clock(run):
    low, high = run["t0_ns"] / 1e9 - 1.0, run["stamps"][-1] / 1e9 + 1.0
    events = [(json.loads(p), enc) for p, enc, _ in run["got"]["events"]]
    kinds = {e["kind"] for e, _ in events}
    assert {"calibrating", "calibrated", "round"} <= kinds, kinds
    for event, encoding in events:
        assert encoding.split(";")[0] == "application/json"
        assert low <= event["t"] <= high, event
    rounds = [e["t"] for e, _ in events if e["kind"] in ("round", "model")]
    assert rounds and min(rounds) >= run["stamps"][0] / 1e9
    logged = mcap_event_times(run["logs"], "PSM1")
    assert len(logged) >= len([e for e, _ in events if e["arm"] == "PSM1"])
    assert all(low * 1e9 <= t <= high * 1e9 for t in logged)


def test_ros2dds_arm_takes_the_bridges_keys(run):
    psm3 = run["got"]["psm3"]
    assert len(psm3) == PSM2_SAMPLES
    stamps = set(run["stamps"][:PSM2_SAMPLES])
    for payload, encoding, att in psm3:
        msg = STORE.deserialize_cdr(payload, "geometry_msgs/msg/WrenchStamped")
        assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec in stamps
        assert encoding.split(";")[0] == "application/cdr" and att is None
