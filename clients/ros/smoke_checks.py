"""What ``fleet-ros smoke`` makes of each ROS 2 command's output, and the table it prints.

Pure functions of text: each reads one command's output in the format the ROS 2 tools print
(ros2cli's ``topic list -t``, ``topic echo``, ``topic hz``, ``service call``, ``param list``;
rosbag2's ``bag info``; Humble and Jazzy, from their sources) and gives a :class:`Verdict`.
They are tested on outputs written by hand from those formats (tests/clients/data/ros_smoke/),
not captured from a real ROS install; the first real run is the test of the formats.

A verdict is PASS or FAIL.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

import yaml

PASS, FAIL = "PASS", "FAIL"
#: how far ``ros2 topic hz`` may read from the rate fleetsim publishes at (real time)
HZ_TOLERANCE = 0.2


@dataclass(frozen=True)
class Outcome:
    """One command's run: what it printed and how it ended."""

    command: list[str]
    stdout: str = ""
    stderr: str = ""
    returncode: int | None = 0
    #: killed at its time limit (it hung, or never printed what was waited for)
    timed_out: bool = False

    @property
    def text(self) -> str:
        return f"{self.stdout}\n{self.stderr}" if self.stderr else self.stdout


@dataclass(frozen=True)
class Verdict:
    check: str
    status: str
    detail: str
    outcomes: list[Outcome] = field(default_factory=list)  # the commands behind it, for the report


def _short(text: str, limit: int = 160) -> str:
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _failed_run(check: str, out: Outcome) -> Verdict | None:
    """FAIL for a command that hung or exited with an error, else None."""
    if out.timed_out:
        return Verdict(check, FAIL, f"no answer within the time limit: {_short(out.text) or 'no output'}", [out])
    if out.returncode not in (0, None):
        return Verdict(check, FAIL, f"exit {out.returncode}: {_short(out.text) or 'no output'}", [out])
    return None


# -- ros2 service call /spawn_entity ----------------------------------------------------------------

_RESPONSE = re.compile(r"response:\s*\n\s*\S+\((?P<fields>.*)\)\s*$", re.S)


def response_fields(stdout: str) -> dict[str, str]:
    """The fields of the response ``ros2 service call`` prints as the response's repr:
    ``pkg.srv.Name_Response(success=True, status_message='...')``."""
    m = _RESPONSE.search(stdout.strip())
    if m is None:
        return {}
    return {k: v.strip("'\"") for k, v in re.findall(r"(\w+)=('(?:[^'\\]|\\.)*'|\"[^\"]*\"|[^,]*)", m["fields"])}


def check_spawn(out: Outcome) -> Verdict:
    check = "spawn: ros2 service call /spawn_entity"
    failed = _failed_run(check, out)
    if failed is not None:
        return failed
    fields = response_fields(out.stdout)
    if not fields:
        return Verdict(check, FAIL, f"no response printed: {_short(out.text)}", [out])
    message = fields.get("status_message", "")
    ok = fields.get("success") == "True"
    return Verdict(check, PASS if ok else FAIL, message or str(fields), [out])


# -- ros2 topic list -t -----------------------------------------------------------------------------


def topic_types(stdout: str) -> dict[str, list[str]]:
    """``/TB3_1/odom [nav_msgs/msg/Odometry]`` lines as topic -> types."""
    topics: dict[str, list[str]] = {}
    for line in stdout.splitlines():
        m = re.fullmatch(r"\s*(/\S*)\s+\[(.*)\]\s*", line)
        if m:
            topics[m[1]] = [t.strip() for t in m[2].split(",") if t.strip()]
    return topics


def expected_topics(ns: str) -> dict[str, set[str]]:
    """What the daemon publishes and takes for a robot ``ns`` (docs/ros2.md, "What ROS 2 sees")."""
    return {
        f"/{ns}/odom": {"nav_msgs/msg/Odometry"},
        f"/{ns}/scan": {"sensor_msgs/msg/LaserScan"},
        f"/{ns}/imu": {"sensor_msgs/msg/Imu"},
        f"/{ns}/joint_states": {"sensor_msgs/msg/JointState"},
        f"/{ns}/cmd_vel": {"geometry_msgs/msg/Twist", "geometry_msgs/msg/TwistStamped"},
        "/tf": {"tf2_msgs/msg/TFMessage"},
        "/tf_static": {"tf2_msgs/msg/TFMessage"},
        "/clock": {"rosgraph_msgs/msg/Clock"},
    }


