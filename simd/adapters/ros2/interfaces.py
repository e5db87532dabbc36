"""ROS 2 interface types: CDR through rosbags, the names and type hashes rmw_zenoh puts in keys.

rosbags' stores know the standard messages (nav_msgs, sensor_msgs, tf2_msgs, ...). The
services the daemon serves (gazebo_msgs' SpawnEntity and DeleteEntity, simulation_interfaces'
standard simulator services) are registered here from their definitions, written as rosidl
reads them (field types, names and order; comments and constants left out, as the hashes
and CDR ignore them).

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


def _register_ours(store: Typestore, *, with_event: bool) -> Typestore:
    for name, text in SIMULATION_MESSAGES.items():
        store.register(get_types_from_msg(text, name))
    for name, (req, resp) in {**SERVICES, **SIMULATION_SERVICES}.items():
        store.register(service_definitions(name, req, resp, with_event=with_event))
    return store


@functools.lru_cache(maxsize=4)
def typestore(distro: Distro) -> Typestore:
    """The store that serializes and deserializes: the distro's messages and our services."""
    store = get_typestore(Stores.ROS2_HUMBLE if distro == "humble" else Stores.ROS2_JAZZY)
    return _register_ours(store, with_event=False)


@functools.lru_cache(maxsize=1)
def _hashing_store() -> Typestore:
    base = get_typestore(Stores.ROS2_JAZZY)
    store = get_typestore(Stores.EMPTY)
    store.register({k: v for k, v in base.fielddefs.items() if k != "service_msgs/msg/ServiceEventInfo"})
    store.register(get_types_from_msg(_SERVICE_EVENT_INFO, "service_msgs/msg/ServiceEventInfo"))
    return _register_ours(store, with_event=True)


def rihs01(typename: str, store: Typestore | None = None) -> str:
    """REP-2011 hash of a message or service type, ``RIHS01_<64 hex>``."""
    return (store or _hashing_store()).hash_rihs01(typename)


@functools.lru_cache(maxsize=256)
def type_hash(typename: str, distro: Distro) -> str:
    """What rmw_zenoh of ``distro`` puts in keys and tokens for ``typename``."""
    return HUMBLE_HASH if distro == "humble" else rihs01(typename)


def dds_type_name(typename: str) -> str:
    """``pkg/msg/Name`` -> ``pkg::msg::dds_::Name_`` (a service by its own name, no _Request)."""
    pkg, kind, name = typename.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"
