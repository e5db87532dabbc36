"""What ``simd`` publishes and how a benchmark process reaches it.

The subscriber process and the benchmark's own session both count and decode the daemon's
traffic, so the facts they rely on (key prefix, tick rate, scan period, payload sizes) live here
once rather than in each of them.
"""

from __future__ import annotations

from typing import Any

PREFIX = "fleet"
TICK_HZ = 30  # simd's fixed tick: one odometry message per robot per tick
SCAN_EVERY = 6  # ticks between two scans of one robot (5 Hz)
BEAMS = 360  # rays per scan
SCAN_MIN_BYTES = BEAMS * 4  # a scan carries 360 float32 ranges, plus its header
ODOM_MIN_BYTES = 200  # an Odometry map with two 36-double covariances is ~700 B
MSGPACK = "application/msgpack"


def zenoh_config(endpoint: str, connect_timeout_s: float) -> Any:
    from fleetcommon.zenoh_config import ZenohOptions

    conf = ZenohOptions(mode="client", connect=[endpoint]).build()
    conf.insert_json5("connect/timeout_ms", str(int(connect_timeout_s * 1000)))
    return conf
