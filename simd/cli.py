"""``simd``: the command line of the simulation daemon."""

from __future__ import annotations

import argparse
import logging
import math
import os
import re
import signal
import sys
from collections.abc import Mapping
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

from protocol.control import DEFAULT_DAEMON_ID
from protocol.errors import ErrorCode, FleetError
from protocol.keys import DEFAULT_PREFIX, Keys
from protocol.names import check_name
from protocol.ros_domain import domain_id
from protocol.zenoh_config import add_zenoh_args, options_from_args, zenoh_error_text
from simd.adapters.zenoh_entities import zenoh_too_old

if TYPE_CHECKING:
    from protocol.navigation import NavigateRequest
    from simd.core.sim import Simulation
    from simd.nav.navigator import Navigator

log = logging.getLogger("simd")

#: A tick puts one odometry per robot and a batch of scans back to back (~1.2 MB at 1 000
#: robots). zenoh's default data queue (2 batches of 64 kB) overflows on such bursts and drops;
#: 16 batches (the maximum) absorb them (measured: scans delivered 92% -> 100% at 100 robots).
TRANSPORT_DEFAULTS = {
    "transport/link/tx/queue/size/data": "16",
    "transport/link/tx/queue/size/data_low": "16",  # scans (see net.Bridge.add_robot)
}

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
    if args.rtf < 0:
        return fail("--rtf must be >= 0")
    if args.cmd_timeout < 0:
        return fail("--cmd-timeout must be >= 0")
    if args.max_robots < 1:
        return fail("--max-robots must be >= 1")
    if args.seed < 0:
        return fail("--seed must be >= 0")
    if not 0.0 <= args.odom_noise <= 0.5:
        return fail("--odom-noise must be in 0..0.5 (a fraction of each wheel's travel)")
    if args.nav_cell is not None and not (math.isfinite(args.nav_cell) and 0.2 <= args.nav_cell <= 5.0):
        return fail(f"--nav-cell must be a number of metres in 0.2..5, got {args.nav_cell:g}")
    if not (math.isfinite(args.cell_size) and args.cell_size > 0):
        return fail(f"--cell-size must be a finite number of metres > 0, got {args.cell_size:g}")
    try:
        keys = Keys(args.prefix)
        check_name(args.id, "--id")
        ros_domain, ros_distro = ros_settings(args, os.environ) if args.ros2 else (0, "jazzy")
    except FleetError as e:
        return fail(e.message)
    except ValueError as e:
        return fail(str(e))

    from simd.core.mapworld import load_world_or_map
    from simd.core.worldfile import WorldFileError

    try:
        world = load_world_or_map(args.world, args.cell_size)
    except WorldFileError as e:
        return fail(str(e))

    from simd.core import native

    try:  # importing the hot loops reads FLEETSIM_NATIVE / FLEETSIM_LIDAR
        fast = native.status()
    except (ValueError, ImportError) as e:
        if "FLEETSIM_" not in str(e):
            raise
        return fail(str(e))

    import zenoh

    from simd.adapters.fleet.adapter import FleetAdapter
    from simd.core.sim import SimConfig, Simulation
    from simd.engine import Engine, checkpoint

    sim = Simulation(
        world,
        SimConfig(
            seed=args.seed,
            noise=not args.no_noise,
            cmd_timeout=args.cmd_timeout,
            max_robots=args.max_robots,
            odom_noise=args.odom_noise,
        ),
    )
    saver = None
    saved = None
    if args.state:
        state_path = Path(args.state)
        if not state_path.parent.is_dir():
            return fail(f"--state {args.state}: directory {state_path.parent} does not exist")
        try:
            saved = checkpoint.read(state_path)
            restored = 0 if saved is None else checkpoint.restore(sim, saved, state_path)
        except checkpoint.StateFileError as e:
            sim.close()
            return fail(str(e))
        if saved is None:
            print(f"simd: state {state_path}: none yet, the fleet will be kept there", flush=True)
        else:
            print(f"simd: state {state_path}: restored {restored} robots at sim time {sim.time:.3f} s", flush=True)
        saver = checkpoint.Saver(state_path)
    ros_session = None
    router: str | None = None
    ros_source = ""
    if args.ros2:  # first: with --ros-serve-router the fleet session below connects to it
        from protocol.zenoh_config import exposed_without_authentication
        from simd.adapters.ros2.session import RosConfigError, session_config

        try:
            ros = session_config(args.ros_router, serve=args.ros_serve_router, mode=args.ros_mode, env=os.environ)
        except RosConfigError as e:
            return fail(str(e))
        router, ros_source = ros.router, ros.source
        try:
            ros_session = zenoh.open(ros.config)
        except (ValueError, zenoh.ZError) as e:
            msg = zenoh_error_text(e)
            if "in use" in msg.lower():
                msg = "address already in use (is rmw_zenohd running there? then leave out --ros-serve-router)"
            return fail(f"cannot open the ROS 2 session on {router or ros_source}: {msg}")
        exposed = exposed_without_authentication(ros.config, ros.mode)
        if exposed:
            print(f"simd: warning: the ROS 2 session listens on {', '.join(exposed)} without authentication: "
                  "anyone who can reach it can call its services and drive the robots (docs/security.md)",
                  file=sys.stderr, flush=True)  # fmt: skip
    opts = options_from_args(args, server=True)
    through_router = router is not None and not args.listen and not args.config
    if through_router and router is not None:
        # rmw_zenohd (or our own router) holds the port fleet clients know, 7447: the fleet
        # protocol is served through it instead of on a port of its own, as the router's client
        # (a peer that does not listen hears no other peer through a router: the daemons of a
        # shared fleet would not hear each other)
        opts.listen = []
        if args.mode is None:
            opts.mode = "client"
        reach = router.replace("0.0.0.0", "127.0.0.1").replace("[::]", "[::1]")
        if reach not in opts.connect:
            opts.connect.append(reach)
    try:
        conf = opts.build(defaults=TRANSPORT_DEFAULTS)
        if through_router:
            conf.insert_json5("connect/timeout_ms", "-1")  # wait for rmw_zenohd, as ROS processes do
            conf.insert_json5("connect/exit_on_failure", "false")
    except (ValueError, zenoh.ZError) as e:
        if ros_session is not None:
            ros_session.close()
        return fail(f"bad zenoh configuration: {zenoh_error_text(e)}")
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as e:
        if ros_session is not None:
            ros_session.close()
        msg = zenoh_error_text(e)
        if "in use" in msg.lower():
            return fail(f"cannot listen on {opts.endpoints()}: address already in use (is another simd running?)")
        return fail(f"cannot open zenoh session on {opts.endpoints()}: {msg}")
    from protocol.zenoh_config import exposed_without_authentication

    exposed = exposed_without_authentication(conf, opts.mode)
    if exposed:
        print(f"simd: warning: listening on {', '.join(exposed)} without authentication: anyone who can reach it "
              "can spawn, delete and drive robots and answer in the daemon's place; for a secured fleet see "
              "docs/security.md (fleet-security init)", file=sys.stderr, flush=True)  # fmt: skip
    from simd.adapters.fleet.presence import Members, Presence, Unanswered, fleet_tick, infos, refusal, serving, twin

    try:  # asked, not listened for: the answer does not depend on how busy the fleet is
        there = infos(session, keys)
        others = sorted(set(serving(session, keys)) | {i.id for i in there})
        why = refusal(others, there, args.id, world.name, args.join, keys.prefix)
    except Unanswered as e:
        why = f"{e}; is the network or the fleet at prefix {keys.prefix!r} overloaded?"
    if why is not None:
        session.close()
        if ros_session is not None:
            ros_session.close()
        sim.close()
        return fail(why)
    if args.join and others:
        tick = fleet_tick(session, keys)
        if tick is not None and sim.tick == 0 and len(sim.robots) == 0:
            sim.start_at(tick)  # the fleet's clock: stepped together, its daemons' ticks agree
    navigator = None if args.no_nav else _navigator(sim, args)
    if args.state and saved is not None and saved.goals:
        _resume_goals(sim, navigator, saved.goals)
    engine = Engine(sim, rtf=args.rtf, lockstep=args.lockstep, paused=args.paused, saver=saver, navigator=navigator)
    adapter: FleetAdapter | None = None
    presence: Presence | None = None
    ghost_feed = None
    ros_adapter = None
    command_session: zenoh.Session | None = None
    try:
        from simd.adapters.fleet.commands import command_session_needed

        if command_session_needed(opts.mode):  # the same router, the same credentials
            command_session = zenoh.open(conf)
        members = Members(session, keys, args.id) if args.join else None
        adapter = FleetAdapter(session, keys, engine, args.id, members, command_session)
        if members is not None:
            from simd.adapters.fleet.ghosts import GhostFeed

            ghost_feed = GhostFeed(session, keys, members)
            engine.ghost_source = ghost_feed
        presence = Presence(session, keys, args.id, world.name, shared=args.join)
        if args.join:  # another with this id may have started at the same moment: the later leaves
            try:
                first = twin(session, keys, presence.info)
            except Unanswered as e:
                return fail(f"{e}; is the network or the fleet at prefix {keys.prefix!r} overloaded?")
            if first is not None:
                return fail(refusal([args.id], [first], args.id, world.name, True, keys.prefix) or "")
        if ros_session is not None:
            from simd.adapters.ros2.adapter import Ros2Adapter, RosOptions
            from simd.adapters.ros2.shared_fleet import SharedFleet

            options = RosOptions(
                ros_domain, ros_distro, args.ros_world_frame, args.ros_cmd_vel,  # type: ignore[arg-type]
                namespaced_tf=args.ros_tf == "namespaced", localization=args.ros_localization,
            )  # fmt: skip
            shared = SharedFleet(session, keys, args.id) if args.join else None
            ros_adapter = Ros2Adapter(ros_session, engine, options, shared)
            how = "serving as the router on" if args.ros_serve_router else "joining the router at"
            print(f"simd: ROS 2 ({ros_distro}, domain {ros_domain}) {how} {router or '(no router named)'}; "
                  f"session config: {ros_source}", flush=True)  # fmt: skip

        def on_signal(signum: int, frame: FrameType | None) -> None:
            log.info("received %s, stopping", signal.Signals(signum).name)
            engine.stop()

        signal.signal(signal.SIGINT, on_signal)
        signal.signal(signal.SIGTERM, on_signal)
        x, y, _ = world.default_spawn
        mode = "lockstep" if args.lockstep else ("paused" if args.paused else f"rtf {args.rtf:g}")
        if through_router:
            where = f"fleet protocol through the ROS router at {router}"
        elif opts.mode == "client":
            where = f"connected to {opts.endpoints()}"
        else:
            where = f"listening on {opts.endpoints()}"
        print(f"simd: world {world.name} ({world.source}), {mode}, seed {args.seed}; {where}; prefix '{keys.prefix}'; "
              f"id '{args.id}'", flush=True)  # fmt: skip
        slow = {name: why.removeprefix("numpy (").removesuffix(")") for name, why in fast.items() if why != "native"}
        if slow:  # a user who wonders why the daemon is slow should see this
            reasons = set(slow.values())
            why = reasons.pop() if len(reasons) == 1 else "; ".join(f"{k}: {v}" for k, v in slow.items())
            print(f"simd: running the slower numpy versions of {', '.join(slow)} ({why})", flush=True)
        else:
            log.info("compiled fast paths: %s", ", ".join(fast))
        from protocol.programs import runnable

        print(
            f"simd: spawn a robot with: {runnable('fleet-spawn')} tb3_0 --x {x:g} --y {y:g}   "
            f'(or zenoh get -s {keys.spawn} -v \'{{"name": "tb3_0", "x": {x:g}, "y": {y:g}}}\')',
            flush=True,
        )
        engine.run()
    finally:
        if ghost_feed is not None:
            ghost_feed.close()
        if presence is not None:
            presence.close()
        if ros_adapter is not None:
            ros_adapter.close()
        if adapter is not None:
            adapter.close()
        sim.close()
        if ros_session is not None:
            ros_session.close()
        if command_session is not None:
            command_session.close()
        session.close()
    log.info("stopped at sim time %.3f s", sim.time)
    return 0


