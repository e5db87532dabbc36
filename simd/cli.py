"""``simd``: the command line of the simulation daemon: its flags, checked before anything
opens; the daemon is then built (simd/daemon.py), run, and torn down in one place."""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import os
import re
import signal
import sys
import threading
from collections.abc import Callable, Mapping
from types import FrameType
from typing import TYPE_CHECKING

from fleetcommon.zenoh_config import add_zenoh_args
from protocol.control import DEFAULT_DAEMON_ID
from protocol.errors import FleetError
from protocol.keys import DEFAULT_PREFIX, Keys
from protocol.names import check_name
from protocol.ros_domain import domain_id
from simd.adapters.zenoh_entities import zenoh_too_old
from simd.daemon import CheckedFlags, Refused, build_daemon

if TYPE_CHECKING:  # imported for real only once the flags are checked (it picks the fast paths)
    from simd.engine.engine import Engine

log = logging.getLogger("simd")

#: the ROS 2 distributions --ros-distro knows (simd.adapters.ros2.interfaces.DISTROS; named here so
#: that parsing the flags does not load the ROS adapter and rosbags)
ROS_DISTROS = ("humble", "jazzy", "kilted", "lyrical", "rolling")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="simd",
        description="Headless 2D TurtleBot3 fleet simulator served over Zenoh.",
        epilog='Spawn a robot: zenoh get -s fleet/spawn -v \'{"name": "tb3_0", "x": -2.0, "y": -0.5}\' '
        "(see the README for the whole key space).",
    )
    p.add_argument(
        "--world",
        default="turtlebot3_world",
        help="world name (turtlebot3_world, turtlebot3_house, empty), a world YAML file, a map_server map's "
        "YAML (map.yaml + its image: the occupied cells become walls), or a MovingAI grid map (NAME.map: the "
        "blocked cells become walls; see --cell-size)",
    )
    p.add_argument(
        "--cell-size",
        type=float,
        default=0.5,  # simd.core.movingai.DEFAULT_CELL_SIZE_M, not imported before the flags are parsed
        metavar="M",
        help="the side of one cell of a MovingAI .map world in metres (0.5 fits a burger in a one-cell aisle; "
        "waffles need 0.6); ignored for other worlds (default: %(default)s)",
    )
    p.add_argument("--prefix", default=DEFAULT_PREFIX, help="key prefix (default: %(default)s)")
    p.add_argument(
        "--join",
        action="store_true",
        help="share the prefix with the other --join daemons on the network: each spawn is placed on one of them "
        "by its name, lists are merged, robots on other daemons are seen and felt here, pause/resume/reset/step "
        "reach every daemon (docs/scale-out.md)",
    )
    p.add_argument(
        "--id",
        default=DEFAULT_DAEMON_ID,
        help="this daemon's name in the fleet (its liveliness token P/daemons/ID; fleet daemons lists them; "
        "default: %(default)s)",
    )
    p.add_argument(
        "--seed",
        type=int,
        default=0,
        help="noise seed (default: %(default)s); the same seed replays the same noise on the same build "
        "(the compiled and the numpy noise draw different streams)",
    )
    p.add_argument(
        "--rtf",
        type=float,
        default=1.0,
        help="target real-time factor; 0 runs as fast as possible (default: %(default)s)",
    )
    p.add_argument("--no-noise", action="store_true", help="turn the lidar noise off")
    p.add_argument(
        "--odom-noise",
        type=float,
        default=0.0,
        metavar="F",
        help="wheel slip: each wheel's travel off by F times a normal draw (seeded), so odometry drifts from the "
        "true pose as on a real robot (e.g. 0.05); fleet list keeps the true pose (default: 0, exact odometry)",
    )
    p.add_argument(
        "--cmd-timeout",
        type=float,
        default=0.5,
        help="seconds of sim time without cmd_vel before a robot stops; 0 = never (default: %(default)s)",
    )
    p.add_argument("--max-robots", type=int, default=5000, help="robot limit (default: %(default)s)")
    p.add_argument(
        "--lockstep",
        action="store_true",
        help="advance only when a client asks (sim/step), for deterministic tests and learning loops",
    )
    p.add_argument("--paused", action="store_true", help="start paused")
    p.add_argument(
        "--state",
        metavar="FILE",
        help="keep the fleet in FILE: written every few seconds and on shutdown, restored on start, so a restarted "
        "daemon brings its robots back (a missing FILE is created)",
    )
    p.add_argument(
        "--nav-cell",
        type=float,
        default=None,
        metavar="M",
        help="side of the cells one robot wide that navigation lays over an open world, in metres (default: the "
        "smallest the largest robot fits in: 0.35 for burgers, 0.6 with waffles; a MovingAI map uses --cell-size)",
    )
    p.add_argument(
        "--no-nav",
        action="store_true",
        help="no navigation: robots go only where cmd_vel drives them (by default every robot takes goals on "
        "P/<ns>/navigate: fleet goto NS X Y; docs/navigation.md)",
    )
    p.add_argument("--log-level", default="info", choices=("debug", "info", "warning", "error"))
    add_zenoh_args(p, server=True)
    add_ros_args(p)
    return p


