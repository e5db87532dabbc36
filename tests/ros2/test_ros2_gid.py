"""GIDs as rmw_zenoh makes them: XXH3-128 (seed 0) of the liveliness token, low half first,
little-endian. The stand-in's XXH3-128 (xxh3.py, written from xxHash's specification) is checked
against xxHash's own published vectors; the daemon's (the ``xxhash`` library) against it."""

from __future__ import annotations

import pytest

from simd.adapters.ros2 import graph
from simd.adapters.ros2.graph import Kind, Node, Topic
from tests.ros2 import xxh3

PRIME32 = 2654435761
PRIME64 = 11400714785074694797


def sanity_buffer(length: int) -> bytes:
    """The input of xxHash's sanity test (``XSUM_fillTestBuffer`` in cli/xsum_sanity_check.c)."""
    out = bytearray()
    gen = PRIME32
    for _ in range(length):
        out.append(gen >> 56)
        gen = (gen * PRIME64) & xxh3.M64
    return bytes(out)


#: XXH3_128bits with seed 0 of the sanity buffer's first N bytes, as (low64, high64): the seed-0
#: rows of ``XSUM_XXH128_testdata`` in Cyan4973/xxHash ``cli/xsum_sanity_check.c`` (commit b2e9dbb),
#: one or more per code path (empty, 1-3, 4-8, 9-16, 17-128, 129-240 bytes, and long inputs of one
#: to three 1 kB blocks, ending on or off a stripe)
VECTORS = {
    0: (0x6001C324468D497F, 0x99AA06D3014798D8),
    1: (0xC44BDFF4074EECDB, 0xA6CD5E9392000F6A),
    6: (0x3E7039BDDA43CFC6, 0x082AFE0B8162D12A),
    12: (0x061A192713F69AD9, 0x6E3EFD8FC7802B18),
    24: (0x1E7044D28B1B901D, 0x0CE966E4678D3761),
    48: (0xF942219AED80F67B, 0xA002AC4E5478227E),
    81: (0x5E8BAFB9F95FB803, 0x4952F58181AB0042),
    222: (0xF1AEBD597CEC6B3A, 0x337E09641B948717),
    403: (0xCDEB804D65C6DEA4, 0x1B6DE21E332DD73D),
    512: (0x617E49599013CB6B, 0x18D2D110DCC9BCA1),
    2048: (0xDD59E2C3A5F038E0, 0xF736557FD47073A5),
    2240: (0x6E73A90539CF2948, 0xCCB134FBFA7CE49D),
    2367: (0xCB37AEB9E5D361ED, 0xE89C0F6FF369B427),
}


@pytest.mark.parametrize(("length", "expected"), VECTORS.items())
def test_the_stand_ins_xxh3_128_gives_xxhashs_published_vectors(length: int, expected: tuple[int, int]) -> None:
    assert xxh3.xxh3_128(sanity_buffer(length)) == expected


@pytest.mark.parametrize("length", sorted({*VECTORS, 2, 3, 4, 8, 9, 16, 17, 32, 33, 128, 129, 240, 241, 1024, 1025}))
def test_the_daemons_gid_is_the_stand_ins_for_inputs_of_every_length_class(length: int) -> None:
    text = sanity_buffer(length).hex()[:length]  # a token is text: hex digits of the right length
    assert graph.gid(text) == xxh3.gid(text)


def test_gid_bytes_are_the_low_half_then_the_high_half_little_endian() -> None:
    low, high = VECTORS[0]
    assert graph.gid("") == low.to_bytes(8, "little") + high.to_bytes(8, "little")


def test_the_tokens_of_a_robot_get_rmw_zenohs_gids() -> None:
    """Real tokens, the longest past 240 bytes (XXH3's long-input path)."""
    node = Node(domain=0, zid="4b0c2a59f2bd6e1a3f0d7c9e8b5a4d21", node_id=17, namespace="/TB3_1", name="turtlebot3")
    tokens = [node.token()]
    for name, typename, kind, qos in [
        ("/TB3_1/odom", "nav_msgs/msg/Odometry", Kind.PUBLISHER, graph.ODOM_QOS),
        ("/tf_static", "tf2_msgs/msg/TFMessage", Kind.PUBLISHER, graph.TF_STATIC_QOS),
        ("/TB3_1/cmd_vel", "geometry_msgs/msg/TwistStamped", Kind.SUBSCRIPTION, graph.CMD_VEL_QOS),
        ("/fleetsim/get_simulator_features", "simulation_interfaces/srv/GetSimulatorFeatures", Kind.SERVICE,
         graph.SERVICE_QOS),
    ]:  # fmt: skip
        tokens.append(node.entity_token(18, kind, Topic(name, typename, 0, "jazzy"), qos))
    assert max(len(t) for t in tokens) > 240
    for token in tokens:
        assert graph.gid(token) == xxh3.gid(token)
