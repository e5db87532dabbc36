"""ROS 2 interface types: CDR through rosbags, the names and type hashes rmw_zenoh puts in keys.

rosbags' stores know the standard messages (nav_msgs, sensor_msgs, tf2_msgs, ...). The
services the daemon serves (gazebo_msgs' SpawnEntity and DeleteEntity) are registered here
from their definitions, written as rosidl reads them.

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


def _store(distro: Distro) -> Typestore:
    return get_typestore(Stores.ROS2_HUMBLE if distro == "humble" else Stores.ROS2_JAZZY)


@functools.lru_cache(maxsize=4)
def typestore(distro: Distro) -> Typestore:
    """The store that serializes and deserializes: the distro's messages and our services."""
    store = _store(distro)
    for name, (req, resp) in SERVICES.items():
        store.register(service_definitions(name, req, resp, with_event=False))
    return store


@functools.lru_cache(maxsize=1)
def _hashing_store() -> Typestore:
    base = get_typestore(Stores.ROS2_JAZZY)
    store = get_typestore(Stores.EMPTY)
    store.register({k: v for k, v in base.fielddefs.items() if k != "service_msgs/msg/ServiceEventInfo"})
    store.register(get_types_from_msg(_SERVICE_EVENT_INFO, "service_msgs/msg/ServiceEventInfo"))
    for name, (req, resp) in SERVICES.items():
        store.register(service_definitions(name, req, resp, with_event=True))
    return store


def rihs01(typename: str, store: Typestore | None = None) -> str:
    """REP-2011 hash of a message or service type, ``RIHS01_<64 hex>``."""
    return (store or _hashing_store()).hash_rihs01(typename)


def type_hash(typename: str, distro: Distro) -> str:
    """What rmw_zenoh of ``distro`` puts in keys and tokens for ``typename``."""
    return HUMBLE_HASH if distro == "humble" else rihs01(typename)


def dds_type_name(typename: str) -> str:
    """``pkg/msg/Name`` -> ``pkg::msg::dds_::Name_`` (a service by its own name, no _Request)."""
    pkg, kind, name = typename.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"
