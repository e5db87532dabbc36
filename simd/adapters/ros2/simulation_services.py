"""The standard simulator services (simulation_interfaces, the API Gazebo, Isaac Sim and O3DE
implement), under ``/fleetsim/<name>`` as Gazebo serves them under ``/gzserver/<name>``.

Each distro gets the version it ships (interfaces.py): 1.x on Humble, Jazzy and Kilted, 2.x on
Lyrical and Rolling, where a spawn and a spawnable carry their ``uri`` and ``resource_string`` in
an ``entity_resource`` and SetEntityState has ``set_*`` flags. The handlers read and answer both
layouts; the request decoded and the response built are those of the daemon's distro.

What fleetsim supports is what ``get_simulator_features`` lists: spawning (from an SDF or URDF
text, or a ``model://turtlebot3_<model>`` URI) and deleting, listing entities with a name
filter and the robot category, reading an entity's ground-truth state, getting and setting the
simulation state (playing, paused, stopped), stepping while paused, resetting (time and state
together, and the spawned robots), and the three spawnable TurtleBot3 models. Setting an
entity's state, tags and bounds filters are not supported and say so with
``RESULT_FEATURE_UNSUPPORTED``. Every refusal is a ``Result`` code with a message; the call
never hangs.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from typing import Any

from protocol.control import (
    ClockRequest,
    DeleteRequest,
    ListRequest,
    PauseRequest,
    ResetRequest,
    ResumeRequest,
    RobotList,
    RobotRecord,
    SpawnRequest,
    StepReply,
    StepRequest,
)
from protocol.errors import ErrorCode, FleetError
from simd.adapters.ros2 import gazebo_services as gz
from simd.adapters.ros2.service_server import Call, Service
from simd.adapters.ros2.shared_fleet import Message
from simd.core.models import MODELS

PREFIX = "/fleetsim"
PKG = "simulation_interfaces"

# Result codes (simulation_interfaces/msg/Result) and the services' own
FEATURE_UNSUPPORTED, OK, NOT_FOUND, INCORRECT_STATE, OPERATION_FAILED = 0, 1, 2, 3, 4
NAME_NOT_UNIQUE, NAME_INVALID, UNSUPPORTED_FORMAT, NO_RESOURCE, NAMESPACE_INVALID = 101, 102, 103, 104, 105
RESOURCE_PARSE_ERROR, INVALID_POSE = 106, 109
ALREADY_IN_TARGET_STATE, STATE_TRANSITION_ERROR, INCORRECT_TRANSITION = 101, 102, 103
# SimulationState
STOPPED, PLAYING, PAUSED, QUITTING = 0, 1, 2, 3
# ResetSimulation scopes
SCOPE_DEFAULT, SCOPE_TIME, SCOPE_STATE, SCOPE_SPAWNED, SCOPE_ALL = 0, 1, 2, 4, 255
CATEGORY_ROBOT = 1
BOUNDS_EMPTY, BOUNDS_BOX = 0, 1
SPAWNABLE = f"{PKG}/msg/Spawnable"

#: SimulatorFeatures ids of what is implemented here
FEATURES = [
    0,  # SPAWNING
    1,  # DELETING
    8,  # ENTITY_CATEGORIES (every entity is a robot)
    9,  # SPAWNING_RESOURCE_STRING
    10,  # ENTITY_STATE_GETTING
    14,  # SPAWNABLES
    20,  # SIMULATION_RESET
    23,  # SIMULATION_RESET_SPAWNED
    24,  # SIMULATION_STATE_GETTING
    25,  # SIMULATION_STATE_SETTING
    26,  # SIMULATION_STATE_PAUSE
    31,  # STEP_SIMULATION_SINGLE
    32,  # STEP_SIMULATION_MULTIPLE
]
#: how tall each model stands (the spawnables' bounds; the 2D footprint gives x and y)
HEIGHT = {"burger": 0.192, "waffle": 0.141, "waffle_pi": 0.141}
#: names tried for a spawn with allow_renaming, after the one asked for
MAX_RENAMES = 100
_URI_MODEL = re.compile(r"turtlebot3_(burger|waffle_pi|waffle)\b")


def _result(call: Call, code: int, message: str = "") -> Any:
    return call.make(f"{PKG}/msg/Result", result=code, error_message=message)


def _answer(call: Call, code: int, message: str = "", **fields: Any) -> None:
    call.respond(result=_result(call, code, message), **fields)


def _failed(call: Call, message: str) -> None:
    _answer(call, OPERATION_FAILED, message)


# -- spawn and delete -------------------------------------------------------------------------


def _spawn_code(err: FleetError) -> int:
    if err.code in (ErrorCode.INVALID_NAME, ErrorCode.RESERVED_NAME, ErrorCode.ALREADY_EXISTS):
        if err.field == "namespace":
            return NAMESPACE_INVALID
        return NAME_NOT_UNIQUE if err.code == ErrorCode.ALREADY_EXISTS else NAME_INVALID
    if err.code in (ErrorCode.NON_FINITE, ErrorCode.OUT_OF_BOUNDS, ErrorCode.COLLISION):
        return INVALID_POSE
    if err.code == ErrorCode.UNKNOWN_MODEL:
        return UNSUPPORTED_FORMAT
    return OPERATION_FAILED


def model_from(uri: str, resource: str) -> str:
    """The model a spawn names, by its resource text first, else its URI; or gz.Refused with a code."""
    if resource:
        try:
            return gz.model_of(resource)
        except gz.Refused as e:
            code = RESOURCE_PARSE_ERROR if str(e).startswith("Failed to") else UNSUPPORTED_FORMAT
            raise _Refusal(code, str(e)) from None
    if uri:
        m = _URI_MODEL.search(uri)
        if m is None:
            raise _Refusal(
                UNSUPPORTED_FORMAT, f"fleetsim spawns model://turtlebot3_burger, _waffle or _waffle_pi, not {uri!r}"
            )
        return m.group(1)
    raise _Refusal(NO_RESOURCE, "give uri (model://turtlebot3_burger) or resource_string (an SDF or URDF text)")


class _Refusal(Exception):
    def __init__(self, code: int, message: str) -> None:
        super().__init__(message)
        self.code = code


def _resource(msg: Any) -> tuple[str, str]:
    """(uri, resource_string) of a SpawnEntity request: its own fields in 1.x, its
    ``entity_resource``'s in 2.x."""
    holder = getattr(msg, "entity_resource", msg)
    return str(holder.uri), str(holder.resource_string)