def _navigator(sim: Simulation, args: argparse.Namespace) -> Navigator:
    """The navigator for the world: a MovingAI map is navigated on its own cells, in lanes; an
    open world on cells laid over it (``--nav-cell`` wide, else as the robots need)."""
    from simd.core.movingai import is_movingai
    from simd.core.worldfile import SHIPPED_WORLDS
    from simd.nav.navigator import NavConfig, Navigator

    data, source = SHIPPED_WORLDS.read(args.world)
    grid_map = is_movingai(data, source)
    config = NavConfig(lanes=True, cell=args.cell_size) if grid_map else NavConfig(cell=args.nav_cell)
    return Navigator(sim.world, sim.config.lidar, sim.robots, config)


def _resume_goals(sim: Simulation, navigator: Navigator | None, goals: list[NavigateRequest]) -> None:
    """The goals saved in the state file, sent again: the robots go on to where they were sent."""
    if navigator is None:
        print(f"simd: state: {len(goals)} goals not resumed (navigation is off: --no-nav)", flush=True)
        return
    resumed = 0
    for goal in goals:
        robot = sim.find(goal.robot)
        try:
            if robot is None:
                raise FleetError(ErrorCode.NOT_FOUND, f"no robot called {goal.robot!r}", "robot")
            navigator.goal(robot.namespace, robot.model, goal, sim.time)
            resumed += 1
        except FleetError as e:
            print(f"simd: state: goal {goal.goal_id} of {goal.robot} not resumed: {e.message}", flush=True)
    navigator.take_events()  # nothing was preempted: the results of a fresh start are none
    print(f"simd: state: resumed {resumed} goals", flush=True)


if __name__ == "__main__":
    sys.exit(main())