def add_ros_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("ROS 2 (docs/ros2.md)")
    g.add_argument(
        "--ros2",
        action="store_true",
        help="also serve the robots to ROS 2 tools over rmw_zenoh (topics, /tf, /clock, /spawn_entity)",
    )
    g.add_argument(
        "--ros-domain-id",
        type=int,
        default=None,
        metavar="N",
        help="ROS domain (default: $ROS_DOMAIN_ID, else 0)",
    )
    g.add_argument(
        "--ros-distro",
        choices=ROS_DISTROS,
        default=None,
        help="the ROS tools' distribution: humble keys topics without type hashes, the others with them; "
        "lyrical and rolling get simulation_interfaces 2.x (default: $ROS_DISTRO if it is one of these, "
        "else jazzy)",
    )
    g.add_argument(
        "--ros-cmd-vel",
        choices=("twist", "stamped", "both"),
        default=None,
        help="the type each robot's cmd_vel subscription advertises (both are taken either way): Twist, "
        "TwistStamped, or both, which tools that infer a topic's type refuse (default: twist up to jazzy, "
        "stamped from kilted, as Nav2 defaults)",
    )
    g.add_argument(
        "--ros-router",
        default=None,
        metavar="ENDPOINT",
        help="the rmw_zenoh router to join (default: tcp/localhost:7447, where rmw_zenohd listens, or the one "
        "$ZENOH_SESSION_CONFIG_URI's file connects to: the ROS session's config is rmw_zenoh's, and "
        "ZENOH_SESSION_CONFIG_URI, ZENOH_ROUTER_CONFIG_URI and ZENOH_CONFIG_OVERRIDE change it as they change "
        "a ROS process's; docs/ros2.md)",
    )
    g.add_argument(
        "--ros-world-frame",
        default=None,
        metavar="FRAME",
        help="also send a static FRAME -> <ns>/odom for every robot, so that RViz can show the whole fleet "
        "in FRAME (leave it off when SLAM publishes map -> <ns>/odom)",
    )
    g.add_argument(
        "--ros-tf",
        choices=("global", "namespaced"),
        default="global",
        help="global: every robot's transforms on /tf and /tf_static, frames prefixed by the namespace (TB3_1/odom, "
        "the TurtleBot3 multi-robot launch); namespaced: each robot's on /<ns>/tf and /<ns>/tf_static, frames "
        "unprefixed (odom, base_footprint), as nav2_bringup's multi-robot launches read them (default: %(default)s)",
    )
    g.add_argument(
        "--ros-localization",
        action="store_true",
        help="localization for free, as nav2_loopback_sim: map -> odom from the ground truth in every robot's tree, "
        "/map drawn from the world (transient local), and /<ns>/initialpose puts the robot there; Nav2 then runs "
        "without AMCL or SLAM",
    )
    g.add_argument(
        "--ros-serve-router",
        action="store_true",
        help="be the router on --ros-router's endpoint instead of joining one (no rmw_zenohd needed; by default "
        "tcp/localhost:7447, loopback only, where rmw_zenohd listens on every interface)",
    )
    g.add_argument(
        "--ros-mode",
        choices=("peer", "client"),
        default=None,
        help="join the ROS router as a peer that ROS processes reach directly, as rmw_zenoh's processes do, or "
        "as its client, everything through the router (a daemon in a container, which other peers cannot reach) "
        "(default: peer, or the mode of $ZENOH_SESSION_CONFIG_URI's file)",
    )


def ros_settings(args: argparse.Namespace, env: Mapping[str, str]) -> tuple[int, str]:
    """The ROS domain and distro from the flags, else the environment (ValueError if bad)."""
    domain = domain_id(args.ros_domain_id, env)
    frame = args.ros_world_frame
    if frame is not None and not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z0-9_]+)*", frame):
        raise ValueError(f"--ros-world-frame must be a tf frame name like 'world' (no leading '/'), got {frame!r}")
    if args.ros_localization and frame is not None:
        raise ValueError(
            f"--ros-localization hangs every robot's odom from 'map', --ros-world-frame from {frame!r}: a frame "
            "has one parent, leave one out"
        )
    if args.ros_serve_router and args.ros_mode == "client":
        raise ValueError(
            "--ros-serve-router makes simd the ROS router, which is no client: leave out --ros-mode client"
        )
    distro: str = args.ros_distro or (env["ROS_DISTRO"] if env.get("ROS_DISTRO") in ROS_DISTROS else "jazzy")
    return domain, distro


