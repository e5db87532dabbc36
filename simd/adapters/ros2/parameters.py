"""A node's parameters as rclcpp keeps them, so that ``ros2 param`` gets rclcpp's answers.

Every rclcpp node declares ``use_sim_time`` (its TimeSource does) and serves six services on its
parameters (``<node>/list_parameters``, ``get_parameters``, ``describe_parameters``,
``get_parameter_types``, ``set_parameters``, ``set_parameters_atomically``). The daemon's nodes
have that one parameter, and it is true: every stamp they send is sim time (``/clock``).

The answers follow rclcpp's ``NodeParameters`` and ``ParameterService`` (rclcpp/src/rclcpp/
node_interfaces/node_parameters.cpp, parameter_service.cpp) with undeclared parameters not
allowed, as a node is by default:

- get, describe and get_types of a list naming an undeclared parameter answer with an empty list
  (rclcpp catches its ParameterNotDeclaredException and leaves the response empty);
- list matches names by prefix and depth, counting ``.`` as the separator;
- set answers each parameter on its own: undeclared, read-only and wrong-typed parameters fail
  with rclcpp's words; so does a ``use_sim_time`` other than true (the daemon cannot run its nodes
  on the wall clock), while true succeeds and changes nothing. set_parameters_atomically fails
  whole as soon as one fails.

Plain data in and out: the ROS messages are built by the caller (node_entities.py).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import Any


class ParameterType(IntEnum):
    """rcl_interfaces/msg/ParameterType, with rclcpp's names for its messages."""

    NOT_SET = 0
    BOOL = 1
    INTEGER = 2
    DOUBLE = 3
    STRING = 4
    BYTE_ARRAY = 5
    BOOL_ARRAY = 6
    INTEGER_ARRAY = 7
    DOUBLE_ARRAY = 8
    STRING_ARRAY = 9

    @property
    def label(self) -> str:
        """As ``rclcpp::to_string(ParameterType)`` says it (in set's refusals)."""
        return "not set" if self is ParameterType.NOT_SET else self.name.lower()


#: rclcpp's separator of parameter namespaces (``a.b.c``)
SEPARATOR = "."
#: ListParameters' DEPTH_RECURSIVE
DEPTH_RECURSIVE = 0


@dataclass(frozen=True)
class Declared:
    """One declared parameter: its value and what its descriptor says."""

    name: str
    type: ParameterType
    value: Any
    description: str = ""
    additional_constraints: str = ""
    read_only: bool = False
    #: why setting another value fails (the value cannot change; rclcpp's read-only would refuse
    #: even setting it to what it is, which a launch file setting use_sim_time:=true does)
    fixed: str = "it cannot change"


USE_SIM_TIME = Declared(
    "use_sim_time",
    ParameterType.BOOL,
    True,
    description="fleetsim stamps every message in sim time, which /clock carries",
    additional_constraints="true only",
    fixed="fleetsim's nodes run on sim time",
)


@dataclass(frozen=True)
class SetResult:
    """rcl_interfaces/msg/SetParametersResult."""

    successful: bool
    reason: str = ""


class NodeParameters:
    """The declared parameters of one node (the same for every node of the daemon)."""

    def __init__(self, declared: Sequence[Declared] = (USE_SIM_TIME,)) -> None:
        self._declared = {p.name: p for p in sorted(declared, key=lambda p: p.name)}

    def get(self, names: Sequence[str]) -> list[Declared]:
        """GetParameters: each parameter named, or none at all if one is not declared."""
        if not all(n in self._declared for n in names):
            return []
        return [self._declared[n] for n in names]

    def describe(self, names: Sequence[str]) -> list[Declared]:
        """DescribeParameters: as :meth:`get` (a descriptor per parameter)."""
        return self.get(names)

    def types(self, names: Sequence[str]) -> list[ParameterType]:
        """GetParameterTypes: as :meth:`get`, the types."""
        return [p.type for p in self.get(names)]

    def list_names(self, prefixes: Sequence[str], depth: int) -> tuple[list[str], list[str]]:
        """ListParameters: (names, prefixes) as rclcpp's ``list_parameters`` matches them."""

        def shallow(name: str) -> bool:
            return name.count(SEPARATOR) < depth

        def matches(name: str) -> bool:
            if not prefixes and depth == DEPTH_RECURSIVE:
                return True
            if not prefixes and shallow(name):
                return True
            return any(
                name == prefix
                or (
                    name.startswith(prefix + SEPARATOR)
                    and (depth == DEPTH_RECURSIVE or shallow(name[len(prefix) + 1 :]))
                )
                for prefix in prefixes
            )

        names = [n for n in self._declared if matches(n)]
        found: list[str] = []
        for name in names:
            if SEPARATOR in name:
                prefix = name.rsplit(SEPARATOR, 1)[0]
                if prefix not in found:
                    found.append(prefix)
        return names, found

    def set_one(self, name: str, type_: int, value: Any) -> SetResult:
        """One parameter of SetParameters (``type_`` and ``value`` from its ParameterValue)."""
        declared = self._declared.get(name)
        if declared is None:
            return SetResult(False, f"parameter '{name}' cannot be set because it was not declared")
        if declared.read_only:
            return SetResult(False, f"parameter '{name}' cannot be set because it is read-only")
        if type_ != declared.type:
            known = _type(type_)
            given = known.label if known is not None else str(type_)
            return SetResult(
                False,
                f"Wrong parameter type, parameter {{{name}}} is of type {{{declared.type.label}}}, "
                f"setting it to {{{given}}} is not allowed.",
            )
        if value != declared.value:
            shown = str(value).lower() if isinstance(value, bool) else repr(value)
            return SetResult(False, f"parameter '{name}' cannot be set to {shown}: {declared.fixed}")
        return SetResult(True)

    def set_atomically(self, parameters: Sequence[tuple[str, int, Any]]) -> SetResult:
        """SetParametersAtomically: all or nothing (and nothing ever changes here)."""
        if not all(name in self._declared for name, _, _ in parameters):
            return SetResult(False, "One or more parameters were not declared before setting")
        for name, type_, value in parameters:
            result = self.set_one(name, type_, value)
            if not result.successful:
                return result
        return SetResult(True)


#: the field of an rcl_interfaces/msg/ParameterValue that holds a value of each scalar type
VALUE_FIELDS = {
    ParameterType.BOOL: "bool_value",
    ParameterType.INTEGER: "integer_value",
    ParameterType.DOUBLE: "double_value",
    ParameterType.STRING: "string_value",
}


def _type(number: int) -> ParameterType | None:
    try:
        return ParameterType(number)
    except ValueError:
        return None


def value_of(message: Any) -> tuple[int, Any]:
    """(type, value) of an rcl_interfaces/msg/ParameterValue (the value of an array: None; no
    parameter here is one)."""
    type_ = int(message.type)
    known = _type(type_)
    field = VALUE_FIELDS.get(known) if known is not None else None
    return type_, (getattr(message, field) if field is not None else None)
