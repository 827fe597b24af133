"""zenoh's own configuration passed through ZenohConfig: a key or a file takes effect in a real
session (seen by another process), the layers keep their order, and bad input is a ConfigError
naming the file, field or key."""

from __future__ import annotations

import json
import subprocess
import sys
import threading

import pytest
import zenoh

from wrenchd.adapters.zenoh_config import ZenohConfig, has_endpoints, zenoh_config
from wrenchd.adapters.zenoh_io import open_session
from wrenchd.models.errors import ConfigError
from wrenchd.service.runtime.settings import load_settings
from tests.support import communicate_within, free_port

#: a client in its own process: opens a session to the endpoint in argv[1] (failing at once
#: without an answer), puts argv[2] on "zc/test" and prints "sent"; else prints "refused"
CLIENT = """
import json, sys, zenoh
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
try:
    session = zenoh.open(conf)
except zenoh.ZError:
    print("refused", flush=True)
    sys.exit(0)
try:
    publisher = session.declare_publisher("zc/test")
    for _ in range(500):                       # the route to the subscriber is not instant
        if publisher.matching_status.matching:
            break
        __import__("time").sleep(0.01)
    publisher.put(sys.argv[2])
    print("sent", flush=True)
finally:
    session.close()
"""


def client_puts(endpoint: str, text: str) -> str:
    """What a client process says after trying to put ``text`` through ``endpoint``."""
    proc = subprocess.Popen([sys.executable, "-c", CLIENT, endpoint, text],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out, err = communicate_within(proc, 60.0, "the zenoh client")
    assert proc.returncode == 0, err
    return out.strip()


def received_through(config: ZenohConfig, endpoint: str) -> tuple[str, list[str]]:
    """Open a session with ``config``, let a client process put through ``endpoint``; what the
    client said and what this session's subscriber got."""
    got: list[str] = []
    arrived = threading.Event()

    def on_sample(sample) -> None:
        got.append(sample.payload.to_string())
        arrived.set()

    session = open_session(config)
    try:
        sub = session.declare_subscriber("zc/test", on_sample)
        try:
            said = client_puts(endpoint, "hello")
            if said == "sent":
                arrived.wait(10.0)
        finally:
            sub.undeclare()
    finally:
        session.close()
    return said, got


def get(conf, key: str):
    return json.loads(conf.get_json(key))


def test_a_key_passed_through_sets_the_session_id():
    session = open_session(ZenohConfig(config={"id": "5eed1234"}))
    try:
        assert str(session.info.zid()) == "5eed1234"
    finally:
        session.close()


def test_a_listen_key_wins_over_the_listen_field_in_a_real_session():
    field, key = (f"tcp/127.0.0.1:{free_port()}" for _ in range(2))
    config = ZenohConfig(listen=[field], config={"listen/endpoints": [key]})
    said, got = received_through(config, key)
    assert said == "sent" and got == ["hello"]
    said, got = received_through(config, field)
    assert said == "refused" and got == []


def test_a_config_file_is_loaded_and_the_layers_keep_their_order(tmp_path):
    """zenoh's defaults < the file < wrenchd's fields that are set < the key table."""
    file_ep, field_ep, key_ep = (f"tcp/127.0.0.1:{free_port()}" for _ in range(3))
    path = tmp_path / "zenoh.json5"
    path.write_text(f"""// a file zenoh's own tools take
{{
  id: "f11e",
  mode: "peer",
  listen: {{ endpoints: ["{file_ep}"] }},
  connect: {{ retry: {{ period_max_ms: 3000 }} }},
  scouting: {{ multicast: {{ enabled: false }}, gossip: {{ enabled: false }} }},
  adminspace: {{ enabled: true }},
}}
""")
    only_file = ZenohConfig(config_file=str(path))
    conf = only_file.to_zenoh()
    assert get(conf, "id") == "f11e" and get(conf, "adminspace/enabled") is True
    assert get(conf, "listen/endpoints") == [file_ep]
    # retry periods the file leaves unset take wrenchd's defaults, its own stays
    assert get(conf, "connect/retry") == {"period_init_ms": 250, "period_max_ms": 3000,
                                          "period_increase_factor": 2.0}
    # unset fields are shown as unset: the file's values stand
    assert only_file.mode is None and only_file.multicast_scouting is None

    layered = ZenohConfig(config_file=str(path), listen=[field_ep], retry_period_max_ms=500,
                          config={"id": "7ab1e"})
    conf = layered.to_zenoh()
    assert get(conf, "listen/endpoints") == [field_ep]                 # field over file
    assert get(conf, "connect/retry")["period_max_ms"] == 500
    assert get(conf, "id") == "7ab1e" and get(conf, "adminspace/enabled") is True

    top = layered.model_copy(update={"config": {"id": "7ab1e", "listen/endpoints": [key_ep]}})
    assert get(top.to_zenoh(), "listen/endpoints") == [key_ep]        # key over field

    # and in real sessions: the file's id, then the key table's; the file's endpoint serves
    session = open_session(only_file)
    try:
        assert str(session.info.zid()) == "f11e"
    finally:
        session.close()
    said, got = received_through(layered, field_ep)
    assert said == "sent" and got == ["hello"]
    session = open_session(layered)
    try:
        assert str(session.info.zid()) == "7ab1e"
    finally:
        session.close()


def test_wrenchd_defaults_fill_only_what_the_file_leaves_unset(tmp_path):
    silent = tmp_path / "silent.json5"
    silent.write_text('{ id: "ab" }')
    conf = ZenohConfig(config_file=str(silent)).to_zenoh()
    # multicast scouting stays off although zenoh's own default would turn it on
    assert get(conf, "scouting/multicast/enabled") is False
    assert get(conf, "mode") == "peer"
    assert get(conf, "connect/retry")["period_init_ms"] == 250
    loud = tmp_path / "loud.json5"
    loud.write_text('{ mode: "client", scouting: { multicast: { enabled: true } } }')
    conf = ZenohConfig(config_file=str(loud)).to_zenoh()
    assert get(conf, "scouting/multicast/enabled") is True and get(conf, "mode") == "client"
    conf = ZenohConfig(config_file=str(loud), mode="peer", multicast_scouting=False).to_zenoh()
    assert get(conf, "scouting/multicast/enabled") is False and get(conf, "mode") == "peer"
    # without a file the fields show wrenchd's defaults, as before
    plain = ZenohConfig()
    assert (plain.mode, plain.multicast_scouting, plain.retry_period_init_ms) == ("peer", False, 250)


@pytest.mark.parametrize(("fields", "says"), [
    ({"config": {"nonsense/key": 1}},
     "config key 'nonsense/key' = 1: refused by zenoh: no such zenoh configuration key"),
    ({"config": {"mode": "banana"}}, "config key 'mode' = \"banana\": refused by zenoh: unknown "
                                     "variant `banana`"),
    ({"config": {"id": "not-hex"}}, "config key 'id'"),
    ({"config": {"access_control": {"enabled": True, "bogus": 1}}},
     "config key 'access_control'"),
    ({"config": {"": 1}}, "empty zenoh key"),
    ({"listen": ["nowhere"]}, "listen = [\"nowhere\"]: refused by zenoh: Endpoints must be"),
])
def test_a_bad_key_or_value_is_a_config_error_naming_it(fields, says):
    with pytest.raises(ConfigError, match="^zenoh settings: ") as caught:
        zenoh_config(**fields)
    assert says in str(caught.value)
    assert ".rs:" not in str(caught.value)          # no Rust source paths


def test_a_missing_or_bad_config_file_is_a_config_error_naming_it(tmp_path):
    missing = tmp_path / "absent.json5"
    with pytest.raises(ConfigError, match=f"config_file '{missing}': no such file"):
        zenoh_config(config_file=str(missing))
    typo = tmp_path / "typo.json5"
    typo.write_text('{\n  mode: "client",\n  scoutng: {},\n}\n')
    with pytest.raises(ConfigError, match=r"unknown field `scoutng`.*\(line 3, column \d+\)"):
        zenoh_config(config_file=str(typo))
    broken = tmp_path / "broken.json5"
    broken.write_text('{ mode: "client", ')
    with pytest.raises(ConfigError, match=f"config_file '{broken}': refused by zenoh"):
        zenoh_config(config_file=str(broken))
    # a file that vanishes after validation is still a ConfigError when the session opens
    gone = tmp_path / "gone.json5"
    gone.write_text('{ id: "ab" }')
    config = ZenohConfig(config_file=str(gone))
    gone.unlink()
    with pytest.raises(ConfigError, match="no such file"):
        open_session(config)


def test_the_daemon_settings_take_the_file_and_the_key_table(tmp_path, monkeypatch):
    port = free_port()
    zfile = tmp_path / "zenoh.json5"
    zfile.write_text(f'{{ id: "d1", listen: {{ endpoints: ["tcp/127.0.0.1:{port}"] }} }}')
    toml = tmp_path / "wrenchd.toml"
    toml.write_text(f"""
[zenoh]
config_file = "{zfile}"

[zenoh.config]
id = "d2"
"transport/link/tls/root_ca_certificate" = "/etc/wrenchd/tls/ca.pem"
""")
    settings = load_settings(toml)
    conf = settings.zenoh.to_zenoh()
    assert get(conf, "id") == "d2"
    assert get(conf, "transport/link/tls/root_ca_certificate") == "/etc/wrenchd/tls/ca.pem"
    assert has_endpoints(settings.zenoh, "listen") and not settings.zenoh.listen
    # the environment's keys join the file's table, key by key
    monkeypatch.setenv("WRENCHD_ZENOH__CONFIG", '{"id": "d3"}')
    settings = load_settings(toml)
    assert settings.zenoh.config["transport/link/tls/root_ca_certificate"]
    session = open_session(settings.zenoh)
    try:
        assert str(session.info.zid()) == "d3"
    finally:
        session.close()
    monkeypatch.delenv("WRENCHD_ZENOH__CONFIG")
    toml.write_text(toml.read_text() + '"scouting/multicast/enabld" = true\n')
    with pytest.raises(ConfigError, match=r"wrenchd.toml: invalid settings: zenoh: .*"
                                          r"'scouting/multicast/enabld'"):
        load_settings(toml)
    toml.write_text(f'[zenoh]\nconfig_file = "{tmp_path / "nope.json5"}"\n')
    with pytest.raises(ConfigError, match="nope.json5'?: no such file"):
        load_settings(toml)


def test_an_unchanged_config_builds_what_it_built_before():
    """Without a file or keys, the zenoh configuration is the one wrenchd always built."""
    conf = ZenohConfig(listen=["tcp/127.0.0.1:7447"]).to_zenoh()
    fresh = zenoh.Config()
    assert get(conf, "mode") == "peer" and get(conf, "scouting/multicast/enabled") is False
    assert get(conf, "listen/endpoints") == ["tcp/127.0.0.1:7447"]
    assert get(conf, "connect/endpoints") == get(fresh, "connect/endpoints") == []
    assert get(conf, "connect/retry") == {"period_init_ms": 250, "period_max_ms": 1000,
                                          "period_increase_factor": 2.0}
    # the send queue holds a pass of express wrenches (zenoh's default: 2 batches)
    assert get(conf, "transport/link/tx/queue/size/data") == 8
    assert get(fresh, "transport/link/tx/queue/size/data") == 2


def test_the_send_queue_depth_is_a_field_a_file_or_a_key(tmp_path):
    file = tmp_path / "deep.json5"
    file.write_text('{ transport: { link: { tx: { queue: { size: { data: 4 } } } } } }')
    assert get(ZenohConfig(config_file=str(file)).to_zenoh(),
               "transport/link/tx/queue/size/data") == 4              # unset: the file's
    assert get(ZenohConfig(config_file=str(file), tx_queue_batches=8).to_zenoh(),
               "transport/link/tx/queue/size/data") == 8
    assert get(ZenohConfig(tx_queue_batches=3, config={
        "transport/link/tx/queue/size/data": 5}).to_zenoh(),
        "transport/link/tx/queue/size/data") == 5                     # a key wins
    with pytest.raises(ConfigError, match="tx_queue_batches"):
        zenoh_config(tx_queue_batches=0)