def check_topic_list(out: Outcome, ns: str) -> Verdict:
    check = "ros2 topic list -t"
    failed = _failed_run(check, out)
    if failed is not None:
        return failed
    seen = topic_types(out.stdout)
    problems = []
    for topic, types in expected_topics(ns).items():
        if topic not in seen:
            problems.append(f"{topic} missing")
        elif set(seen[topic]) != types:
            problems.append(f"{topic} is [{', '.join(seen[topic])}], expected [{', '.join(sorted(types))}]")
    if problems:
        return Verdict(check, FAIL, "; ".join(problems), [out])
    return Verdict(check, PASS, f"{len(seen)} topics, the robot's {len(expected_topics(ns))} with their types", [out])


# -- ros2 topic echo --once -------------------------------------------------------------------------


def echoed(stdout: str) -> dict[str, Any] | None:
    """The first message ``ros2 topic echo`` printed (YAML, ended by ``---``), or None."""
    lines = stdout.splitlines()
    if "---" not in lines:
        return None
    body = "\n".join(lines[: lines.index("---")])
    try:
        message = yaml.safe_load(body)
    except (yaml.YAMLError, RecursionError):
        return None
    return message if isinstance(message, dict) else None


def odom_x(message: dict[str, Any]) -> float | None:
    try:
        return float(message["pose"]["pose"]["position"]["x"])
    except (KeyError, TypeError, ValueError):
        return None


def check_echo(out: Outcome, ns: str) -> Verdict:
    check = f"ros2 topic echo --once /{ns}/odom"
    failed = _failed_run(check, out)
    if failed is not None:
        return failed
    message = echoed(out.stdout)
    if message is None:
        return Verdict(check, FAIL, f"no message printed: {_short(out.text)}", [out])
    frames = (message.get("header", {}).get("frame_id"), message.get("child_frame_id"))
    x = odom_x(message)
    if frames != (f"{ns}/odom", f"{ns}/base_footprint") or x is None:
        return Verdict(check, FAIL, f"frames {frames[0]} -> {frames[1]}, x {x}", [out])
    return Verdict(check, PASS, f"frames {frames[0]} -> {frames[1]}, x {x:.3f}", [out])


# -- ros2 topic hz ----------------------------------------------------------------------------------


def average_rate(stdout: str) -> float | None:
    """The last ``average rate: 29.998`` ``ros2 topic hz`` printed."""
    rates = re.findall(r"average rate: ([0-9.]+)", stdout)
    return float(rates[-1]) if rates else None


def check_hz(out: Outcome, ns: str, expected_hz: float = 30.0) -> Verdict:
    check = f"ros2 topic hz /{ns}/odom"
    if out.timed_out:
        return Verdict(check, FAIL, "it did not stop when interrupted", [out])
    rate = average_rate(out.stdout)
    if rate is None:
        return Verdict(check, FAIL, f"no rate printed: {_short(out.text)}", [out])
    ok = abs(rate - expected_hz) <= HZ_TOLERANCE * expected_hz
    return Verdict(check, PASS if ok else FAIL, f"{rate:g} Hz (fleetsim sends {expected_hz:g} Hz at --rtf 1)", [out])


# -- a teleop publish, seen in the odometry ---------------------------------------------------------


def check_teleop(publish: Outcome, before: Outcome, after: Outcome, ns: str, min_m: float = 0.05) -> Verdict:
    """``ros2 topic pub`` of a forward command: the odometry's x before and after must differ."""
    check = f"teleop: ros2 topic pub /{ns}/cmd_vel"
    runs = [publish, before, after]
    failed = _failed_run(check, publish) or _failed_run(check, after)
    if failed is not None:
        return Verdict(check, FAIL, failed.detail, runs)
    first, last = echoed(before.stdout), echoed(after.stdout)
    x0 = odom_x(first) if first else None
    x1 = odom_x(last) if last else None
    if x0 is None or x1 is None:
        return Verdict(check, FAIL, "no odometry before or after the commands", runs)
    moved = x1 - x0
    ok = moved >= min_m
    return Verdict(check, PASS if ok else FAIL, f"x {x0:.3f} -> {x1:.3f} ({moved:+.3f} m)", runs)


# -- ros2 param list --------------------------------------------------------------------------------


