"""``fleet-ros``: what a ROS 2 user needs around ``simd --ros2``.

    fleet-ros nav2 TB3_1 TB3_2:waffle -o nav2/       # Nav2 parameter files and a launch file
    fleet-ros nav2 --file tb3_multi -o nav2/ --force  # the robots of a fleet file; replace the files
    fleet-ros smoke                                   # simd against the ROS 2 install here: a table

Exit codes: 0 done (smoke: nothing failed); 1 smoke: a check failed; 2 usage error (a bad
argument, files already there without ``--force``, no ROS 2 to test against).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from clients.fleetfile import FleetFileError, load_fleet
from clients.ros import nav2_files, smoke
from clients.ros.nav2_params import DISTROS, MODELS, Robot
from clients.ros.smoke_checks import FAIL, table
from protocol.errors import FleetError
from protocol.names import check_name

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2


class UsageError(ValueError):
    pass


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="fleet-ros", description="ROS 2 helpers for simd --ros2 (docs/ros2.md).")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    n = sub.add_parser(
        "nav2",
        help="write Nav2 parameter files and a launch file for fleetsim's robots",
        description="Write, for each robot, a Nav2 parameter file that fits fleetsim's topics, frames, footprint "
        "and sim time, and one launch file that starts Nav2 in every robot's namespace (docs/ros2.md, Nav2).",
    )
    n.add_argument("robots", nargs="*", metavar="NS[:MODEL]", help="robot namespaces, each with its model")
    n.add_argument("--file", metavar="FLEET", help="the robots of a fleet file (fleet spawn --file), e.g. tb3_multi")
    n.add_argument("--model", choices=MODELS, default=None,
                   help="the model of robots given without one (default: $TURTLEBOT3_MODEL, else burger)")  # fmt: skip
    n.add_argument("-o", "--output", default="nav2_fleetsim", metavar="DIR",
                   help="the directory to write into, made if missing (default: %(default)s)")  # fmt: skip
    n.add_argument("--ros-tf", choices=("namespaced", "global"), default="namespaced",
                   help="the daemon's TF layout (simd --ros-tf): namespaced, each robot's /<ns>/tf with unprefixed "
                        "frames as nav2_bringup's multi-robot launches; global, the fleet's /tf with frames "
                        "<ns>/odom (default: %(default)s)")  # fmt: skip
    n.add_argument("--distro", choices=DISTROS, default=None,
                   help="the ROS 2 distribution Nav2 runs on (default: $ROS_DISTRO if one of these, "
                        "else jazzy)")  # fmt: skip
    n.add_argument("--force", action="store_true", help="replace files that exist")
    s = sub.add_parser(
        "smoke",
        help="run simd --ros2 against the ROS 2 tools installed here and print a pass/fail table",
        description="Start simd --ros2, run ros2 topic list/echo/hz, a teleop publish, a /spawn_entity call, "
        "ros2 param list and a 5 s ros2 bag record against it, and print a table to paste into an issue. Needs a "
        "sourced ROS 2 with RMW_IMPLEMENTATION=rmw_zenoh_cpp.",
    )
    s.add_argument("--ros-router", default="tcp/localhost:7447", metavar="ENDPOINT",
                   help="the rmw_zenoh router (default: %(default)s; simd serves as the router if none "
                        "listens)")  # fmt: skip
    s.add_argument("-o", "--output", metavar="FILE", help="also write the table to FILE")
    s.add_argument("--force", action="store_true", help="replace --output FILE if it exists")
    return p


def parse_robots(items: Sequence[str], default_model: str) -> list[Robot]:
    robots = []
    for item in items:
        namespace, _, model = item.partition(":")
        namespace = namespace.strip("/")
        try:
            check_name(namespace, "namespace")
        except FleetError as e:
            raise UsageError(f"robot {item!r}: {e.message}") from None
        model = model or default_model
        if model not in MODELS:
            raise UsageError(f"robot {item!r}: unknown model {model!r}: one of {', '.join(MODELS)}")
        robots.append(Robot(namespace, model))
    return robots


def nav2_plan(args: argparse.Namespace, env: dict[str, str]) -> tuple[list[Robot], str]:
    """The robots and the distro, or :class:`UsageError`."""
    default_model = args.model or env.get("TURTLEBOT3_MODEL") or "burger"
    if default_model not in MODELS:
        raise UsageError(f"TURTLEBOT3_MODEL is {default_model!r}: one of {', '.join(MODELS)}, or give --model")
    robots = parse_robots(args.robots, default_model)
    if args.file:
        try:
            fleet = load_fleet(args.file)
        except FleetFileError as e:
            raise UsageError(str(e)) from None
        robots += parse_robots([f"{r.effective_namespace}:{r.model or default_model}" for r in fleet], default_model)
    if not robots:
        raise UsageError("name the robots (TB3_1 TB3_2:waffle) or give --file FLEET")
    seen = set()
    for r in robots:
        if r.namespace in seen:
            raise UsageError(f"namespace {r.namespace!r} is given twice")
        seen.add(r.namespace)
    distro = args.distro or (env["ROS_DISTRO"] if env.get("ROS_DISTRO") in DISTROS else "jazzy")
    return robots, distro


def nav2_main(args: argparse.Namespace, env: dict[str, str]) -> int:
    robots, distro = nav2_plan(args, env)
    namespaced = args.ros_tf == "namespaced"
    out = Path(args.output)
    try:
        paths = nav2_files.write(out, nav2_files.files(robots, distro, namespaced), args.force)
    except nav2_files.FilesError as e:
        raise UsageError(str(e)) from None
    names = ", ".join(f"{r.namespace} ({r.model})" for r in robots)
    print(f"fleet-ros: wrote {len(paths)} files to {out}/ for {names}, ROS 2 {distro}, --ros-tf {args.ros_tf}")
    print(f"  1. {nav2_files.simd_command(namespaced)}")
    spawn = f"fleet spawn --file {args.file}" if args.file else "fleet spawn NAME X Y --namespace NS (each robot)"
    print(f"  2. {spawn}")
    print(f"  3. ros2 launch {out / nav2_files.LAUNCH_FILE}")
    return EXIT_OK


def smoke_main(args: argparse.Namespace, env: dict[str, str]) -> int:
    if args.output and Path(args.output).exists() and not args.force:
        raise UsageError(f"{args.output} already exists: choose another -o, or --force to replace it")
    try:
        setup = smoke.setup(env, args.ros_router)
    except smoke.SmokeError as e:
        raise UsageError(str(e)) from None
    how = "serving as the router" if setup.serve_router else "joining the router"
    print(f"fleet-ros: starting simd --ros2 ({how} on {setup.router}); this takes about a minute", file=sys.stderr)
    try:
        head, verdicts = smoke.smoke(setup)
    except smoke.SmokeError as e:
        print(f"fleet-ros: error: {e}", file=sys.stderr)
        return EXIT_FAILED
    report = table(verdicts, head)
    print(report, end="")
    if args.output:
        Path(args.output).write_text(report)
    return EXIT_FAILED if any(v.status == FAIL for v in verdicts) else EXIT_OK


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    env = dict(os.environ)
    try:
        if args.command == "nav2":
            return nav2_main(args, env)
        return smoke_main(args, env)
    except UsageError as e:
        print(f"fleet-ros {args.command}: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