def spawn_entity(call: Call) -> None:
    msg = call.request
    try:
        model = model_from(*_resource(msg))
        pose = msg.initial_pose
        if pose.header.frame_id not in ("", "world", "map", "/map"):
            raise _Refusal(INVALID_POSE, f"initial_pose is in frame {pose.header.frame_id!r}; fleetsim knows world")
        p, q = pose.pose.position, pose.pose.orientation
        if not all(math.isfinite(v) for v in (p.x, p.y, p.z, q.x, q.y, q.z, q.w)):
            raise _Refusal(INVALID_POSE, "initial_pose is not finite")
        rename = bool(msg.allow_renaming)
        name = str(msg.name)
        if not name:
            if not rename:
                raise _Refusal(NAME_INVALID, "give a name, or allow_renaming to let fleetsim pick one")
            name = model
        namespace = str(msg.entity_namespace).strip("/") or None
    except _Refusal as e:
        return _answer(call, e.code, str(e), entity_name="")
    yaw = gz.yaw_of(q.x, q.y, q.z, q.w)

    def attempt(n: int) -> None:
        candidate = name if n == 0 else f"{name}_{n}"
        req = SpawnRequest(name=candidate, namespace=namespace, model=model, x=float(p.x), y=float(p.y), yaw=yaw)

        def then(result: Message | FleetError) -> None:
            if isinstance(result, FleetError):
                taken = result.code == ErrorCode.ALREADY_EXISTS and result.field == "name"
                if rename and taken and n < MAX_RENAMES:
                    return attempt(n + 1)
                return _answer(call, _spawn_code(result), result.message, entity_name="")
            _answer(call, OK, entity_name=candidate)

        call.ask(req, then)

    attempt(0)


def delete_entity(call: Call) -> None:
    def then(result: Message | FleetError) -> None:
        if isinstance(result, FleetError):
            return _answer(call, NOT_FOUND if result.code == ErrorCode.NOT_FOUND else OPERATION_FAILED, result.message)
        _answer(call, OK)

    if not call.request.entity:
        return _answer(call, NOT_FOUND, "no entity named ''")
    call.ask(DeleteRequest(name=str(call.request.entity)), then)


# -- entities ---------------------------------------------------------------------------------


def _listed(call: Call, use: Callable[[RobotList], None]) -> None:
    def then(result: Message | FleetError) -> None:
        if isinstance(result, FleetError):
            return _failed(call, result.message)
        assert isinstance(result, RobotList)
        use(result)

    call.ask(ListRequest(), then)