def fail(message: str) -> int:
    print(f"simd: error: {message}", file=sys.stderr, flush=True)
    return 2


def check_flags(args: argparse.Namespace, env: Mapping[str, str]) -> CheckedFlags:
    """Every flag checked before anything opens (a session, a thread); Refused says what is wrong."""
    if args.rtf < 0:
        raise Refused("--rtf must be >= 0")
    if args.cmd_timeout < 0:
        raise Refused("--cmd-timeout must be >= 0")
    if args.max_robots < 1:
        raise Refused("--max-robots must be >= 1")
    if args.seed < 0:
        raise Refused("--seed must be >= 0")
    if not 0.0 <= args.odom_noise <= 0.5:
        raise Refused("--odom-noise must be in 0..0.5 (a fraction of each wheel's travel)")
    if args.nav_cell is not None and not (math.isfinite(args.nav_cell) and 0.2 <= args.nav_cell <= 5.0):
        raise Refused(f"--nav-cell must be a number of metres in 0.2..5, got {args.nav_cell:g}")
    if not (math.isfinite(args.cell_size) and args.cell_size > 0):
        raise Refused(f"--cell-size must be a finite number of metres > 0, got {args.cell_size:g}")
    try:
        keys = Keys(args.prefix)
        check_name(args.id, "--id")
        ros_domain, ros_distro = ros_settings(args, env) if args.ros2 else (0, "jazzy")
    except FleetError as e:
        raise Refused(e.message) from None
    except ValueError as e:
        raise Refused(str(e)) from None

    from simd.core.mapworld import load_world_or_map
    from simd.core.worldfile import WorldFileError

    try:
        world = load_world_or_map(args.world, args.cell_size)
    except WorldFileError as e:
        raise Refused(str(e)) from None

    import simd.nav
    import simd.wire  # noqa: F401  # both register their compiled fast paths for status()
    from simd.core import native

    try:  # importing the hot loops reads FLEETSIM_NATIVE / FLEETSIM_LIDAR
        fast = native.status()
    except (ValueError, ImportError) as e:
        if "FLEETSIM_" not in str(e):
            raise
        raise Refused(str(e)) from None
    return CheckedFlags(args, keys, world, fast, ros_domain, ros_distro)


def stopping_handler(engine: Engine) -> Callable[[int, FrameType | None], None]:
    """The SIGINT/SIGTERM handler: stop the engine from a thread of its own. A handler runs on
    the main thread, which is the simulation thread, between two bytecodes, possibly inside a
    lock that stopping takes (the request queue's, whose ``get`` the loop is in): a daemon
    stopped on the spot there waited for itself forever and ignored SIGTERM (seen once in the
    suite, a lockstep daemon behind a router)."""

    def on_signal(signum: int, frame: FrameType | None) -> None:
        name = signal.Signals(signum).name
        threading.Thread(target=_stop, args=(engine, name), name="stop", daemon=True).start()

    return on_signal


def _stop(engine: Engine, signal_name: str) -> None:
    log.info("received %s, stopping", signal_name)
    engine.stop()


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    too_old = zenoh_too_old()
    if too_old is not None:
        return fail(too_old)
    # zenoh's query callbacks need the GIL, which the simulation thread would otherwise hold
    # for up to 5 ms at a time; 1 ms keeps spawn replies prompt at the cost of a few switches.
    sys.setswitchinterval(0.001)
    if hasattr(sys.stdout, "reconfigure"):
        sys.stdout.reconfigure(line_buffering=True)
    logging.basicConfig(
        level=args.log_level.upper(),
        stream=sys.stdout,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    try:
        flags = check_flags(args, os.environ)
        with contextlib.ExitStack() as teardown:  # everything opened below is closed here, in reverse
            daemon = build_daemon(flags, teardown)
            engine = daemon.engine

            on_signal = stopping_handler(engine)
            signal.signal(signal.SIGINT, on_signal)
            signal.signal(signal.SIGTERM, on_signal)
            daemon.announce()
            engine.run()
    except Refused as e:
        return fail(str(e))
    log.info("stopped at sim time %.3f s", engine.sim.time)
    return 0


if __name__ == "__main__":
    sys.exit(main())
