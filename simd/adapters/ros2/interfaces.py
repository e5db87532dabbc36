"""ROS 2 interface types: CDR through rosbags, the names and type hashes rmw_zenoh puts in keys.

rosbags' stores know the standard messages (nav_msgs, sensor_msgs, tf2_msgs, action_msgs' and
rcl_interfaces' messages, ...). The services the daemon serves (gazebo_msgs' SpawnEntity and
DeleteEntity, simulation_interfaces' standard simulator services, action_msgs' CancelGoal,
rcl_interfaces' parameter services) and the action (nav2_msgs' NavigateToPose) are registered
here from their definitions, written as rosidl reads them (field types, names and order;
comments and constants left out, as the hashes and CDR ignore them).

An action is no type of its own on the wire: rosidl turns ``pkg/action/A`` into messages
(``A_Goal``, ``A_Result``, ``A_Feedback``, ``A_FeedbackMessage``) and two services
(``A_SendGoal``, ``A_GetResult``), which rmw_zenoh carries as any other; their hashes are those
of the synthesised types (checked against rosidl's own for test_msgs' Fibonacci in the tests).

What a distro ships decides both a type's hash and its CDR layout, so every store here is one
distro's: simulation_interfaces is 1.x on Humble, Jazzy and Kilted and 2.x on Lyrical and Rolling
(2.0 moved a spawn's ``uri`` and ``resource_string`` into a ``Resource``, 2.1 gave SetEntityState
its ``set_*`` flags), and Nav2's NavigateToPose feedback grew two fields on Lyrical and Rolling. A
client of another version finds the service (rmw_zenoh matches servers by name and type name
only) and then waits forever on a key nobody serves.

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

Distro = Literal["humble", "jazzy", "kilted", "lyrical", "rolling"]
DISTROS: tuple[Distro, ...] = ("humble", "jazzy", "kilted", "lyrical", "rolling")
HUMBLE_HASH = "TypeHashNotSupported"

#: rosbags' store of each distro's standard messages (Rolling's are Lyrical's: the messages served
#: here did not change since)
_STORES: dict[Distro, Stores] = {
    "humble": Stores.ROS2_HUMBLE,
    "jazzy": Stores.ROS2_JAZZY,
    "kilted": Stores.ROS2_KILTED,
    "lyrical": Stores.ROS2_LYRICAL,
    "rolling": Stores.ROS2_LYRICAL,
}

#: the simulation_interfaces each distro ships (ros2-gbp/simulation_interfaces-release: humble
#: 1.4.0, jazzy 1.5.1, kilted 1.6.1, lyrical and rolling 2.1.0; a 2.0.0 that went to every distro
#: in July 2025 was replaced by the 1.x releases on the three older ones)
SIMULATION_INTERFACES: dict[Distro, str] = {
    "humble": "1.4.0", "jazzy": "1.5.1", "kilted": "1.6.1", "lyrical": "2.1.0", "rolling": "2.1.0",
}  # fmt: skip

CmdVel = Literal["twist", "stamped", "both"]
#: the cmd_vel type a distro's tools publish by default: Twist up to Jazzy (teleop_twist_keyboard,
#: Nav2's ``enable_stamped_cmd_vel`` false), TwistStamped from Kilted on (both default to stamped)
CMD_VEL_DEFAULT: dict[Distro, CmdVel] = {
    "humble": "twist", "jazzy": "twist", "kilted": "stamped", "lyrical": "stamped", "rolling": "stamped",
}  # fmt: skip

#: gazebo_msgs (ros-simulation/gazebo_ros_pkgs, the same fields in Humble and on the ros2 branch)
SERVICES: dict[str, tuple[str, str]] = {
    "gazebo_msgs/srv/SpawnEntity": (
        "string name\nstring xml\nstring robot_namespace\ngeometry_msgs/Pose initial_pose\nstring reference_frame",
        "bool success\nstring status_message",
    ),
    "gazebo_msgs/srv/DeleteEntity": ("string name", "bool success\nstring status_message"),
}

#: simulation_interfaces 1.x (ros-simulation/simulation_interfaces, branch jazzy, 1.5.1; the humble
#: and kilted branches define the same): the messages its services use, then the services
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

#: what simulation_interfaces 2.x (branch main, 2.1.0) changed: a ``Resource`` (a URI or the text
#: itself) where a spawn and a spawnable had ``uri`` and ``resource_string``, and SetEntityState's
#: flags saying which parts of the state to set
_RESOURCE = "simulation_interfaces/Resource"
SIMULATION_MESSAGES_2: dict[str, str] = {
    **SIMULATION_MESSAGES,
    "simulation_interfaces/msg/Resource": "string uri\nstring resource_string",
    "simulation_interfaces/msg/Spawnable": (
        f"{_RESOURCE} entity_resource\nstring description\nsimulation_interfaces/Bounds spawn_bounds"
    ),
}
SIMULATION_SERVICES_2: dict[str, tuple[str, str]] = {
    **SIMULATION_SERVICES,
    "simulation_interfaces/srv/SpawnEntity": (
        f"string name\nbool allow_renaming\n{_RESOURCE} entity_resource\nstring entity_namespace\n"
        "geometry_msgs/PoseStamped initial_pose",
        f"{_RESULT}\nstring entity_name",
    ),
    "simulation_interfaces/srv/SetEntityState": (
        "string entity\nsimulation_interfaces/EntityState state\nbool set_pose\nbool set_twist\nbool set_acceleration",
        _RESULT,
    ),
}


def simulation_interfaces(distro: Distro) -> tuple[dict[str, str], dict[str, tuple[str, str]]]:
    """The messages and services of the simulation_interfaces ``distro`` ships."""
    if SIMULATION_INTERFACES[distro].startswith("1."):
        return SIMULATION_MESSAGES, SIMULATION_SERVICES
    return SIMULATION_MESSAGES_2, SIMULATION_SERVICES_2


#: rcl_interfaces' parameter services, which every rclcpp node serves (ros2/rcl_interfaces, the
#: same in every distro served here; their messages are in rosbags' stores)
PARAMETER_SERVICES: dict[str, tuple[str, str]] = {
    "rcl_interfaces/srv/DescribeParameters": ("string[] names", "rcl_interfaces/ParameterDescriptor[] descriptors"),
    "rcl_interfaces/srv/GetParameterTypes": ("string[] names", "uint8[] types"),
    "rcl_interfaces/srv/GetParameters": ("string[] names", "rcl_interfaces/ParameterValue[] values"),
    "rcl_interfaces/srv/ListParameters": (
        "string[] prefixes\nuint64 depth",
        "rcl_interfaces/ListParametersResult result",
    ),
    "rcl_interfaces/srv/SetParameters": (
        "rcl_interfaces/Parameter[] parameters",
        "rcl_interfaces/SetParametersResult[] results",
    ),
    "rcl_interfaces/srv/SetParametersAtomically": (
        "rcl_interfaces/Parameter[] parameters",
        "rcl_interfaces/SetParametersResult result",
    ),
}


#: nav2_msgs' NavigateToPose (ros-navigation/navigation2, nav2_msgs/action/NavigateToPose.action):
#: (goal, result, feedback) per distro. Jazzy's result (and Kilted's: only its constants differ,
#: which neither the hash nor CDR sees) is an error code and message; Humble's is std_msgs/Empty.
#: Lyrical's and Rolling's feedback adds the robot's distance and heading off its path.
NAVIGATE_TO_POSE = "nav2_msgs/action/NavigateToPose"
_NAV_GOAL = "geometry_msgs/PoseStamped pose\nstring behavior_tree"
_NAV_FEEDBACK = (
    "geometry_msgs/PoseStamped current_pose\nbuiltin_interfaces/Duration navigation_time\n"
    "builtin_interfaces/Duration estimated_time_remaining\nint16 number_of_recoveries\nfloat32 distance_remaining"
)
_NAV_RESULT = "uint16 error_code\nstring error_msg"
_NAV_FEEDBACK_TRACKING = f"{_NAV_FEEDBACK}\nfloat32 position_tracking_error\nfloat32 heading_tracking_error"
ACTIONS: dict[Distro, dict[str, tuple[str, str, str]]] = {
    "humble": {NAVIGATE_TO_POSE: (_NAV_GOAL, "std_msgs/Empty result", _NAV_FEEDBACK)},
    "jazzy": {NAVIGATE_TO_POSE: (_NAV_GOAL, _NAV_RESULT, _NAV_FEEDBACK)},
    "kilted": {NAVIGATE_TO_POSE: (_NAV_GOAL, _NAV_RESULT, _NAV_FEEDBACK)},
    "lyrical": {NAVIGATE_TO_POSE: (_NAV_GOAL, _NAV_RESULT, _NAV_FEEDBACK_TRACKING)},
    "rolling": {NAVIGATE_TO_POSE: (_NAV_GOAL, _NAV_RESULT, _NAV_FEEDBACK_TRACKING)},
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
    messages, services = simulation_interfaces(distro)
    for name, text in messages.items():
        store.register(get_types_from_msg(text, name))
    for name, (req, resp) in {**SERVICES, **services, **ACTION_SERVICES, **PARAMETER_SERVICES}.items():
        store.register(service_definitions(name, req, resp, with_event=with_event))
    for name, (goal, result, feedback) in ACTIONS[distro].items():
        store.register(action_definitions(name, goal, result, feedback, with_event=with_event))
    return store


@functools.lru_cache(maxsize=len(DISTROS))
def typestore(distro: Distro) -> Typestore:
    """The store that serializes and deserializes: the distro's messages, our services and actions."""
    return _register_ours(get_typestore(_STORES[distro]), distro, with_event=False)