def get_entities(call: Call) -> None:
    f = call.request.filters
    if len(f.tags.tags):
        return _answer(call, FEATURE_UNSUPPORTED, "fleetsim entities carry no tags", entities=[])
    if f.bounds.type != BOUNDS_EMPTY:
        return _answer(call, FEATURE_UNSUPPORTED, "fleetsim filters no bounds", entities=[])
    try:
        pattern = re.compile(str(f.filter)) if f.filter else None
    except re.error as e:
        return _answer(call, OPERATION_FAILED, f"filter is not a regular expression: {e}", entities=[])
    robots_wanted = not len(f.categories) or any(c.category == CATEGORY_ROBOT for c in f.categories)

    def use(listed: RobotList) -> None:
        names = [r.name for r in listed.robots if robots_wanted and (pattern is None or pattern.search(r.name))]
        _answer(call, OK, entities=names)

    _listed(call, use)


def _state(call: Call, robot: RobotRecord, t: float) -> Any:
    """The entity's state from the fleet's record of it (world frame; the record's velocities are the body's)."""
    m = "geometry_msgs/msg/"
    x, y, yaw = robot.pose.x, robot.pose.y, robot.pose.yaw
    c, s = math.cos(yaw), math.sin(yaw)
    v, lat = robot.linear_velocity, robot.lateral_velocity
    sec, ns = divmod(round(t * 1e9), 1_000_000_000)
    return call.make(
        f"{PKG}/msg/EntityState",
        header=call.make("std_msgs/msg/Header", stamp=call.make("builtin_interfaces/msg/Time", sec=sec, nanosec=ns),
                         frame_id="world"),
        pose=call.make(m + "Pose", position=call.make(m + "Point", x=x, y=y, z=0.0),
                       orientation=call.make(m + "Quaternion", x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))),
        twist=call.make(m + "Twist", linear=call.make(m + "Vector3", x=v * c - lat * s, y=v * s + lat * c, z=0.0),
                        angular=call.make(m + "Vector3", x=0.0, y=0.0, z=robot.angular_velocity)),
        acceleration=call.make(m + "Accel", linear=call.make(m + "Vector3", x=0.0, y=0.0, z=0.0),
                               angular=call.make(m + "Vector3", x=0.0, y=0.0, z=0.0)),
    )  # fmt: skip


def get_entity_state(call: Call) -> None:
    entity = str(call.request.entity)

    def use(listed: RobotList) -> None:
        for r in listed.robots:
            if entity in (r.name, r.namespace, f"/{r.namespace}"):
                return _answer(call, OK, state=_state(call, r, listed.stamp.to_seconds()))
        _answer(call, NOT_FOUND, f"no entity named {entity!r}")

    _listed(call, use)


def set_entity_state(call: Call) -> None:
    _answer(call, FEATURE_UNSUPPORTED, "fleetsim does not move robots by hand: delete and spawn it at the new pose")


# -- simulation state -------------------------------------------------------------------------


def get_simulation_state(call: Call) -> None:
    def then(result: Message | FleetError) -> None:
        if isinstance(result, FleetError):
            return _failed(call, result.message)
        state = PAUSED if getattr(result, "paused", False) else PLAYING
        _answer(call, OK, state=call.make(f"{PKG}/msg/SimulationState", state=state))

    call.ask(ClockRequest(), then)


def set_simulation_state(call: Call) -> None:
    target = int(call.request.state.state)
    if target == QUITTING:
        return _answer(call, FEATURE_UNSUPPORTED, "fleetsim is not stopped by a ROS client: send simd SIGINT")
    if target not in (STOPPED, PLAYING, PAUSED):
        return _answer(call, INCORRECT_TRANSITION, f"fleetsim always has its world loaded (state {target})")

    def done(result: Message | FleetError) -> None:
        if isinstance(result, FleetError):
            return _answer(call, STATE_TRANSITION_ERROR, result.message)
        _answer(call, OK)

    def now(result: Message | FleetError) -> None:
        if isinstance(result, FleetError):
            return _failed(call, result.message)
        paused = bool(getattr(result, "paused", False))
        if target == PLAYING:
            if not paused:
                return _answer(call, ALREADY_IN_TARGET_STATE, "already playing")
            return call.ask(ResumeRequest(), done)
        if target == PAUSED:
            if paused:
                return _answer(call, ALREADY_IN_TARGET_STATE, "already paused")
            return call.ask(PauseRequest(), done)
        # STOPPED: paused and reset (time zero, robots at their spawn poses)
        call.ask(PauseRequest(), lambda r: done(r) if isinstance(r, FleetError) else call.ask(ResetRequest(), done))

    call.ask(ClockRequest(), now)


