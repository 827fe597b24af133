"""rmw_zenoh's wire format, checked against the examples and layouts of its design document
(ros2/rmw_zenoh ``docs/design.md``) and against type hashes quoted in public sources; the
attachment is parsed here with the test's own reading of the document, not the module's."""

import struct
import time

import pytest
import xxhash

from wrenchd.adapters.rmw_zenoh import (ATTACHMENT_SIZE, PUBLISHER, SUBSCRIPTION, Qos, Stamper,
                                        decode_attachment, dds_type_name, encode_attachment,
                                        endpoint, endpoint_token, gid_of, node_token,
                                        topic_key, type_hash)
from wrenchd.models.errors import ConfigError, DataError

#: RIHS01 hashes as quoted in public sources (Jazzy): std_msgs/String in the rmw_zenoh design
#: document's key expression examples; sensor_msgs/JointState in ``ros2 topic info --verbose``
#: output of a Jazzy joint_state_broadcaster; geometry_msgs/WrenchStamped in the generated
#: type tables of public zenoh-pico ROS 2 clients
QUOTED = {
    "std_msgs/msg/String":
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "sensor_msgs/msg/JointState":
        "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e",
    "geometry_msgs/msg/WrenchStamped":
        "RIHS01_8dc3deaf06b2ab281f9f9a742a8961c328ca7cec16e3fd6586d3a5c83fa78f77",
}


@pytest.mark.parametrize("typename", sorted(QUOTED))
def test_type_hash_is_the_quoted_one(typename):
    assert type_hash(typename) == QUOTED[typename]


def test_topic_keys_of_the_design_document():
    assert topic_key(0, "/chatter", "std_msgs/msg/String") == (
        "0/chatter/std_msgs::msg::dds_::String_/RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db128"
        "8021743503259e948f6b1a18")
    assert topic_key(0, "/robot1/chatter", "std_msgs/msg/String").startswith(
        "0/robot1/chatter/std_msgs::msg::dds_::String_/RIHS01_")


def test_the_dvrk_topics():
    assert topic_key(3, "/PSM1/measured_js", "sensor_msgs/msg/JointState") == (
        "3/PSM1/measured_js/sensor_msgs::msg::dds_::JointState_/" + QUOTED[
            "sensor_msgs/msg/JointState"])
    assert dds_type_name("geometry_msgs/msg/WrenchStamped") == (
        "geometry_msgs::msg::dds_::WrenchStamped_")


def test_tokens_of_the_design_document():
    zid = "aac3178e146ba6f1fc6e6a4085e77f21"
    assert node_token(2, zid, 0, "listener") == f"@ros2_lv/2/{zid}/0/0/NN/%/%/listener"
    assert endpoint_token(SUBSCRIPTION, 2, zid, 0, 10, "listener", "/chatter",
                          "std_msgs/msg/String") == (
        f"@ros2_lv/2/{zid}/0/10/MS/%/%/listener/%chatter/std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,10:,:,:,,")
    talker = "8b20917502ee955ac4476e0266340d5c"
    assert endpoint_token(PUBLISHER, 2, talker, 0, 10, "talker", "/chatter",
                          "std_msgs/msg/String", qos=Qos(depth=7)) == (
        f"@ros2_lv/2/{talker}/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,7:,:,:,,")


def test_qos_names_only_what_differs_from_rmw_zenohs_default():
    assert Qos(depth=42).key() == "::,:,:,:,,"
    assert Qos(reliable=False, transient_local=True, keep_all=True, depth=5).key() == (
        "2:1:2,5:,:,:,,")


def test_namespaced_node_mangles_its_namespace():
    token = endpoint_token(PUBLISHER, 0, "ab", 0, 2, "wrenchd", "/lab/PSM1/wrenchd/measured_cf",
                           "geometry_msgs/msg/WrenchStamped", namespace="/lab")
    parts = token.split("/")
    assert parts[6:10] == ["%", "%lab", "wrenchd", "%lab%PSM1%wrenchd%measured_cf"]


