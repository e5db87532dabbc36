"""The standard simulator services (simulation_interfaces 1.x, and 2.x on Rolling) under /fleetsim/,
called by the stand-in."""

from __future__ import annotations

import math
from typing import Any

import pytest

from clients import wait_until
from tests.ros2.conftest import DATA, RosDomain, pose
from tests.ros2.standin import StandIn, msg

SI = "simulation_interfaces"
OK, FEATURE_UNSUPPORTED, NOT_FOUND, OPERATION_FAILED = 1, 0, 2, 4
PLAYING, PAUSED, STOPPED, QUITTING = 1, 2, 0, 3


def call(ros: RosDomain, srv: str, **fields: Any) -> Any:
    snake = "".join(f"_{c.lower()}" if c.isupper() else c for c in srv).lstrip("_")
    typename = f"{SI}/srv/{srv}"
    store_type = f"{typename}_Request"
    if not fields:
        fields = {"structure_needs_at_least_one_member": 0}
    return ros.tool.call(f"/fleetsim/{snake}", typename, msg(store_type, **fields))


def stamped(x: float, y: float, yaw: float = 0.0, frame: str = "") -> Any:
    header = msg("std_msgs/msg/Header", stamp=msg("builtin_interfaces/msg/Time", sec=0, nanosec=0), frame_id=frame)
    return msg("geometry_msgs/msg/PoseStamped", header=header, pose=pose(x, y, yaw))


def spawn(ros: RosDomain, name: str, x: float, y: float, *, uri: str = "", resource: str = "",
          rename: bool = False, namespace: str = "", frame: str = "") -> Any:  # fmt: skip
    return call(ros, "SpawnEntity", name=name, allow_renaming=rename, uri=uri, resource_string=resource,
                entity_namespace=namespace, initial_pose=stamped(x, y, frame=frame))  # fmt: skip


def sim_state(ros: RosDomain) -> int:
    r = call(ros, "GetSimulationState")
    assert r.result.result == OK
    return int(r.state.state)


def set_state(ros: RosDomain, state: int) -> Any:
    return call(ros, "SetSimulationState", state=msg(f"{SI}/msg/SimulationState", state=state)).result


def test_features_and_spawnables_say_what_is_supported(ros: RosDomain) -> None:
    f = call(ros, "GetSimulatorFeatures").features
    assert set(f.features.tolist()) == {0, 1, 8, 9, 10, 14, 20, 23, 24, 25, 26, 31, 32}
    assert list(f.spawn_formats) == ["sdf", "urdf"]
    r = call(ros, "GetSpawnables", sources=[])
    assert r.result.result == OK
    assert [s.uri for s in r.spawnables] == [f"model://turtlebot3_{m}" for m in ("burger", "waffle", "waffle_pi")]
    box = r.spawnables[0].spawn_bounds
    assert box.type == 1 and len(box.points) == 2 and box.points[0].x < 0 < box.points[1].x
    unsupported = call(ros, "SetEntityState", entity="x", state=msg(
        f"{SI}/msg/EntityState",
        header=msg("std_msgs/msg/Header", stamp=msg("builtin_interfaces/msg/Time", sec=0, nanosec=0), frame_id=""),
        pose=pose(), twist=msg("geometry_msgs/msg/Twist",
                               linear=msg("geometry_msgs/msg/Vector3", x=0.0, y=0.0, z=0.0),
                               angular=msg("geometry_msgs/msg/Vector3", x=0.0, y=0.0, z=0.0)),
        acceleration=msg("geometry_msgs/msg/Accel", linear=msg("geometry_msgs/msg/Vector3", x=0.0, y=0.0, z=0.0),
                         angular=msg("geometry_msgs/msg/Vector3", x=0.0, y=0.0, z=0.0))))  # fmt: skip
    assert unsupported.result.result == FEATURE_UNSUPPORTED and unsupported.result.error_message


def test_spawn_by_resource_and_uri_with_result_codes(ros: RosDomain) -> None:
    sdf = (DATA / "turtlebot3_burger.sdf").read_text()
    r = spawn(ros, "tb3_0", -2.0, -0.5, resource=sdf)
    assert (r.result.result, r.entity_name) == (OK, "tb3_0")
    r = spawn(ros, "tb3_1", 0.5, -2.0, uri="model://turtlebot3_waffle_pi", namespace="/TB3_1")
    assert r.result.result == OK
    taken = spawn(ros, "tb3_0", 2.0, 0.5, uri="model://turtlebot3_burger")
    assert taken.result.result == 101  # NAME_NOT_UNIQUE
    renamed = spawn(ros, "tb3_0", 2.0, 0.5, uri="model://turtlebot3_burger", rename=True)
    assert (renamed.result.result, renamed.entity_name) == (OK, "tb3_0_1")
    assert spawn(ros, "a", 0.0, 0.0).result.result == 104  # NO_RESOURCE
    assert spawn(ros, "a", 2.0, 0.5, uri="model://pr2").result.result == 103  # UNSUPPORTED_FORMAT
    assert spawn(ros, "a", 2.0, 0.5, resource="<sdf><model").result.result == 106  # RESOURCE_PARSE_ERROR
    assert spawn(ros, "a", math.nan, 0.5, uri="model://turtlebot3_burger").result.result == 109  # INVALID_POSE
    assert spawn(ros, "a", 0.0, 0.0, uri="model://turtlebot3_burger").result.result == 109  # on the pillar
    assert spawn(ros, "a", -0.5, 2.0, uri="model://turtlebot3_burger", frame="TB3_1/odom").result.result == 109
    assert spawn(ros, "", -0.5, 2.0, uri="model://turtlebot3_burger").result.result == 102  # NAME_INVALID
    robots = {r.name: r for r in ros.daemon.client().robots()}
    assert sorted(robots) == ["tb3_0", "tb3_0_1", "tb3_1"]
    assert robots["tb3_1"].model == "waffle_pi" and robots["tb3_1"].namespace == "TB3_1"