def check_param_list(out: Outcome) -> Verdict:
    """The daemon's nodes serve rclcpp's parameter services (``use_sim_time`` true): ``ros2 param
    list`` lists ``/fleetsim`` and ``/TB3_1/turtlebot3`` with it. Jazzy's says ``Wait for service
    timed out ... for node`` for a node whose services it did not reach; Humble's skips it."""
    check = "ros2 param list"
    failed = _failed_run(check, out)
    if failed is not None:
        return failed
    listed: dict[str, list[str]] = {}
    node = None
    for line in out.stdout.splitlines():
        if re.match(r"^\S+:\s*$", line):
            node = line.strip()[:-1]
            listed[node] = []
        elif node is not None and line.startswith(" ") and line.strip():
            listed[node].append(line.strip())
    ours = {n: p for n, p in listed.items() if n.startswith("/fleetsim") or n.endswith("/turtlebot3")}
    waited = re.findall(r"parameter services for node (?:NodeName\(.*?full_name='([^']+)'\)|(\S+))", out.text)
    names = {a or b for a, b in waited}
    unreached = sorted(n for n in names if n.startswith("/fleetsim") or n.endswith("/turtlebot3"))
    if unreached:
        return Verdict(check, FAIL, f"timed out on {', '.join(unreached)}", [out])
    if not ours:
        return Verdict(check, FAIL, "no fleetsim node listed", [out])
    without = [n for n, params in ours.items() if "use_sim_time" not in params]
    if without:
        return Verdict(check, FAIL, f"no use_sim_time on {', '.join(without)}", [out])
    return Verdict(check, PASS, f"use_sim_time on {', '.join(sorted(ours))}", [out])


# -- ros2 bag record, then ros2 bag info ------------------------------------------------------------


def bag_counts(stdout: str) -> dict[str, tuple[str, int]]:
    """``Topic: /x | Type: t | Count: n | ...`` lines of ``ros2 bag info`` as topic -> (type, count)."""
    out = {}
    for m in re.finditer(r"Topic: (\S+) \| Type: (\S+) \| Count: (\d+)", stdout):
        out[m[1]] = (m[2], int(m[3]))
    return out


def check_bag(record: Outcome, info: Outcome, ns: str, seconds: float) -> Verdict:
    check = f"ros2 bag record ({seconds:g} s)"
    runs = [record, info]
    if record.timed_out:
        return Verdict(check, FAIL, "ros2 bag record did not stop when interrupted", runs)
    failed = _failed_run(check, info)
    if failed is not None:
        return Verdict(check, FAIL, f"ros2 bag info: {failed.detail}", runs)
    counts = bag_counts(info.stdout)
    wanted = {f"/{ns}/odom": 30 * seconds / 2, f"/{ns}/scan": 5 * seconds / 2, "/tf": 30 * seconds / 2,
              "/tf_static": 1, "/clock": 30 * seconds / 2}  # fmt: skip
    short = [f"{t} {counts.get(t, ('', 0))[1]}" for t, least in wanted.items() if counts.get(t, ("", 0))[1] < least]
    detail = ", ".join(f"{t} {c}" for t, (_, c) in counts.items())
    if short:
        return Verdict(check, FAIL, f"too few messages: {', '.join(short)} (all: {detail or 'none'})", runs)
    return Verdict(check, PASS, detail, runs)


# -- the report -------------------------------------------------------------------------------------


def table(verdicts: list[Verdict], header: list[str]) -> str:
    """The report to paste into an issue: the setup, a Markdown table, and the output of every
    command that failed."""
    lines = [*header, "", "| # | check | result | detail |", "|---|---|---|---|"]
    for i, v in enumerate(verdicts, 1):
        lines.append(f"| {i} | {v.check} | {v.status} | {v.detail.replace('|', '/')} |")
    passed = sum(v.status == PASS for v in verdicts)
    failed = [v for v in verdicts if v.status == FAIL]
    lines += ["", f"{passed} of {len(verdicts)} passed, {len(failed)} failed."]
    for v in failed:
        lines += ["", f"<details><summary>{v.check}: output</summary>", "", "```"]
        for out in v.outcomes:
            lines.append("$ " + " ".join(out.command))
            lines += [line[:300] for line in out.text.strip().splitlines()[-40:]]
        lines += ["```", "</details>"]
    return "\n".join(lines) + "\n"
