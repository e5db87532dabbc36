"""The zenoh session through which the daemon joins a ROS 2 domain, configured as rmw_zenoh's peers.

An rmw_zenoh process opens a peer session that connects to the router (``rmw_zenohd`` on
``tcp/localhost:7447``), listens on a free local port, and learns the other peers' locators by
gossip (multicast scouting off), so data then flows peer to peer. The daemon does the same on a
session of its own, beside the fleet protocol's. With no ROS router around (a fleet driven by
ROS tools from elsewhere, or a test), ``serve`` makes that session the router itself.
"""

from __future__ import annotations

import json

import zenoh

DEFAULT_ROUTER = "tcp/localhost:7447"


def ros_config(router: str = DEFAULT_ROUTER, *, serve: bool = False) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "true")
    if serve:
        conf.insert_json5("mode", json.dumps("router"))
        conf.insert_json5("listen/endpoints", json.dumps([router]))
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
