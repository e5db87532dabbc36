"""ROS 2 interface types: CDR through rosbags, the names and type hashes rmw_zenoh puts in keys.

rosbags' stores know the standard messages (nav_msgs, sensor_msgs, tf2_msgs, action_msgs' messages,
...). The services the daemon serves (gazebo_msgs' SpawnEntity and DeleteEntity,
simulation_interfaces' standard simulator services, action_msgs' CancelGoal) and the action
(nav2_msgs' NavigateToPose) are registered here from their definitions, written as rosidl reads
them (field types, names and order; comments and constants left out, as the hashes and CDR
ignore them).

An action is no type of its own on the wire: rosidl turns ``pkg/action/A`` into messages
(``A_Goal``, ``A_Result``, ``A_Feedback``, ``A_FeedbackMessage``) and two services
(``A_SendGoal``, ``A_GetResult``), which rmw_zenoh carries as any other; their hashes are those
of the synthesised types (checked against rosidl's own for test_msgs' Fibonacci in the tests).

A key carries a type hash (REP-2011 ``RIHS01_``) on Iron and later; Humble's rmw_zenoh puts the
constant ``TypeHashNotSupported`` there instead. A service's hash covers what rosidl
synthesises beside the request and response (an ``_Event`` with ``ServiceEventInfo``), and
rosbags' own ``ServiceEventInfo`` declares ``client_gid`` as ``char[16]`` where rosidl hashes
``uint8[16]``: the hashing store replaces it, or every service hash comes out wrong.
"""

from __future__ import annotations

import functools
from typing import Any, Literal

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

Distro = Literal["jazzy", "humble"]
DISTROS: tuple[Distro, ...] = ("jazzy", "humble")
HUMBLE_HASH = "TypeHashNotSupported"

#: gazebo_msgs (ros-simulation/gazebo_ros_pkgs, the same fields in Humble and on the ros2 branch)
SERVICES: dict[str, tuple[str, str]] = {
    "gazebo_msgs/srv/SpawnEntity": (
        "string name\nstring xml\nstring robot_namespace\ngeometry_msgs/Pose initial_pose\nstring reference_frame",
        "bool success\nstring status_message",
    ),
    "gazebo_msgs/srv/DeleteEntity": ("string name", "bool success\nstring status_message"),
}

#: simulation_interfaces 1.5.1 (ros-simulation/simulation_interfaces, branch jazzy; the humble and
#: kilted branches define the same): the messages its services use, then the services
SIMULATION_MESSAGES: dict[str, str] = {
    "simulation_interfaces/msg/Result": "uint8 result\nstring error_message",
    "simulation_interfaces/msg/EntityCategory": "uint8 category",
    "simulation_interfaces/msg/TagsFilter": "string[] tags\nuint8 filter_mode",
    "simulation_interfaces/msg/Bounds": "uint8 type\ngeometry_msgs/Vector3[] points",
    "simulation_interfaces/msg/EntityFilters": (
        "string filter\nsimulation_interfaces/EntityCategory[] categories\nsimulation_interfaces/TagsFilter tags\n"
        "simulation_interfaces/Bounds bounds"
    ),
    "simulation_interfaces/msg/EntityState": (
        "std_msgs/Header header\ngeometry_msgs/Pose pose\ngeometry_msgs/Twist twist\ngeometry_msgs/Accel acceleration"
    ),
    "simulation_interfaces/msg/SimulationState": "uint8 state",
    "simulation_interfaces/msg/SimulatorFeatures": "uint16[] features\nstring[] spawn_formats\nstring custom_info",
    "simulation_interfaces/msg/Spawnable": "string uri\nstring description\nsimulation_interfaces/Bounds spawn_bounds",
}
_RESULT = "simulation_interfaces/Result result"
SIMULATION_SERVICES: dict[str, tuple[str, str]] = {
    "simulation_interfaces/srv/SpawnEntity": (
        "string name\nbool allow_renaming\nstring uri\nstring resource_string\nstring entity_namespace\n"
        "geometry_msgs/PoseStamped initial_pose",
        f"{_RESULT}\nstring entity_name",
    ),
    "simulation_interfaces/srv/DeleteEntity": ("string entity", _RESULT),
    "simulation_interfaces/srv/GetEntities": (
        "simulation_interfaces/EntityFilters filters",
        f"{_RESULT}\nstring[] entities",
    ),
    "simulation_interfaces/srv/GetEntityState": (
        "string entity",
        f"{_RESULT}\nsimulation_interfaces/EntityState state",
    ),
    "simulation_interfaces/srv/SetEntityState": ("string entity\nsimulation_interfaces/EntityState state", _RESULT),
    "simulation_interfaces/srv/GetSimulationState": ("", f"simulation_interfaces/SimulationState state\n{_RESULT}"),
    "simulation_interfaces/srv/SetSimulationState": ("simulation_interfaces/SimulationState state", _RESULT),
    "simulation_interfaces/srv/StepSimulation": ("uint64 steps", _RESULT),
    "simulation_interfaces/srv/ResetSimulation": ("uint8 scope", _RESULT),
    "simulation_interfaces/srv/GetSimulatorFeatures": ("", "simulation_interfaces/SimulatorFeatures features"),
    "simulation_interfaces/srv/GetSpawnables": (
        "string[] sources",
        f"{_RESULT}\nsimulation_interfaces/Spawnable[] spawnables",
    ),
}