@functools.lru_cache(maxsize=len(DISTROS))
def _hashing_store(distro: Distro = "jazzy") -> Typestore:
    base = get_typestore(_STORES[distro])
    store = get_typestore(Stores.EMPTY)
    store.register({k: v for k, v in base.fielddefs.items() if k != "service_msgs/msg/ServiceEventInfo"})
    store.register(get_types_from_msg(_SERVICE_EVENT_INFO, "service_msgs/msg/ServiceEventInfo"))
    return _register_ours(store, distro, with_event=True)


def rihs01(typename: str, store: Typestore | None = None) -> str:
    """REP-2011 hash of a message or service type, ``RIHS01_<64 hex>`` (Jazzy's definitions
    unless ``store`` says otherwise)."""
    return (store or _hashing_store()).hash_rihs01(typename)


@functools.lru_cache(maxsize=512)
def type_hash(typename: str, distro: Distro) -> str:
    """What rmw_zenoh of ``distro`` puts in keys and tokens for ``typename``."""
    return HUMBLE_HASH if distro == "humble" else rihs01(typename, _hashing_store(distro))


def dds_type_name(typename: str) -> str:
    """``pkg/msg/Name`` -> ``pkg::msg::dds_::Name_`` (a service by its own name, no _Request; an
    action's parts as ``pkg::action::dds_::A_SendGoal_``)."""
    pkg, kind, name = typename.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"