def step_simulation(call: Call) -> None:
    steps = int(call.request.steps)
    if steps < 1:
        return _failed(call, "steps must be at least 1")

    def then(result: Message | FleetError) -> None:
        if isinstance(result, FleetError):
            return _failed(call, result.message)
        assert isinstance(result, StepReply)
        if result.cancelled:
            return _failed(call, f"cancelled after {result.ticks_run} of {steps} steps (paused, resumed or reset)")
        _answer(call, OK)

    call.ask(StepRequest(ticks=steps), then)


def reset_simulation(call: Call) -> None:
    scope = int(call.request.scope)
    if scope in (SCOPE_DEFAULT, SCOPE_ALL):
        scope = SCOPE_TIME | SCOPE_STATE | SCOPE_SPAWNED
    despawn = bool(scope & SCOPE_SPAWNED)
    time_state = scope & (SCOPE_TIME | SCOPE_STATE)
    if time_state not in (0, SCOPE_TIME | SCOPE_STATE) or scope & ~(SCOPE_TIME | SCOPE_STATE | SCOPE_SPAWNED):
        why = "fleetsim resets time and state together (SCOPE_TIME | SCOPE_STATE), and/or SCOPE_SPAWNED"
        return _answer(call, FEATURE_UNSUPPORTED, why)

    def reset(_: object = None) -> None:
        if not time_state:
            return _answer(call, OK)
        call.ask(ResetRequest(), lambda r: _failed(call, r.message) if isinstance(r, FleetError) else _answer(call, OK))

    if not despawn:
        return reset()

    def delete_all(listed: RobotList) -> None:
        names = [r.name for r in listed.robots]

        def next_one(_: object = None) -> None:
            if not names:
                return reset()
            call.ask(DeleteRequest(name=names.pop()), next_one)  # one gone already: go on

        next_one()

    _listed(call, delete_all)


# -- what fleetsim offers ---------------------------------------------------------------------


def get_simulator_features(call: Call) -> None:
    import numpy as np

    features = call.make(
        f"{PKG}/msg/SimulatorFeatures",
        features=np.array(FEATURES, dtype=np.uint16),
        spawn_formats=["sdf", "urdf"],
        custom_info="fleetsim: TurtleBot3 burger, waffle and waffle_pi in 2D; spawn by resource_string (the model's "
        "SDF or URDF) or uri model://turtlebot3_<model>; one step is 1/30 s",
    )
    call.respond(features=features)


def get_spawnables(call: Call) -> None:
    v3 = "geometry_msgs/msg/Vector3"
    spawnables = []
    for name, model in MODELS.items():
        (x0, y0), (x1, y1) = model.outline.min(axis=0), model.outline.max(axis=0)
        corners = [
            call.make(v3, x=float(x0), y=float(y0), z=0.0),
            call.make(v3, x=float(x1), y=float(y1), z=HEIGHT[name]),
        ]
        about = (
            f"TurtleBot3 {name}: LDS-01 lidar, ±{model.max_linear_velocity} m/s, ±{model.max_angular_velocity} rad/s"
        )
        bounds = call.make(f"{PKG}/msg/Bounds", type=BOUNDS_BOX, points=corners)
        uri = f"model://turtlebot3_{name}"
        if "entity_resource" in call.fields(SPAWNABLE):  # 2.x
            where = {"entity_resource": call.make(f"{PKG}/msg/Resource", uri=uri, resource_string="")}
        else:
            where = {"uri": uri}
        spawnables.append(call.make(SPAWNABLE, description=about, spawn_bounds=bounds, **where))
    _answer(call, OK, spawnables=spawnables)


def _malformed(call: Call, message: str) -> None:
    if "result" in call.response_fields:
        call.respond(result=_result(call, OPERATION_FAILED, message))
    else:  # GetSimulatorFeatures answers with its features only
        get_simulator_features(call)


def services() -> list[Service]:
    table: list[tuple[str, Callable[[Call], None]]] = [
        ("SpawnEntity", spawn_entity), ("DeleteEntity", delete_entity), ("GetEntities", get_entities),
        ("GetEntityState", get_entity_state), ("SetEntityState", set_entity_state),
        ("GetSimulationState", get_simulation_state), ("SetSimulationState", set_simulation_state),
        ("StepSimulation", step_simulation), ("ResetSimulation", reset_simulation),
        ("GetSimulatorFeatures", get_simulator_features), ("GetSpawnables", get_spawnables),
    ]  # fmt: skip
    return [Service(f"{PREFIX}/{_snake(srv)}", f"{PKG}/srv/{srv}", handler, _malformed) for srv, handler in table]


def _snake(name: str) -> str:
    return re.sub(r"(?<!^)(?=[A-Z])", "_", name).lower()
