"""Fleet files: a YAML list of robots to spawn together (``fleet spawn --file``).

A fleet file is the declarative twin of a multi-robot launch file::

    - {name: burger_1, namespace: TB3_1, model: burger, x: -2.0, y: -0.5, yaw: 0.0}
    - {name: burger_2, namespace: TB3_2, model: burger, x: 0.5, y: -2.0}

Decoding is strict, as for world files: unknown fields and wrong types are errors that name
the file, the msgspec location (``$[1].yaw``) and, when it can be found, the line. Whether a
robot *can* spawn (name rules, model, pose, walls) is the daemon's call, not this module's;
only what the daemon cannot judge (two entries of the same file clashing) is checked here.

Fleets shipped with fleetsim live in ``clients/fleets/`` and are found by bare name
(``--file tb3_multi``); anything containing ``/`` or ending in ``.yaml``/``.yml`` is a path.
"""

from __future__ import annotations

import re
from pathlib import Path

import msgspec
import msgspec.yaml
import yaml

from fleetcommon.files import FileFormatError, ShippedFiles, split_location, yaml_syntax_problem

FLEETS_DIR = Path(__file__).parent / "fleets"


class FleetFileError(FileFormatError):
    """A fleet file that cannot be used: where (file, location, line) and why."""


class FleetRobot(msgspec.Struct, forbid_unknown_fields=True, frozen=True, kw_only=True):
    """One entry. ``namespace`` defaults to ``name``; ``model`` to the command's default."""

    name: str
    namespace: str | None = None
    model: str | None = None
    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0

    @property
    def effective_namespace(self) -> str:
        return self.namespace or self.name


SHIPPED_FLEETS = ShippedFiles("fleet", FLEETS_DIR, FleetFileError)


def load_fleet(name_or_path: str) -> list[FleetRobot]:
    """Load a shipped fleet by bare name or any fleet file by path; raise FleetFileError."""
    text, source = SHIPPED_FLEETS.read(name_or_path)
    if not text.strip():
        raise FleetFileError(source, "the file is empty; a fleet file is a YAML list of robots")
    try:
        robots = msgspec.yaml.decode(text, type=list[FleetRobot])
    except msgspec.ValidationError as exc:
        raise _validation_error(source, str(exc), text) from None
    except msgspec.DecodeError as exc:
        raise _yaml_error(source, exc) from None
    if not robots:
        raise FleetFileError(source, "the file lists no robots", "$")
    _check_unique(source, robots, text)
    return robots


# --- error wording ----------------------------------------------------------------------------

_PATH_TOKEN = re.compile(r"\[(\d+)\]|\.([A-Za-z_][A-Za-z0-9_]*)")


def _validation_error(source: str, text: str, data: bytes) -> FleetFileError:
    reason, location = split_location(text)
    if location is None:
        if text == "Expected `array`, got `object`":
            reason += " (a fleet file is a YAML list of robots: '- {name: ..., x: ..., y: ...}')"
        return FleetFileError(source, reason, "$")
    line = _line_of(data, location)
    where = f"{location} (line {line})" if line else location
    return FleetFileError(source, reason, where)


def _line_of(data: bytes, location: str) -> int | None:
    """The 1-based line of the YAML node at a msgspec location like ``$[2].x``."""
    try:
        node: yaml.Node | None = yaml.compose(data, Loader=yaml.SafeLoader)
    except (yaml.YAMLError, RecursionError):
        return None
    for index, key in _PATH_TOKEN.findall(location[1:]):
        if isinstance(node, yaml.SequenceNode) and index:
            i = int(index)
            node = node.value[i] if i < len(node.value) else None
        elif isinstance(node, yaml.MappingNode) and key:
            node = next((v for k, v in node.value if getattr(k, "value", None) == key), None)
        else:
            node = None
        if node is None:
            return None
    return node.start_mark.line + 1 if node is not None else None


def _yaml_error(source: str, exc: msgspec.DecodeError) -> FleetFileError:
    reason, where = yaml_syntax_problem(exc)
    return FleetFileError(source, reason, where)


def _check_unique(source: str, robots: list[FleetRobot], data: bytes) -> None:
    """Two entries with the same name or namespace would race; refuse before spawning."""
    seen: dict[str, int] = {}
    for i, r in enumerate(robots):
        for field, value in (("name", r.name), ("namespace", r.effective_namespace)):
            first = seen.get(value)
            if first is not None and first != i:
                line = _line_of(data, f"$[{i}]")
                where = f"$[{i}].{field}" + (f" (line {line})" if line else "")
                raise FleetFileError(source, f"{value!r} is already used by entry $[{first}]", where)
        seen.setdefault(r.name, i)
        seen.setdefault(r.effective_namespace, i)
