"""simd --join --ros2: two daemons behind one router (in rmw_zenohd's part) show one simulator to
a ROS tool (the stand-in, tests/ros2/standin.py): /clock from one daemon, the services answered
once and placed by name as ``fleet spawn`` places them, a node per daemon, and /clock and the
services taken over by the other daemon when that one dies. Real processes on loopback; the
daemons run in lockstep, so that the clock moves only when the test steps it."""

from __future__ import annotations

import re
import subprocess
import time
from collections import Counter
from pathlib import Path
from typing import Any

import pytest

from clients import FleetClient, wait_until
from protocol.placement import owner
from tests.conftest import simd_command
from tests.ros2.conftest import pose_stamped, spawn_request
from tests.ros2.standin import Entity, StandIn, msg, uuid_msg, wait_for
from tests.scaleout.test_router import _start, _wait_for, router  # noqa: F401  (the router fixture)

Router = tuple[str, subprocess.Popen[str], Path]
SPAWN = ("/spawn_entity", "gazebo_msgs/srv/SpawnEntity")
DELETE = ("/delete_entity", "gazebo_msgs/srv/DeleteEntity")
GET_ENTITIES = ("/fleetsim/get_entities", "simulation_interfaces/srv/GetEntities")
LIST = "rcl_interfaces/srv/ListParameters"
TICK = 1.0 / 30


def _daemon(endpoint: str, daemon_id: str, ros_mode: str, tmp_path: Path) -> subprocess.Popen[str]:
    """A --join --ros2 daemon as the docs start it: the router is its ROS router and, with no
    -l, its fleet protocol's too."""
    args = ["--join", "--id", daemon_id, "--world", "empty", "--no-noise", "--lockstep", "--ros2", "--ros-router"]
    args += [endpoint, "--ros-mode", ros_mode]
    return _start(simd_command(*args), tmp_path / f"simd-{daemon_id}.log")