def test_gid_is_the_tokens_xxh3_low_half_first():
    token = endpoint_token(PUBLISHER, 0, "ab", 0, 2, "wrenchd", "/PSM1/wrenchd/measured_cf",
                           "geometry_msgs/msg/WrenchStamped")
    digest = xxhash.xxh3_128_digest(token.encode())         # high half first, big-endian
    assert gid_of(token) == digest[8:][::-1] + digest[:8][::-1]


def test_gid_of_the_design_documents_listener_subscription():
    """A regression vector: the subscription token of the rmw_zenoh design document's listener
    example (187 bytes), whose XXH3-128 libxxhash 0.8.4 gives as
    ``e61dca625437c5a655fe0883538a1476`` (high half first)."""
    token = ("@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/"
             "std_msgs::msg::dds_::String_/RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db128802"
             "1743503259e948f6b1a18/::,10:,:,:,,")
    assert len(token) == 187
    assert gid_of(token) == (bytes.fromhex("55fe0883538a1476")[::-1]
                             + bytes.fromhex("e61dca625437c5a6")[::-1])


def parse_attachment(raw: bytes) -> tuple[int, int, bytes]:
    """The design document's publisher attachment, read by this test: int64 LE sequence
    number, int64 LE timestamp [ns], one byte GID length (16), the GID."""
    assert len(raw) == 8 + 8 + 1 + 16
    seq, stamp = struct.unpack_from("<qq", raw)
    assert raw[16] == 16
    return seq, stamp, raw[17:]


def test_attachment_layout():
    gid = bytes(range(16))
    raw = encode_attachment(7, 1_700_000_000_123_456_789, gid)
    assert len(raw) == ATTACHMENT_SIZE == 33
    assert parse_attachment(raw) == (7, 1_700_000_000_123_456_789, gid)
    assert tuple(decode_attachment(raw)) == (7, 1_700_000_000_123_456_789, gid)


def test_stamper_counts_from_one_with_system_time():
    gid = bytes(range(100, 116))
    stamper = Stamper(gid)
    before = time.time_ns()
    seqs, stamps = [], []
    for _ in range(3):
        seq, stamp, got = parse_attachment(stamper.next())
        seqs.append(seq)
        stamps.append(stamp)
        assert got == gid
    assert seqs == [1, 2, 3]
    assert before <= stamps[0] <= stamps[-1] <= time.time_ns()


@pytest.mark.parametrize("raw, reason", [
    (b"\x00" * 32, "33 bytes"),
    (struct.pack("<qqB16s", 1, 2, 15, bytes(16)), "GID length 15")])
def test_bad_attachments_are_refused(raw, reason):
    with pytest.raises(DataError, match=reason):
        decode_attachment(raw)


@pytest.mark.parametrize("topic", ["PSM1/measured_js", "/PSM1/", "/1PSM/x", "/a//b", "/a b"])
def test_bad_topic_names_are_refused(topic):
    with pytest.raises(ConfigError, match="topic name"):
        topic_key(0, topic, "sensor_msgs/msg/JointState")


def test_unknown_type_is_refused():
    with pytest.raises(ConfigError, match="unknown ROS 2 message type"):
        type_hash("dvrk_msgs/msg/Nothing")


def test_endpoint_bundles_key_token_and_gid():
    e = endpoint(SUBSCRIPTION, 5, "cd", 0, 1, "wrenchd", "/PSM2/measured_js",
                 "sensor_msgs/msg/JointState")
    assert e.key.startswith("5/PSM2/measured_js/sensor_msgs::msg::dds_::JointState_/RIHS01_")
    assert e.token.startswith("@ros2_lv/5/cd/0/1/MS/%/%/wrenchd/%PSM2%measured_js/")
    assert e.gid == gid_of(e.token) and len(e.gid) == 16
