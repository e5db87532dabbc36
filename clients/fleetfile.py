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

import difflib
import os
import re
from pathlib import Path

import msgspec
import msgspec.yaml
import yaml

from protocol.files import FileFormatError, yaml_syntax_problem

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


def list_fleets() -> list[str]:
    return sorted(p.stem for p in FLEETS_DIR.glob("*.yaml"))


def load_fleet(name_or_path: str) -> list[FleetRobot]:
    """Load a shipped fleet by bare name or any fleet file by path; raise FleetFileError."""
    path, source = _resolve(name_or_path)
    try:
        text = path.read_bytes()
    except FileNotFoundError:
        raise FleetFileError(source, "file not found" + _shipped_hint(path)) from None
    except IsADirectoryError:
        raise FleetFileError(source, "is a directory, not a fleet file") from None
    except OSError as exc:
        raise FleetFileError(source, f"cannot read file: {exc.strerror or exc}") from None
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


# --- resolution -------------------------------------------------------------------------------


def _is_bare_name(text: str) -> bool:
    separators = {"/", os.sep} | ({os.altsep} if os.altsep else set())
    return not any(s in text for s in separators) and not text.endswith((".yaml", ".yml"))


def _resolve(name_or_path: str) -> tuple[Path, str]:
    if not _is_bare_name(name_or_path):
        return Path(name_or_path), name_or_path
    available = list_fleets()
    if name_or_path not in available:
        close = difflib.get_close_matches(name_or_path, available, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else "."
        raise FleetFileError(
            name_or_path,
            f"unknown fleet{hint} Shipped fleets: {', '.join(available) or '(none)'}. "
            "A file path must contain '/' or end in .yaml",
        )
    path = FLEETS_DIR / f"{name_or_path}.yaml"
    return path, str(path)


def _shipped_hint(path: Path) -> str:
    if path.suffix in (".yaml", ".yml") and path.stem in list_fleets():
        return f" (for the shipped fleet, pass the bare name {path.stem!r})"
    return ""


# --- error wording ----------------------------------------------------------------------------

_AT_LOCATION = re.compile(r"^(?P<reason>.*) - at `(?P<location>\$[^`]*)`$", re.DOTALL)
_PATH_TOKEN = re.compile(r"\[(\d+)\]|\.([A-Za-z_][A-Za-z0-9_]*)")


def _validation_error(source: str, text: str, data: bytes) -> FleetFileError:
    match = _AT_LOCATION.match(text)
    if match is None:
        reason = text
        if text == "Expected `array`, got `object`":
            reason += " (a fleet file is a YAML list of robots: '- {name: ..., x: ..., y: ...}')"
        return FleetFileError(source, reason, "$")
    location = match["location"]
    line = _line_of(data, location)
    where = f"{location} (line {line})" if line else location
    return FleetFileError(source, match["reason"], where)


def _line_of(data: bytes, location: str) -> int | None:
    """The 1-based line of the YAML node at a msgspec location like ``$[2].x``."""
    try:
        node: yaml.Node | None = yaml.compose(data, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
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