def test_entities_and_their_state(ros: RosDomain) -> None:
    for name, x, y in [("burger_1", -2.0, -0.5), ("burger_2", 0.5, -2.0), ("waffle_1", 2.0, 0.5)]:
        model = "waffle" if name.startswith("waffle") else "burger"
        assert spawn(ros, name, x, y, uri=f"model://turtlebot3_{model}").result.result == OK

    def entities(text: str = "", categories: tuple[int, ...] = (), tags: tuple[str, ...] = ()) -> Any:
        filters = msg(
            f"{SI}/msg/EntityFilters", filter=text,
            categories=[msg(f"{SI}/msg/EntityCategory", category=c) for c in categories],
            tags=msg(f"{SI}/msg/TagsFilter", tags=list(tags), filter_mode=0),
            bounds=msg(f"{SI}/msg/Bounds", type=0, points=[]),
        )  # fmt: skip
        return call(ros, "GetEntities", filters=filters)

    assert list(entities().entities) == ["burger_1", "burger_2", "waffle_1"]
    assert list(entities("^burger").entities) == ["burger_1", "burger_2"]
    assert list(entities(categories=(1,)).entities) == ["burger_1", "burger_2", "waffle_1"]
    assert list(entities(categories=(2,)).entities) == []  # no humans here
    assert entities(tags=("red",)).result.result == FEATURE_UNSUPPORTED
    assert entities("([").result.result == OPERATION_FAILED
    s = call(ros, "GetEntityState", entity="burger_2")
    assert s.result.result == OK
    p = s.state.pose.position
    assert (p.x, p.y) == pytest.approx((0.5, -2.0))
    assert s.state.header.frame_id == "world"
    assert call(ros, "GetEntityState", entity="nobody").result.result == NOT_FOUND
    r = call(ros, "DeleteEntity", entity="burger_2")
    assert r.result.result == OK
    assert call(ros, "DeleteEntity", entity="burger_2").result.result == NOT_FOUND


def test_simulation_state_step_and_reset(ros: RosDomain) -> None:
    c = ros.daemon.client()
    assert spawn(ros, "tb3_0", -2.0, -0.5, uri="model://turtlebot3_burger").result.result == OK
    assert sim_state(ros) == PLAYING
    assert call(ros, "StepSimulation", steps=1).result.result == OPERATION_FAILED  # not paused
    assert set_state(ros, PLAYING).result == 101  # ALREADY_IN_TARGET_STATE
    assert set_state(ros, PAUSED).result == OK
    assert sim_state(ros) == PAUSED and c.clock().paused
    before = c.clock().tick
    assert call(ros, "StepSimulation", steps=30).result.result == OK
    assert c.clock().tick == before + 30
    assert call(ros, "StepSimulation", steps=0).result.result == OPERATION_FAILED
    assert set_state(ros, QUITTING).result == FEATURE_UNSUPPORTED
    assert ros.daemon.alive()
    assert set_state(ros, STOPPED).result == OK  # paused and back to the start
    clock = c.clock()
    assert clock.paused and clock.tick == 0
    assert set_state(ros, PLAYING).result == OK
    assert sim_state(ros) == PLAYING
    assert call(ros, "ResetSimulation", scope=1).result.result == FEATURE_UNSUPPORTED  # time alone
    assert [r.name for r in c.robots()] == ["tb3_0"]
    assert call(ros, "ResetSimulation", scope=3).result.result == OK  # time and state: robots stay
    assert [r.name for r in c.robots()] == ["tb3_0"]
    assert call(ros, "ResetSimulation", scope=0).result.result == OK  # everything: the spawned go too
    assert c.robots() == []


def test_lockstep_cannot_be_played(ros_factory: Any) -> None:
    ros = ros_factory("--lockstep")
    assert sim_state(ros) == PAUSED
    r = set_state(ros, PLAYING)
    assert r.result == 102 and "lockstep" in r.error_message  # STATE_TRANSITION_ERROR
    assert call(ros, "StepSimulation", steps=3000).result.result == OK  # 100 s of sim time, in slices
    assert ros.daemon.client().clock().tick == 3000


