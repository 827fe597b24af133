"""The pure-Python XXH3-128 against the reference C implementation (libxxhash 0.8.4 through
the ``xxhash`` 4.1.0 Python package, which is not a dependency of wrenchd): one vector on each
side of every input-length branch of the algorithm."""

import pytest

from wrenchd.adapters.xxh3 import xxh3_128, xxh3_128_hex


def data(n: int) -> bytes:
    """The test input of length ``n`` the vectors were computed on."""
    return bytes((i * 31 + 7) % 251 for i in range(n))


#: (length, canonical hex digest) from ``xxhash.xxh3_128_hexdigest(data(n))``
REFERENCE = [
    (0, "99aa06d3014798d86001c324468d497f"),
    (1, "495b62073ef70ca44c5cca45d0f4811f"),
    (2, "12b2847aa0de5aaaa7e250c97710ff27"),
    (3, "46f66cb93538156515f7093b173d005c"),
    (4, "7fefeeffb4d0eab3b987ca5d9241572a"),
    (8, "803c675a846cc6c256bb836ceb6d4baa"),
    (9, "365644c233ffe5c213af585c9bf5827d"),
    (16, "da917c385cc874c00d463cb04ceffbaf"),
    (17, "d443578f2c4e2fb495c34448580e19c8"),
    (32, "7e6bb3a654986c3373367e068a010989"),
    (33, "97fbf3ce109f139623a0b885a7dac302"),
    (64, "3515800f003ddbd064524fe2047012df"),
    (65, "7fd00229a220a25b3b589ad4300ec5d5"),
    (96, "0f5fdafe3c60a2ba6aaa14172a8f6957"),
    (97, "203fb0b6f9a8419aaedfb1405f779a9d"),
    (128, "22c34350373a38ae5b77925b2c683a12"),
    (129, "c4a7d8f7893f2090d6d9e73553568be1"),
    (200, "7d5b21c921158e644ec0706f02ef2a5b"),
    (240, "e29d70b8920fd24bc6ed4333f79384f8"),
    (241, "f91b3cb8ed0fa91a07525dbc14902c7f"),
    (1024, "f53a1b1e9f1efedfe2898655db7bc9ee"),
    (1025, "a906cca0f6e772a7134c652ba3d6fb9e"),
    (2100, "05a865eb3b26da8c8ddfb7cfddc5c73e"),
]


@pytest.mark.parametrize(("n", "digest"), REFERENCE, ids=[str(n) for n, _ in REFERENCE])
def test_matches_the_reference_implementation(n, digest):
    assert xxh3_128_hex(data(n)) == digest


def test_halves_of_a_liveliness_token():
    # the subscription token of the rmw_zenoh design document's listener example (187 bytes)
    token = (b"@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/"
             b"std_msgs::msg::dds_::String_/RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db128802"
             b"1743503259e948f6b1a18/::,10:,:,:,,")
    low, high = xxh3_128(token)
    assert f"{high:016x}{low:016x}" == "e61dca625437c5a655fe0883538a1476"
