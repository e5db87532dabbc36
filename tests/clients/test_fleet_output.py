"""What ``fleet`` prints and plans, table by table (clients/fleet/output.py, spawn_plan.py):
pure functions, no daemon."""

from __future__ import annotations

import argparse

import msgspec
import pytest

from clients.fleet.output import describe_clock, describe_spawn, format_table, in_list_order, teleop_command
from clients.fleet.spawn_plan import UsageError, plan_spawn
from clients.fleet_args import build_parser, spawn_parser
from clients.fleetfile import FleetRobot
from clients.naming import natural_key
from protocol.control import Clock, ModelLimits, Pose2D, RobotRecord, Topics
from protocol.messages import Time


def rec(name: str, ns: str | None = None, x: float = 0.0, yaw: float = 0.0) -> RobotRecord:
    return RobotRecord(name=name, namespace=ns or name, model="burger", pose=Pose2D(x=x, yaw=yaw))


@pytest.mark.parametrize(
    ("names", "ordered"),
    [
        (["burger_1", "burger_4", "burger_2", "burger_3"], ["burger_1", "burger_2", "burger_3", "burger_4"]),
        (["r10", "r2", "r1"], ["r1", "r2", "r10"]),
        (["tb3_0", "TB3_1", "a"], ["TB3_1", "a", "tb3_0"]),  # text compares as text (upper first)
        (["x2y10", "x2y9", "x10y1"], ["x2y9", "x2y10", "x10y1"]),
        ([], []),
    ],
)
def test_the_list_is_in_natural_name_order(names: list[str], ordered: list[str]) -> None:
    assert [r.name for r in in_list_order([rec(n) for n in names])] == ordered
    assert sorted(names, key=natural_key) == ordered


def test_the_table_aligns_text_left_and_numbers_right() -> None:
    table = format_table([rec("tb3_0", x=-2.0), rec("burger_10", "TB3_10", x=0.5, yaw=0.25)])
    assert table.splitlines() == [
        "NAME       NAMESPACE  MODEL        X      Y    YAW      V      W",
        "tb3_0      tb3_0      burger  -2.000  0.000  0.000  0.000  0.000",
        "burger_10  TB3_10     burger   0.500  0.000  0.250  0.000  0.000",
    ]
    shared = [rec("tb3_0"), rec("tb3_1")]  # a fleet shared by two daemons: which runs which
    shared = [msgspec.structs.replace(r, daemon=d) for r, d in zip(shared, ["lab_a", "b"], strict=True)]
    assert format_table(shared).splitlines() == [
        "NAME   NAMESPACE  MODEL       X      Y    YAW      V      W  DAEMON",
        "tb3_0  tb3_0      burger  0.000  0.000  0.000  0.000  0.000  lab_a",
        "tb3_1  tb3_1      burger  0.000  0.000  0.000  0.000  0.000  b",
    ]


def spawn_args(*argv: str) -> argparse.Namespace:
    return spawn_parser("fleet-spawn").parse_intermixed_args(list(argv))


@pytest.mark.parametrize(
    ("argv", "env_model", "robot"),
    [
        (["tb3_0"], "", FleetRobot(name="tb3_0", model="burger")),
        (["tb3_0", "-2", "-0.5"], "", FleetRobot(name="tb3_0", model="burger", x=-2.0, y=-0.5)),
        (["burger_1", "TB3_1", "-2", "-0.5", "0.01"], "", FleetRobot(name="burger_1", namespace="TB3_1",
                                                                    model="burger", x=-2.0, y=-0.5)),
        (["-entity", "b", "-robot_namespace", "NS", "-x", "1", "-y", "2", "-Y", "0.5"], "",
         FleetRobot(name="b", namespace="NS", model="burger", x=1.0, y=2.0, yaw=0.5)),
        (["tb3_0", "--model", "waffle"], "burger", FleetRobot(name="tb3_0", model="waffle")),
        (["tb3_0"], " waffle_pi ", FleetRobot(name="tb3_0", model="waffle_pi")),  # $TURTLEBOT3_MODEL
    ],
)  # fmt: skip
def test_every_spawn_form_plans_one_robot(argv: list[str], env_model: str, robot: FleetRobot) -> None:
    plan = plan_spawn(spawn_args(*argv), env_model)
    assert plan.robots == [robot] and not plan.from_file
    assert plan.model_from_env == (bool(env_model.strip()) and "--model" not in argv)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ([], "a robot NAME is required"),
        (["a", "NS", "1"], "expected X Y [Z]"),
        (["a", "1", "2", "3", "4"], "expected X Y [Z]"),
        (["a", "NS", "--namespace", "OTHER"], "namespace given twice"),
        (["a", "1", "2", "--x", "3"], "position given twice"),
        (["--file", "tb3_multi", "a"], "--file cannot be combined with NAME/NS/X/Y"),
    ],
)
def test_a_bad_spawn_line_says_what_is_wrong(argv: list[str], message: str) -> None:
    with pytest.raises(UsageError, match=message.replace("[", r"\[").replace("]", r"\]")):
        plan_spawn(spawn_args(*argv))