def _kill(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.kill()
        proc.wait(10)


def _voice(g: list[Entity]) -> tuple[list[str], list[str]]:
    """The nodes that publish /clock and those that serve /spawn_entity."""
    clock = [e.node for e in g if e.kind == "MP" and e.topic == "/clock"]
    spawn = [e.node for e in g if e.kind == "SS" and e.topic == SPAWN[0]]
    return clock, spawn


PARAMETER_SERVICES = ("describe_parameters", "get_parameter_types", "get_parameters", "list_parameters",
                      "set_parameters", "set_parameters_atomically")  # fmt: skip


def _parameters(e: Entity) -> bool:
    """One of the parameter services every node has (``<node>/list_parameters``, ...)."""
    return e.topic in {f"{e.node_fqn}/{s}" for s in PARAMETER_SERVICES}


def _parameter_nodes(g: list[Entity]) -> set[str]:
    """The daemons' nodes that serve all six parameter services."""
    nodes = {e.node for e in g if e.kind == "NN" and e.namespace == "/"}
    return {n for n in nodes if sum(e.node == n and e.kind == "SS" and _parameters(e) for e in g) == 6}


def _spawn(tool: StandIn, name: str, x: float, namespace: str = "") -> Any:
    """A /spawn_entity call and the one reply it must get."""
    replies = tool.call_all(*SPAWN, spawn_request(name, namespace, x, 0.0))
    assert len(replies) == 1, [r.status_message for r in replies]
    return replies[0]


def _goal_once(tool: StandIn, namespace: str, x: float) -> None:
    """A navigate_to_pose goal and a cancel of it, each answered by one daemon, once."""
    nav = "nav2_msgs/action/NavigateToPose"
    action = f"/{namespace}/navigate_to_pose/_action"
    # as an rclpy ActionClient's wait_for_server: the robot's server reaches the tool through the
    # router a moment after its spawn is answered
    services = ((f"{action}/send_goal", f"{nav}_SendGoal"), (f"{action}/cancel_goal", "action_msgs/srv/CancelGoal"))
    assert wait_until(lambda: all(tool.service_available(*s) for s in services), 10.0)
    goal_id = bytes(range(16))
    goal = msg(f"{nav}_Goal", pose=pose_stamped(x, 0.0), behavior_tree="")
    request = msg(f"{nav}_SendGoal_Request", goal_id=uuid_msg(goal_id), goal=goal)
    (accepted,) = tool.call_all(f"{action}/send_goal", f"{nav}_SendGoal", request)
    assert accepted.accepted
    zero = msg("builtin_interfaces/msg/Time", sec=0, nanosec=0)
    info = msg("action_msgs/msg/GoalInfo", goal_id=uuid_msg(goal_id), stamp=zero)
    cancel = msg("action_msgs/srv/CancelGoal_Request", goal_info=info)
    (cancelled,) = tool.call_all(f"{action}/cancel_goal", "action_msgs/srv/CancelGoal", cancel)
    assert [bytes(i.goal_id.uuid) for i in cancelled.goals_canceling] == [goal_id]


def _delete(tool: StandIn, name: str) -> Any:
    replies = tool.call_all(*DELETE, msg("gazebo_msgs/srv/DeleteEntity_Request", name=name))
    assert len(replies) == 1, [r.status_message for r in replies]
    return replies[0]


def _entities(tool: StandIn) -> list[str]:
    si = "simulation_interfaces/msg"
    filters = msg(f"{si}/EntityFilters", filter="", categories=[], tags=msg(f"{si}/TagsFilter", tags=[], filter_mode=0),
                  bounds=msg(f"{si}/Bounds", type=0, points=[]))  # fmt: skip
    (reply,) = tool.call_all(*GET_ENTITIES, msg(f"{GET_ENTITIES[1]}_Request", filters=filters))
    return list(reply.entities)


def _ticks(m: Any) -> int:
    seconds: float = m.clock.sec + m.clock.nanosec * 1e-9
    return round(seconds / TICK)


def _clock_reaches(c: FleetClient, clock: Any) -> tuple[int, bytes]:
    """Step until the speaking daemon has the subscription (it publishes only then): the tick
    and publisher GID of the first /clock message."""
    deadline = time.monotonic() + 20.0
    while True:
        c.step(1)
        try:
            m, _, _, gid = wait_for(clock, timeout=0.5)
            return _ticks(m), gid
        except TimeoutError:
            assert time.monotonic() < deadline, "no /clock"


def _clock_window(c: FleetClient, clock: Any, ticks: int) -> tuple[Counter[int], set[bytes], int]:
    """Step ``ticks`` ticks, then one more as a fence: how often each tick came on /clock, from
    which publishers, and the tick before the fence."""
    while not clock.empty():
        clock.get_nowait()
    start = c.clock().tick
    c.step(ticks)
    c.step(1)
    seen: Counter[int] = Counter()
    gids: set[bytes] = set()
    while seen[start + ticks + 1] == 0:
        m, _, _, gid = wait_for(clock)
        seen[_ticks(m)] += 1
        gids.add(gid)
    return seen, gids, start


@pytest.mark.parametrize("ros_mode", ["peer", "client"])  # peers as on one host; clients as in compose.fleet.yaml
def test_two_daemons_show_one_simulator_to_ros(ros_mode: str, router: Router, tmp_path: Path) -> None:  # noqa: F811
    endpoint = router[0]
    names = [f"burger_{i}" for i in range(40)]
    on_a = [n for n in names if owner(n, ["a", "b"]) == "a"]
    on_b = [n for n in names if owner(n, ["a", "b"]) == "b"]
    daemons = {"a": _daemon(endpoint, "a", ros_mode, tmp_path)}
    tool = StandIn(endpoint)
    try:
        with FleetClient(endpoint, timeout=5.0) as c:
            assert wait_until(lambda: [d.id for d in c.daemons()] == ["a"], 30.0), (tmp_path / "simd-a.log").read_text()
            assert wait_until(lambda: tool.service_available(*SPAWN), 10.0)
            # alone, a runs every robot: one that placement by name gives b once b is there
            early = on_b[0]
            assert _spawn(tool, early, 0.0).success
            daemons["b"] = _daemon(endpoint, "b", ros_mode, tmp_path)
            assert wait_until(lambda: [d.id for d in c.daemons()] == ["a", "b"], 30.0), (
                tmp_path / "simd-b.log"
            ).read_text()
            # b listens for the daemons there before it may speak, then leaves the voice to a
            _wait_for(tmp_path / "simd-b.log", "daemon 'a' speaks for the fleet on ROS 2", daemons["b"])

            # the graph: a node per daemon; /clock and the services from a (there first) alone
            g = tool.wait_graph(lambda g: _parameter_nodes(g) == {"fleetsim_a", "fleetsim_b"})
            assert {e.node_fqn for e in g if e.kind == "NN" and e.namespace == "/"} == {"/fleetsim_a", "/fleetsim_b"}
            clock_nodes, spawn_nodes = _voice(g)
            assert clock_nodes == ["fleetsim_a"] and spawn_nodes == ["fleetsim_a"]
            # each node has its own parameter services (as every rclcpp node); the fleet's are a's alone
            fleet = {e.node for e in g if e.kind == "SS" and e.namespace == "/" and not _parameters(e)}
            assert fleet == {"fleetsim_a"}
            assert _parameter_nodes(g) == {"fleetsim_a", "fleetsim_b"}
            # a robot's own services are its navigate_to_pose action's, on its node, from its daemon
            robots = {e.topic for e in g if e.kind == "SS" and e.namespace != "/" and not _parameters(e)}
            assert {t.split("/_action/")[0] for t in robots} <= {f"/{n}/navigate_to_pose" for n in names}

            # spawns through ROS land where `fleet spawn` would put them, each with one reply
            here, there = on_a[0], on_b[1]
            for k, name in enumerate([here, there]):
                r = _spawn(tool, name, 1.0 + k)
                assert (r.success, r.status_message) == (True, f"SpawnEntity: Successfully spawned entity [{name}]")
            placed = {early: "a", here: "a", there: "b"}
            assert {r.name: r.daemon for r in c.robots()} == placed
            assert _entities(tool) == sorted(placed)  # the services see the whole fleet
            # refused in Gazebo's words, once, nothing lost: the name lives on a, placement says b
            dup = _spawn(tool, early, 3.0)
            assert (dup.success, dup.status_message) == (False, f"Entity [{early}] already exists.")
            clash = _spawn(tool, on_b[2], 3.0, namespace=here)  # b's robot in a's robot's namespace
            assert not clash.success and f"Entity [{here}] already exists (on another daemon)" in clash.status_message
            assert {r.name: r.daemon for r in c.robots()} == placed
            # a goal for b's robot is answered once, by b, whose navigator drives the robot
            _goal_once(tool, there, 3.0)
            # a delete reaches the robot's daemon through the speaker
            gone = _delete(tool, there)
            assert (gone.success, gone.status_message) == (True, f"Successfully deleted entity [{there}]")
            missing = _delete(tool, there)
            assert (missing.success, missing.status_message) == (False, f"Entity [{there}] does not exist")
            assert _spawn(tool, there, 2.0).success
            assert {r.name: r.daemon for r in c.robots()} == placed
            # a robot's parameters are answered once, by its own daemon (b), through the wildcard every daemon has
            node = f"/{there}/turtlebot3"
            assert wait_until(lambda: tool.service_available(f"{node}/list_parameters", LIST), 10.0)
            request = msg(f"{LIST}_Request", prefixes=[], depth=0)
            replies = tool.call_all(f"{node}/list_parameters", LIST, request, timeout=3.0)
            assert [list(r.result.names) for r in replies] == [["use_sim_time"]]

            # /clock: every tick of a step once, from one publisher
            clock = tool.subscribe("/clock", "rosgraph_msgs/msg/Clock")
            _, gid_a = _clock_reaches(c, clock)
            seen, gids, start = _clock_window(c, clock, 30)
            assert gids == {gid_a}
            assert {t: n for t, n in seen.items() if t > start} == dict.fromkeys(range(start + 1, start + 32), 1)

            # a dies: b takes /clock and the services over; a's robots leave with it
            _kill(daemons["a"])
            assert wait_until(lambda: [d.id for d in c.daemons()] == ["b"], 20.0)
            _wait_for(tmp_path / "simd-b.log", "this daemon speaks for the fleet on ROS 2", daemons["b"])
            g = tool.wait_graph(lambda g: _voice(g) == (["fleetsim_b"], ["fleetsim_b"]))
            assert _voice(g) == (["fleetsim_b"], ["fleetsim_b"]), (tmp_path / "simd-b.log").read_text()
            assert not any(e.node == "fleetsim_a" for e in g)
            assert {r.name: r.daemon for r in c.robots()} == {there: "b"}
            seen, gids, start = _clock_window(c, clock, 10)
            assert len(gids) == 1 and gids != {gid_a}
            assert {t: n for t, n in seen.items() if t > start} == dict.fromkeys(range(start + 1, start + 12), 1)
            r = _spawn(tool, early, 0.0)  # gone with a: its name is free, and b runs it now
            assert r.success, r.status_message
            assert {r.name: r.daemon for r in c.robots()} == {there: "b", early: "b"}
            assert tool.rejected == []
    finally:
        tool.close()
        for p in daemons.values():
            _kill(p)


def _compose_value(text: str, shell: dict[str, str]) -> str:
    """``${NAME:-default}`` as compose reads it from ``shell``."""
    return re.sub(r"\$\{(\w+):-([^}]*)\}", lambda m: shell.get(m.group(1)) or m.group(2), text)


@pytest.mark.parametrize(
    "shell",
    [
        {},
        {"SIMD_ROS2": "1"},
        {"SIMD_ROS2": "1", "SIMD_ROS_TF": "namespaced", "SIMD_ROS_LOCALIZATION": "1", "SIMD_NO_NAV": "1"},
    ],
)
def test_the_fleet_compose_file_adds_ros2_to_both_daemons_when_asked(shell: dict[str, str]) -> None:
    """docker/compose.fleet.yaml through the image's entrypoint (the flags simd gets from the
    daemons' command and variables): without SIMD_ROS2 as before, with it --ros2 on both
    daemons, the compose router as the ROS router and the daemons as its clients."""
    import yaml

    from simd.cli import build_parser
    from simd.container_entry import build_argv
    from tests.conftest import ROOT

    compose = yaml.safe_load((ROOT / "docker/compose.fleet.yaml").read_text())
    for service, daemon_id in (("simd_a", "a"), ("simd_b", "b")):
        spec = compose["services"][service]
        env = {k: _compose_value(str(v), shell) for k, v in spec["environment"].items()}
        args = build_parser().parse_args(build_argv(spec["command"], env))
        assert (args.join, args.id, args.mode, args.connect) == (True, daemon_id, "client", ["tcp/router:7447"])
        assert not args.listen  # a client of the router, as before
        assert args.ros2 == bool(shell)
        if args.ros2:
            assert (args.ros_router, args.ros_mode, args.ros_domain_id) == ("tcp/router:7447", "client", 0)
        # Nav2's multi-robot layout when asked for, else the defaults
        assert args.ros_tf == shell.get("SIMD_ROS_TF", "global")
        assert args.ros_localization == ("SIMD_ROS_LOCALIZATION" in shell)
        assert args.no_nav == ("SIMD_NO_NAV" in shell)