#: nav2_msgs' NavigateToPose (ros-navigation/navigation2, nav2_msgs/action/NavigateToPose.action):
#: (goal, result, feedback) per distro. Jazzy's result (and Kilted's: only its constants differ,
#: which neither the hash nor CDR sees) is an error code and message; Humble's is std_msgs/Empty.
NAVIGATE_TO_POSE = "nav2_msgs/action/NavigateToPose"
_NAV_GOAL = "geometry_msgs/PoseStamped pose\nstring behavior_tree"
_NAV_FEEDBACK = (
    "geometry_msgs/PoseStamped current_pose\nbuiltin_interfaces/Duration navigation_time\n"
    "builtin_interfaces/Duration estimated_time_remaining\nint16 number_of_recoveries\nfloat32 distance_remaining"
)
ACTIONS: dict[Distro, dict[str, tuple[str, str, str]]] = {
    "jazzy": {NAVIGATE_TO_POSE: (_NAV_GOAL, "uint16 error_code\nstring error_msg", _NAV_FEEDBACK)},
    "humble": {NAVIGATE_TO_POSE: (_NAV_GOAL, "std_msgs/Empty result", _NAV_FEEDBACK)},
}
#: what every action server serves beside its own types (ros2/rcl_interfaces, action_msgs/srv)
ACTION_SERVICES: dict[str, tuple[str, str]] = {
    "action_msgs/srv/CancelGoal": (
        "action_msgs/GoalInfo goal_info",
        "int8 return_code\naction_msgs/GoalInfo[] goals_canceling",
    ),
}


#: rosidl's ServiceEventInfo, as hashed (uint8 client_gid, not rosbags' char)
_SERVICE_EVENT_INFO = """uint8 REQUEST_SENT = 0
uint8 REQUEST_RECEIVED = 1
uint8 RESPONSE_SENT = 2
uint8 RESPONSE_RECEIVED = 3
uint8 event_type
builtin_interfaces/Time stamp
uint8[16] client_gid
int64 sequence_number"""


def _srv_names(obj: Any) -> Any:
    """rosbags' msg parser files every type under ``msg/`` (``pkg/srv/X`` becomes
    ``pkg/srv/msg/X``); put service types back where rosidl has them."""
    if isinstance(obj, str):
        return obj.replace("/srv/msg/", "/srv/")
    if isinstance(obj, tuple | list):
        return type(obj)(_srv_names(o) for o in obj)
    return obj


