"""``/spawn_entity`` and ``/delete_entity`` as gazebo_ros' factory answers them.

The TurtleBot3 spawner node sends the model file's whole text in ``xml`` (an SDF or a URDF),
an entity name, a robot namespace and a pose, and prints the ``status_message``. Here the
model is recognised from that text (``<model name="turtlebot3_burger">`` in the SDF,
``<robot name="turtlebot3_burger">`` in the URDF; burger, waffle and waffle_pi), the yaw is
read from the pose's quaternion, and the answer carries Gazebo's words for the same outcome
(``Entity [x] already exists.``, ``Entity [x] does not exist``, ...), so scripts that match on
them keep working. Whatever is wrong with a request comes back as ``success = false`` with a
status message: rclcpp never delivers an error reply to the caller, which would wait forever.
``xml`` is parsed by the standard library's expat, which refuses entity-expansion bombs.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from collections.abc import Callable
from typing import Any

from protocol.control import DeleteRequest, SpawnRequest
from protocol.errors import ErrorCode, FleetError
from simd.adapters.ros2.service_server import Call, Service
from simd.adapters.ros2.shared_fleet import Message

#: The largest ``xml`` accepted (a TurtleBot3 SDF is about 15 kB).
MAX_XML_BYTES = 1 << 20
#: How much of a bad ``xml`` a status message quotes back (Gazebo quotes all of it).
QUOTE_CHARS = 400

_MODEL_NAME = re.compile(r"^(?:turtlebot3_)?(burger|waffle_pi|waffle)(?:_.*)?$")
_REFERENCE_FRAMES = ("", "world", "map", "/map")


class Refused(Exception):
    """A request answered with ``success = false`` and this message."""


def _quote(text: str) -> str:
    return text if len(text) <= QUOTE_CHARS else text[:QUOTE_CHARS] + f"... ({len(text)} characters)"


def model_of(xml: str) -> str:
    """The TurtleBot3 model an SDF or URDF text describes, or :class:`Refused`."""
    if len(xml.encode()) > MAX_XML_BYTES:
        raise Refused(f"Failed to parse XML string: the xml is larger than {MAX_XML_BYTES} bytes")
    try:
        root = ET.fromstring(xml)
    except ET.ParseError as e:
        raise Refused(f"Failed to parse XML string: {e}\n{_quote(xml)}") from None
    element = root if root.tag in ("model", "robot") else root.find(".//model")
    if element is None:
        raise Refused(f"Failed to find a model or light on SDF: \n{_quote(xml)}")
    name = element.get("name", "")
    m = _MODEL_NAME.match(name)
    if m is None:
        raise Refused(
            f"fleetsim simulates the TurtleBot3 burger, waffle and waffle_pi; the {element.tag} in xml is named "
            f"[{name}] (expected turtlebot3_burger, turtlebot3_waffle or turtlebot3_waffle_pi)"
        )
    return m.group(1)


def yaw_of(qx: float, qy: float, qz: float, qw: float) -> float:
    """The rotation about z of a quaternion (all zeros reads as no rotation)."""
    return math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


def spawn_request(msg: Any) -> SpawnRequest:
    """A gazebo_msgs/srv/SpawnEntity_Request as the engine's request, or :class:`Refused`."""
    name = str(msg.name)
    if not name:
        raise Refused("fleetsim needs an entity name (Gazebo would queue a nameless entity; give name or -entity)")
    if msg.reference_frame not in _REFERENCE_FRAMES:
        raise Refused(
            f"Reference frame [{msg.reference_frame}] not found, did you forget to scope the link by model name?"
        )
    model = model_of(str(msg.xml))
    p, q = msg.initial_pose.position, msg.initial_pose.orientation
    numbers = (p.x, p.y, p.z, q.x, q.y, q.z, q.w)
    if not all(math.isfinite(v) for v in numbers):
        raise Refused("initial_pose is not finite")
    namespace = str(msg.robot_namespace).strip("/") or None
    return SpawnRequest(
        name=name, namespace=namespace, model=model, x=float(p.x), y=float(p.y), yaw=yaw_of(q.x, q.y, q.z, q.w)
    )


def spawn_failure(name: str, err: FleetError) -> str:
    """Gazebo's words for a refusal where it has them, ours otherwise."""
    if err.code == ErrorCode.ALREADY_EXISTS and err.field == "name":
        return f"Entity [{name}] already exists."
    return f"SpawnEntity: {err.message}"


def spawn_success(name: str) -> str:
    return f"SpawnEntity: Successfully spawned entity [{name}]"


def delete_request(msg: Any) -> DeleteRequest:
    name = str(msg.name)
    if not name:
        raise Refused("Entity [] does not exist")
    return DeleteRequest(name=name)


def delete_failure(name: str, err: FleetError) -> str:
    if err.code == ErrorCode.NOT_FOUND:
        return f"Entity [{name}] does not exist"
    return f"DeleteEntity: {err.message}"


def delete_success(name: str) -> str:
    return f"Successfully deleted entity [{name}]"


def _respond(call: Call, success: bool, message: str) -> None:
    call.respond(success=success, status_message=message)


def _serve(
    call: Call,
    to_request: Callable[[Any], SpawnRequest | DeleteRequest],
    ok: Callable[[str], str],
    failed: Callable[[str, FleetError], str],
) -> None:
    """Refuse what the request says wrong at once, else ask the engine and answer in Gazebo's words."""
    try:
        request = to_request(call.request)
    except Refused as e:
        return _respond(call, False, str(e))
    name = request.name

    def then(result: Message | FleetError) -> None:
        if isinstance(result, FleetError):
            return _respond(call, False, failed(name, result))
        _respond(call, True, ok(name))

    call.ask(request, then)


def spawn_entity(call: Call) -> None:
    _serve(call, spawn_request, spawn_success, spawn_failure)


def delete_entity(call: Call) -> None:
    _serve(call, delete_request, delete_success, delete_failure)


def _malformed(call: Call, message: str) -> None:
    _respond(call, False, message)


SERVICES = [
    Service("/spawn_entity", "gazebo_msgs/srv/SpawnEntity", spawn_entity, _malformed),
    Service("/delete_entity", "gazebo_msgs/srv/DeleteEntity", delete_entity, _malformed),
]