def test_a_fleet_file_fills_in_the_default_model_and_nothing_else() -> None:
    files = {"two": [FleetRobot(name="a", x=1.0), FleetRobot(name="b", model="waffle")]}
    plan = plan_spawn(spawn_args("--file", "two", "--model", "waffle_pi"), "", lambda name: files[name])
    assert plan.from_file and [(r.name, r.model, r.x) for r in plan.robots] == [
        ("a", "waffle_pi", 1.0),
        ("b", "waffle", 0.0),
    ]


def fleet_args(*argv: str) -> argparse.Namespace:
    _, cmds = build_parser()
    return cmds["spawn"].parse_intermixed_args(["x", *argv])


@pytest.mark.parametrize(
    ("argv", "program", "command"),
    [
        ([], "fleet-teleop", "fleet-teleop TB3_1"),
        (["-e", "tcp/10.0.0.5:7447"], "fleet-teleop", "fleet-teleop TB3_1 -e tcp/10.0.0.5:7447"),
        (["--prefix", "lab"], ".venv/bin/fleet-teleop", ".venv/bin/fleet-teleop TB3_1 --prefix lab"),
        (["--cfg", "a/b:1"], "/opt/my venv/bin/fleet-teleop", "'/opt/my venv/bin/fleet-teleop' TB3_1 --cfg a/b:1"),
    ],
)
def test_the_teleop_hint_reaches_the_same_daemon(argv: list[str], program: str, command: str) -> None:
    assert teleop_command("TB3_1", fleet_args(*argv), program) == command


def test_a_spawn_is_described_with_its_topics_limits_and_hint() -> None:
    r = RobotRecord(
        name="burger_1", namespace="TB3_1", model="burger", pose=Pose2D(x=-2.0, y=-0.5, yaw=1.5708),
        topics=Topics(cmd_vel="fleet/TB3_1/cmd_vel", odom="fleet/TB3_1/odom", scan="fleet/TB3_1/scan",
                      alive="fleet/TB3_1/alive"),
        limits=ModelLimits(max_linear_velocity=0.22, max_angular_velocity=2.84, wheel_separation=0.16,
                           wheel_radius=0.033, max_wheel_acceleration=1.0),
    )  # fmt: skip
    assert describe_spawn(r, "fleet-teleop TB3_1") == [
        "spawned burger_1 (burger) in namespace TB3_1 at x -2.000 m, y -0.500 m, yaw 1.571 rad (90.0°)",
        "  topics: fleet/TB3_1/cmd_vel (in)  fleet/TB3_1/odom  fleet/TB3_1/scan  fleet/TB3_1/alive (liveliness)",
        "  limits: ±0.22 m/s, ±2.84 rad/s",
        "  drive it: fleet-teleop TB3_1",
    ]
    for daemon, said in [("", ""), ("simd", ""), ("b", " on daemon b")]:  # a shared fleet names the daemon
        first = describe_spawn(msgspec.structs.replace(r, daemon=daemon), "fleet-teleop TB3_1")[0]
        assert (
            first
            == f"spawned burger_1 (burger) in namespace TB3_1 at x -2.000 m, y -0.500 m, yaw 1.571 rad (90.0°){said}"
        )


@pytest.mark.parametrize(
    ("paused", "lockstep", "target", "text"),
    [
        (False, False, 1.0, "running, real-time factor 0.98 (target 1)"),
        (True, False, 1.0, "paused, real-time factor 0.98 (target 1)"),
        (True, True, 1.0, "lockstep, real-time factor 0.98 (target 1)"),
        (False, False, 0.0, "running, real-time factor 0.98 (target max)"),
    ],
)
def test_the_clock_line(paused: bool, lockstep: bool, target: float, text: str) -> None:
    c = Clock(clock=Time(sec=3, nanosec=500_000_000), tick=105, dt=1 / 30, paused=paused, lockstep=lockstep,
              real_time_factor=0.98, target_real_time_factor=target, robots=4)  # fmt: skip
    assert describe_clock(c) == f"sim time 3.500 s, tick 105, {text}, robots 4"


def test_the_clock_line_says_when_the_daemon_falls_behind_and_what_it_can_keep() -> None:
    c = Clock(clock=Time(sec=3), tick=90, dt=1 / 30, paused=False, lockstep=False, real_time_factor=0.42,
              target_real_time_factor=1.0, robots=900, behind_s=12.34, falling_behind=True, tick_s=0.0791,
              capacity_robots=380)  # fmt: skip
    assert describe_clock(c) == (
        "sim time 3.000 s, tick 90, running, real-time factor 0.42 (target 1), robots 900, falling behind "
        "(12.3 s of sim time behind the target); a tick takes 79.1 ms: about 380 robots like these keep real "
        "time here"
    )
    recovered = msgspec.structs.replace(c, falling_behind=False, real_time_factor=1.0)
    assert "robots 900, 12.3 s of sim time behind the target;" in describe_clock(recovered)