def service_definitions(name: str, request: str, response: str, *, with_event: bool) -> dict[str, Any]:
    """The field definitions of a service's request and response (and, for hashing, of the
    ``_Event`` and the service type rosidl synthesises)."""
    texts = {f"{name}_Request": request, f"{name}_Response": response}
    if with_event:
        texts[f"{name}_Event"] = (
            f"service_msgs/msg/ServiceEventInfo info\n{name}_Request[<=1] request\n{name}_Response[<=1] response"
        )
        texts[name] = f"{name}_Request request_message\n{name}_Response response_message\n{name}_Event event_message"
    out: dict[str, Any] = {}
    for typename, text in texts.items():
        out.update({_srv_names(k): _srv_names(v) for k, v in get_types_from_msg(text, typename).items()})
    return out


def action_definitions(name: str, goal: str, result: str, feedback: str, *, with_event: bool) -> dict[str, Any]:
    """What rosidl makes of an action ``pkg/action/A`` (rosidl_parser's ``Action``): its goal,
    result and feedback, the feedback message (``goal_id`` and ``feedback``), the ``A_SendGoal``
    and ``A_GetResult`` services and, for hashing, the action type that holds them all."""
    uuid = "unique_identifier_msgs/UUID goal_id"
    texts = {
        f"{name}_Goal": goal,
        f"{name}_Result": result,
        f"{name}_Feedback": feedback,
        f"{name}_FeedbackMessage": f"{uuid}\n{name}_Feedback feedback",
    }
    if with_event:
        texts[name] = (
            f"{name}_Goal goal\n{name}_Result result\n{name}_Feedback feedback\n"
            f"{name}_SendGoal send_goal_service\n{name}_GetResult get_result_service\n"
            f"{name}_FeedbackMessage feedback_message"
        )
    out: dict[str, Any] = {}
    for typename, text in texts.items():
        out.update(get_types_from_msg(text, typename))
    send = f"{uuid}\n{name}_Goal goal", "bool accepted\nbuiltin_interfaces/Time stamp"
    out.update(service_definitions(f"{name}_SendGoal", *send, with_event=with_event))
    get = uuid, f"int8 status\n{name}_Result result"
    out.update(service_definitions(f"{name}_GetResult", *get, with_event=with_event))
    return out


def _register_ours(store: Typestore, distro: Distro, *, with_event: bool) -> Typestore:
    for name, text in SIMULATION_MESSAGES.items():
        store.register(get_types_from_msg(text, name))
    for name, (req, resp) in {**SERVICES, **SIMULATION_SERVICES, **ACTION_SERVICES}.items():
        store.register(service_definitions(name, req, resp, with_event=with_event))
    for name, (goal, result, feedback) in ACTIONS[distro].items():
        store.register(action_definitions(name, goal, result, feedback, with_event=with_event))
    return store


@functools.lru_cache(maxsize=4)
def typestore(distro: Distro) -> Typestore:
    """The store that serializes and deserializes: the distro's messages, our services and actions."""
    store = get_typestore(Stores.ROS2_HUMBLE if distro == "humble" else Stores.ROS2_JAZZY)
    return _register_ours(store, distro, with_event=False)


@functools.lru_cache(maxsize=1)
def _hashing_store() -> Typestore:
    base = get_typestore(Stores.ROS2_JAZZY)
    store = get_typestore(Stores.EMPTY)
    store.register({k: v for k, v in base.fielddefs.items() if k != "service_msgs/msg/ServiceEventInfo"})
    store.register(get_types_from_msg(_SERVICE_EVENT_INFO, "service_msgs/msg/ServiceEventInfo"))
    return _register_ours(store, "jazzy", with_event=True)


def rihs01(typename: str, store: Typestore | None = None) -> str:
    """REP-2011 hash of a message or service type, ``RIHS01_<64 hex>``."""
    return (store or _hashing_store()).hash_rihs01(typename)


@functools.lru_cache(maxsize=256)
def type_hash(typename: str, distro: Distro) -> str:
    """What rmw_zenoh of ``distro`` puts in keys and tokens for ``typename``."""
    return HUMBLE_HASH if distro == "humble" else rihs01(typename)


def dds_type_name(typename: str) -> str:
    """``pkg/msg/Name`` -> ``pkg::msg::dds_::Name_`` (a service by its own name, no _Request; an
    action's parts as ``pkg::action::dds_::A_SendGoal_``)."""
    pkg, kind, name = typename.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"
