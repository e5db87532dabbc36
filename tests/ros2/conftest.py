"""A ROS domain on loopback: a zenoh router in the role of rmw_zenohd, a daemon started with
``--ros2`` joining it, and the stand-in ROS tool (standin.py) joining it as another peer."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import zenoh

from tests.conftest import Daemon, free_port
from tests.ros2.standin import StandIn, msg

DATA = Path(__file__).parent / "data"


@dataclass
class RosDomain:
    router: str
    daemon: Daemon
    tool: StandIn


@pytest.fixture
def router() -> Iterator[str]:
    """rmw_zenohd's part: a zenoh router on a free port, multicast scouting off."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    yield endpoint
    session.close()


@pytest.fixture
def ros_factory(router: str, daemon_factory: Callable[..., Daemon]) -> Iterator[Callable[..., RosDomain]]:
    tools: list[StandIn] = []

    def make(*args: str, domain: int = 0, distro: str = "jazzy") -> RosDomain:
        d = daemon_factory("--ros2", "--ros-router", router, "--ros-domain-id", str(domain), "--ros-distro", distro,
                           *args)  # fmt: skip
        tool = StandIn(router, domain, distro)
        tools.append(tool)
        tool.wait_graph(lambda g: any(e.kind == "SS" and e.topic == "/spawn_entity" for e in g))
        return RosDomain(router, d, tool)

    yield make
    for t in tools:
        t.close()


@pytest.fixture
def ros(ros_factory: Callable[..., RosDomain]) -> RosDomain:
    return ros_factory()


def pose(x: float = 0.0, y: float = 0.0, yaw: float = 0.0, z: float = 0.01) -> object:
    import math

    return msg(
        "geometry_msgs/msg/Pose",
        position=msg("geometry_msgs/msg/Point", x=x, y=y, z=z),
        orientation=msg("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
    )


def pose_stamped(x: float, y: float, yaw: float = 0.0, frame: str = "map") -> Any:
    """A goal as RViz's "2D Goal Pose" sends it (stamped zero here)."""
    header = msg("std_msgs/msg/Header", stamp=msg("builtin_interfaces/msg/Time", sec=0, nanosec=0), frame_id=frame)
    return msg("geometry_msgs/msg/PoseStamped", header=header, pose=pose(x, y, yaw, z=0.0))


def spawn_request(name: str, namespace: str, x: float, y: float, yaw: float = 0.0,
                  xml: str | None = None, reference_frame: str = "") -> object:  # fmt: skip
    """What the TurtleBot3 spawner node sends: the model file's whole text in ``xml``."""
    if xml is None:
        xml = (DATA / "turtlebot3_burger.sdf").read_text()
    return msg(
        "gazebo_msgs/srv/SpawnEntity_Request",
        name=name, xml=xml, robot_namespace=namespace, initial_pose=pose(x, y, yaw), reference_frame=reference_frame,
    )  # fmt: skip


def twist(v: float, w: float) -> object:
    v3 = "geometry_msgs/msg/Vector3"
    return msg("geometry_msgs/msg/Twist", linear=msg(v3, x=v, y=0.0, z=0.0), angular=msg(v3, x=0.0, y=0.0, z=w))
