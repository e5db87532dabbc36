"""A large fleet's own answers reach the client: a daemon's robot list grows with its fleet
(~760 bytes a robot) past the 4 MB that any request may carry. A real daemon gives one
robot's record; a zenoh queryable on a free port answers the list with 6 000 of them."""

from __future__ import annotations

import json

import msgspec
import zenoh

from clients import FleetClient
from protocol.codec import MAX_PAYLOAD_BYTES, encode
from protocol.control import RobotList
from tests.conftest import Daemon, free_port


def test_a_robot_list_larger_than_a_request_may_be_reaches_the_client(daemon: Daemon) -> None:
    with daemon.client() as c:
        one = c.spawn("tb3_0", -2.0, -0.5)
        clock = c.clock()
    records = [msgspec.structs.replace(one, name=f"r{i}", namespace=f"r{i}") for i in range(6000)]
    payload = encode(RobotList(stamp=clock.clock, robots=records), "msgpack")
    assert len(payload) > MAX_PAYLOAD_BYTES  # what the requests' limit would refuse

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")

    def answer(query: zenoh.Query) -> None:
        with query:
            query.reply("fleet/robots", payload, encoding="application/msgpack")

    with zenoh.open(conf) as big:
        queryable = big.declare_queryable("fleet/robots", answer)
        try:
            with FleetClient(endpoint, timeout=10.0) as client:
                listed = client.robots()
        finally:
            queryable.undeclare()
    assert [r.name for r in listed] == [f"r{i}" for i in range(6000)]
    assert listed[-1].topics == one.topics
