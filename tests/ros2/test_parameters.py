"""A node's parameters answer as rclcpp's NodeParameters does (rclcpp/src/rclcpp/node_interfaces/
node_parameters.cpp and parameter_service.cpp): the rules without the wire (the wire is in
test_ros2_daemon.py)."""

from __future__ import annotations

import pytest

from simd.adapters.ros2.parameters import USE_SIM_TIME, Declared, NodeParameters, ParameterType, SetResult

BOOL, STRING = int(ParameterType.BOOL), int(ParameterType.STRING)


def nested() -> NodeParameters:
    """A node with namespaced parameters, to check list's prefixes and depths."""
    names = ["use_sim_time", "a.b", "a.c.d", "a.c.e", "ab"]
    return NodeParameters([Declared(n, ParameterType.BOOL, True) for n in names])


def test_a_node_has_use_sim_time_true() -> None:
    p = NodeParameters()
    assert p.list_names([], 0) == (["use_sim_time"], [])
    assert p.get(["use_sim_time"]) == [USE_SIM_TIME] and USE_SIM_TIME.value is True
    assert p.types(["use_sim_time"]) == [ParameterType.BOOL]


def test_naming_an_undeclared_parameter_empties_the_answer() -> None:
    p = NodeParameters()
    assert p.get(["use_sim_time", "nope"]) == []
    assert p.describe(["nope"]) == []
    assert p.types(["use_sim_time", "nope"]) == []


@pytest.mark.parametrize(
    ("prefixes", "depth", "names", "found"),
    [
        ([], 0, ["a.b", "a.c.d", "a.c.e", "ab", "use_sim_time"], ["a", "a.c"]),
        ([], 1, ["ab", "use_sim_time"], []),
        ([], 2, ["a.b", "ab", "use_sim_time"], ["a"]),
        (["a"], 0, ["a.b", "a.c.d", "a.c.e"], ["a", "a.c"]),
        (["a"], 1, ["a.b"], ["a"]),
        (["a.c"], 1, ["a.c.d", "a.c.e"], ["a.c"]),
        (["ab"], 1, ["ab"], []),
        (["x"], 0, [], []),
    ],
)
def test_list_by_prefix_and_depth(prefixes: list[str], depth: int, names: list[str], found: list[str]) -> None:
    assert nested().list_names(prefixes, depth) == (names, found)


def test_set_takes_true_and_refuses_the_rest_in_rclcpps_words() -> None:
    p = NodeParameters()
    assert p.set_one("use_sim_time", BOOL, True) == SetResult(True)
    refused = p.set_one("use_sim_time", BOOL, False)
    assert not refused.successful and "sim time" in refused.reason
    assert p.set_one("use_sim_time", STRING, "yes") == SetResult(
        False,
        "Wrong parameter type, parameter {use_sim_time} is of type {bool}, setting it to {string} is not allowed.",
    )
    assert p.set_one("rate", BOOL, True) == SetResult(
        False, "parameter 'rate' cannot be set because it was not declared"
    )
    read_only = NodeParameters([Declared("x", ParameterType.BOOL, True, read_only=True)])
    assert read_only.set_one("x", BOOL, True) == SetResult(False, "parameter 'x' cannot be set because it is read-only")
    assert p.get(["use_sim_time"])[0].value is True  # nothing changed


def test_set_atomically_is_all_or_nothing() -> None:
    p = NodeParameters()
    assert p.set_atomically([("use_sim_time", BOOL, True)]) == SetResult(True)
    assert p.set_atomically([("use_sim_time", BOOL, True), ("rate", BOOL, True)]) == SetResult(
        False, "One or more parameters were not declared before setting"
    )
    assert not p.set_atomically([("use_sim_time", BOOL, True), ("use_sim_time", BOOL, False)]).successful
