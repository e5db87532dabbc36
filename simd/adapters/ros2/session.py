"""The zenoh session through which the daemon joins a ROS 2 domain, configured as rmw_zenoh's peers.

An rmw_zenoh process opens a peer session that connects to the router (``rmw_zenohd`` on
``tcp/localhost:7447``), listens on a free local port, and learns the other peers' locators by
gossip (multicast scouting off), so data then flows peer to peer. The daemon does the same on a
session of its own, beside the fleet protocol's. With no ROS router around (a fleet driven by
ROS tools from elsewhere, or a test), ``serve`` makes that session the router itself.

A peer is reached at the addresses it listens on, which gossip hands to the others; a daemon in
a container listens on its own loopback, which no other peer reaches, and a router does not pass
data, tokens or queries between two peers (checked with zenoh 1.10). ``mode="client"`` then
makes the session a client of the router, which passes everything between its clients and its
peers (the router is on the data path, as for any client).
"""

from __future__ import annotations

import json

import zenoh

DEFAULT_ROUTER = "tcp/localhost:7447"


def ros_config(router: str = DEFAULT_ROUTER, *, serve: bool = False, mode: str = "peer") -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "true")
    if serve:
        conf.insert_json5("mode", json.dumps("router"))
        conf.insert_json5("listen/endpoints", json.dumps([router]))
    elif mode == "client":
        conf.insert_json5("mode", json.dumps("client"))
        conf.insert_json5("connect/endpoints", json.dumps([router]))
    else:
        conf.insert_json5("mode", json.dumps("peer"))
        conf.insert_json5("connect/endpoints", json.dumps([router]))
        conf.insert_json5("listen/endpoints", json.dumps(["tcp/localhost:0"]))
    # a tick's messages leave back to back: the fleet session's larger send queues (simd/cli.py)
    conf.insert_json5("transport/link/tx/queue/size/data", "16")
    conf.insert_json5("transport/link/tx/queue/size/data_low", "16")
    # as rmw_zenoh: keep retrying the router instead of failing when it starts later
    conf.insert_json5("connect/timeout_ms", "-1")
    conf.insert_json5("connect/exit_on_failure", "false")
    return conf