# -- simulation_interfaces 2.x (Lyrical, Rolling) -------------------------------------------------


def _call2(ros: RosDomain, srv: str, **fields: Any) -> Any:
    """A call as a Rolling tool makes it: its own (2.x) types."""
    snake = "".join(f"_{c.lower()}" if c.isupper() else c for c in srv).lstrip("_")
    typename = f"{SI}/srv/{srv}"
    return ros.tool.call(f"/fleetsim/{snake}", typename, ros.tool.msg(f"{typename}_Request", **fields))


def _spawn2(ros: RosDomain, name: str, x: float, y: float, *, uri: str = "", resource: str = "") -> Any:
    t = ros.tool
    header = t.msg("std_msgs/msg/Header", stamp=t.msg("builtin_interfaces/msg/Time", sec=0, nanosec=0), frame_id="")
    pose = t.msg("geometry_msgs/msg/Pose", position=t.msg("geometry_msgs/msg/Point", x=x, y=y, z=0.0),
                 orientation=t.msg("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0))  # fmt: skip
    return _call2(
        ros, "SpawnEntity", name=name, allow_renaming=False,
        entity_resource=t.msg(f"{SI}/msg/Resource", uri=uri, resource_string=resource), entity_namespace="",
        initial_pose=t.msg("geometry_msgs/msg/PoseStamped", header=header, pose=pose),
    )  # fmt: skip


def test_rolling_gets_simulation_interfaces_2(ros_factory: Any) -> None:
    """A Rolling client sends 2.x requests (a Resource, SetEntityState's flags) and reads 2.x
    answers; a Jazzy client in the same domain finds the services by name and type, and its
    1.x call goes to a key nobody serves (the hang the daemon avoids by serving each distro
    its own version)."""
    ros = ros_factory(distro="rolling")
    sdf = (DATA / "turtlebot3_burger.sdf").read_text()
    r = _spawn2(ros, "tb3_0", -2.0, -0.5, resource=sdf)
    assert (r.result.result, r.entity_name) == (OK, "tb3_0")
    r = _spawn2(ros, "tb3_1", 0.5, -2.0, uri="model://turtlebot3_waffle")
    assert (r.result.result, r.entity_name) == (OK, "tb3_1")
    assert _spawn2(ros, "tb3_2", 2.0, 0.5).result.result == 104  # NO_RESOURCE
    models = {r.name: r.model for r in ros.daemon.client().robots()}
    assert models == {"tb3_0": "burger", "tb3_1": "waffle"}
    spawnables = _call2(ros, "GetSpawnables", sources=[])
    assert [s.entity_resource.uri for s in spawnables.spawnables] == [
        f"model://turtlebot3_{m}" for m in ("burger", "waffle", "waffle_pi")
    ]
    t = ros.tool
    v3 = {"x": 0.0, "y": 0.0, "z": 0.0}
    state = t.msg(
        f"{SI}/msg/EntityState",
        header=t.msg("std_msgs/msg/Header", stamp=t.msg("builtin_interfaces/msg/Time", sec=0, nanosec=0), frame_id=""),
        pose=t.msg("geometry_msgs/msg/Pose", position=t.msg("geometry_msgs/msg/Point", **v3),
                   orientation=t.msg("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0)),
        twist=t.msg("geometry_msgs/msg/Twist", linear=t.msg("geometry_msgs/msg/Vector3", **v3),
                    angular=t.msg("geometry_msgs/msg/Vector3", **v3)),
        acceleration=t.msg("geometry_msgs/msg/Accel", linear=t.msg("geometry_msgs/msg/Vector3", **v3),
                           angular=t.msg("geometry_msgs/msg/Vector3", **v3)),
    )  # fmt: skip
    moved = _call2(ros, "SetEntityState", entity="tb3_0", state=state, set_pose=True, set_twist=False,
                   set_acceleration=False)  # fmt: skip
    assert moved.result.result == FEATURE_UNSUPPORTED
    assert _call2(ros, "GetSimulationState", structure_needs_at_least_one_member=0).result.result == OK
    jazzy = StandIn(ros.router, 0, "jazzy")
    try:
        assert wait_until(lambda: jazzy.service_available("/fleetsim/spawn_entity", f"{SI}/srv/SpawnEntity"), 10.0)
        request = msg(f"{SI}/srv/SpawnEntity_Request", name="tb3_9", allow_renaming=False, uri="model://turtlebot3_burger",
                      resource_string="", entity_namespace="", initial_pose=stamped(2.0, 0.5))  # fmt: skip
        with pytest.raises(TimeoutError):
            jazzy.call("/fleetsim/spawn_entity", f"{SI}/srv/SpawnEntity", request, timeout=1.0)
    finally:
        jazzy.close()
    assert sorted(r.name for r in ros.daemon.client().robots()) == ["tb3_0", "tb3_1"]
