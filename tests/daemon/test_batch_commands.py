"""``P/commands``: many robots' commands in one message, taken as one ``cmd_vel`` per robot
would be (its row to each robot, the limits, the watchdog), and a bad batch dropped whole and
counted, never half applied."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import msgspec
import numpy as np
import pytest
import zenoh

from clients import FleetClient, wait_until
from protocol.control import PackedCommands
from tests.conftest import Daemon
from tests.daemon.test_bad_input import world_state
from tests.daemon.test_daemon import step_until
from tests.zraw import matching, raw_session


def _velocities(c: FleetClient, name: str) -> tuple[float, float]:
    r = c.robot(name)
    assert r is not None
    return r.linear_velocity, r.angular_velocity


def test_a_batch_drives_each_robot_by_its_row_and_the_watchdog_stops_them(
    daemon_factory: Callable[..., Daemon],
) -> None:
    d = daemon_factory("--lockstep", "--world", "empty")
    c = d.client()
    c.spawn("a", 0.0, 0.0)
    c.spawn("b", 1.0, 1.0, namespace="ns_b")
    names = ["ns_b", "ghost", "a"]  # by namespace; a name no robot has is ignored
    values = np.array([[0.0, 1.0], [0.2, 0.2], [9.0, 0.0]])  # a's 9 m/s is clamped to the burger's 0.22

    def moving() -> bool:
        c.drive_many(names, values)  # a fresh session may not know the daemon's subscriber yet: again
        return _velocities(c, "a")[0] > 0.0 and _velocities(c, "b")[1] > 0.0

    step_until(c, moving)
    c.step(10)  # the wheels ramp up (1 m/s² at the rim: 7 ticks to 0.22 m/s) within the watchdog's 15
    linear_a, angular_a = _velocities(c, "a")
    linear_b, angular_b = _velocities(c, "b")
    assert linear_a == pytest.approx(0.22) and angular_a == pytest.approx(0.0, abs=1e-9)
    assert angular_b == pytest.approx(1.0) and linear_b == pytest.approx(0.0, abs=1e-9)
    assert c.clock().dropped_commands == 0  # the ghost's row is no bad command
    c.step(15 + 30)  # the watchdog, then the ramp down
    assert _velocities(c, "a") == (0.0, 0.0) and _velocities(c, "b") == (0.0, 0.0)

    with pytest.raises(ValueError, match=r"shape \(2, 2\)"):
        c.drive_many(["a", "ns_b"], np.zeros(3))
    with pytest.raises(ValueError, match="finite"):
        c.drive_many(["a"], [[math.nan, 0.0]])
    with pytest.raises(ValueError, match="more than once"):
        c.drive_many(["a", "a"], np.zeros((2, 2)))


def _batch(names: list[str], rows: list[tuple[float, float]]) -> bytes:
    return msgspec.msgpack.encode(PackedCommands(names=names, twist=np.array(rows, "<f8").tobytes()))


BAD_BATCHES: list[tuple[str, bytes]] = [
    ("garbage", b"\x00\xffnot a batch"),
    ("json of the wrong shape", b'{"names": "tb3_0", "twist": 5}'),
    ("json twist not base64", b'{"names": ["tb3_0"], "twist": "not base64!"}'),
    ("twist one value short", msgspec.msgpack.encode({"names": ["tb3_0"], "twist": b"\x00" * 8})),
    ("a name twice", _batch(["tb3_0", "tb3_0"], [(0.2, 0.0), (0.2, 0.0)])),
    ("not finite, beside a good row", _batch(["ns_of_b", "tb3_0"], [(0.2, 0.0), (math.nan, 0.0)])),
    ("infinite", _batch(["tb3_0"], [(0.1, math.inf)])),
    ("nested deep", b'{"names":' + b"[" * 100_000 + b"]" * 100_000 + b"}"),
    ("more than 4 MiB", _batch([f"r{i}" for i in range(300_000)], [(0.1, 0.0)] * 300_000)),
]


def test_bad_batches_are_dropped_whole_and_counted(daemon_factory: Any) -> None:
    d = daemon_factory("--lockstep")  # nothing moves between checks: "unchanged" is exact
    c = d.client()
    c.spawn("tb3_0", -2.0, -0.5)
    c.spawn("b", 0.5, -2.0, namespace="ns_of_b")
    before = world_state(c)
    dropped = c.clock().dropped_commands
    with raw_session(d.endpoint) as s:
        # BLOCK: a loaded machine must not drop the test's own (fragmented, megabytes) puts
        pub = s.declare_publisher("fleet/commands", congestion_control=zenoh.CongestionControl.BLOCK)
        assert wait_until(lambda: matching(pub), 5.0)
        for _, body in BAD_BATCHES:
            pub.put(body)
        assert wait_until(lambda: c.clock().dropped_commands >= dropped + len(BAD_BATCHES), 10.0)
    c.step(30)
    assert world_state(c) == before  # not even the good row of a bad batch moved its robot
    assert d.alive() and "Traceback" not in d.log()
    assert "fleet/commands" in d.log()  # the drop is logged, with the key
