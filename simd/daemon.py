"""Building the daemon from its checked flags (simd/cli.py): the simulation, restored from
``--state``; the ROS 2 session, then the fleet's; the fleet's consent to one more daemon; the
engine, its navigator and its adapters.

Whatever is opened is handed to the caller's ``ExitStack`` the moment it opens, so one place
closes it all, in the reverse order, however the start ends: refused half-way (a ``Refused``
with the line to print), or stopped after running. Heavy modules (pymunk, zenoh's adapters,
rosbags) are imported here, once the flags are known to be good.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from fleetcommon.zenoh_config import exposed_without_authentication, options_from_args, zenoh_error_text
from protocol.errors import ErrorCode, FleetError
from protocol.keys import Keys

if TYPE_CHECKING:
    import zenoh

    from fleetcommon.zenoh_config import ZenohOptions
    from protocol.navigation import NavigateRequest
    from simd.core.sim import Simulation
    from simd.core.worldfile import WorldGeometry
    from simd.engine import Engine
    from simd.engine.checkpoint import SavedFleet, Saver
    from simd.nav.navigator import Navigator

log = logging.getLogger("simd")

#: A tick puts one odometry per robot and a batch of scans back to back (~1.2 MB at 1 000
#: robots). zenoh's default data queue (2 batches of 64 kB) overflows on such bursts and drops;
#: 16 batches (the maximum) absorb them (measured: scans delivered 92% -> 100% at 100 robots).
TRANSPORT_DEFAULTS = {
    "transport/link/tx/queue/size/data": "16",
    "transport/link/tx/queue/size/data_low": "16",  # scans (the publisher's lower priority)
    # zenoh hands a reply over 3 kB to a client on this machine through shared memory, from a
    # pool of 16 MiB by default: the robot list of 20 000 robots (16 MB) did not fit with
    # another reply in flight and went through TCP (docs/robustness.md)
    "transport/shared_memory/transport_optimization/pool_size": str(48 * 1024 * 1024),
}


class Refused(Exception):
    """The daemon cannot start: a flag, a file, the network or the fleet says no. The message
    is the one line ``simd: error: ...`` prints; the exit status is 2."""


@dataclass(frozen=True)
class CheckedFlags:
    """The flags, checked, with what they name: the world loaded, the ROS settings read from
    the environment, which compiled fast paths run."""

    args: argparse.Namespace
    keys: Keys
    world: WorldGeometry
    fast: dict[str, str]  # simd.core.native.status(): label -> "native" or "numpy (why)"
    ros_domain: int = 0
    ros_distro: str = "jazzy"


@dataclass(frozen=True)
class RosSession:
    """The ROS 2 side's zenoh session, and the router it joins or serves."""

    session: zenoh.Session
    router: str | None
    source: str  # where its configuration came from


@dataclass(frozen=True)
class FleetSession:
    """The fleet protocol's zenoh session and how it was opened."""

    session: zenoh.Session
    config: zenoh.Config
    options: ZenohOptions
    through_router: bool  # served through the ROS router (no port of its own)


@dataclass
class Daemon:
    """A daemon built and attached, ready to run: ``engine.run()`` serves until stopped."""

    flags: CheckedFlags
    engine: Engine
    fleet: FleetSession
    ros: RosSession | None

    def announce(self) -> None:
        """The start-up lines: what runs where, what is slow, how to spawn a robot."""
        args, keys, world, fleet = self.flags.args, self.flags.keys, self.flags.world, self.fleet
        x, y, _ = world.default_spawn
        mode = "lockstep" if args.lockstep else ("paused" if args.paused else f"rtf {args.rtf:g}")
        if fleet.through_router:
            where = f"fleet protocol through the ROS router at {self.ros.router if self.ros else None}"
        elif fleet.options.mode == "client":
            where = f"connected to {fleet.options.endpoints()}"
        else:
            where = f"listening on {fleet.options.endpoints()}"
        print(f"simd: world {world.name} ({world.source}), {mode}, seed {args.seed}; {where}; prefix '{keys.prefix}'; "
              f"id '{args.id}'", flush=True)  # fmt: skip
        fast = self.flags.fast
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


def build_daemon(flags: CheckedFlags, teardown: contextlib.ExitStack) -> Daemon:
    """The simulation, the sessions, the engine and its adapters; each handed to ``teardown`` as
    it opens. Refused (and whatever opened closed by ``teardown``) when the start cannot go on."""
    args = flags.args
    sim, saved, saver = _simulation(flags, teardown)
    ros = _open_ros_session(args, teardown) if args.ros2 else None
    fleet = _open_fleet_session(args, ros.router if ros else None, teardown)
    _join_fleet(flags, fleet.session, sim)
    navigator = None if args.no_nav else _navigator(sim, args)
    if saved is not None and saved.goals:
        _resume_goals(sim, navigator, saved.goals)
    from simd.engine import Engine
    from simd.engine.heap import HeapKeeper

    engine = Engine(sim, rtf=args.rtf, lockstep=args.lockstep, paused=args.paused, saver=saver, navigator=navigator,
                    heap=HeapKeeper())  # fmt: skip
    _attach_adapters(flags, engine, fleet, ros, teardown)
    return Daemon(flags, engine, fleet, ros)


def _simulation(
    flags: CheckedFlags, teardown: contextlib.ExitStack
) -> tuple[Simulation, SavedFleet | None, Saver | None]:
    """The simulation, restored from ``--state`` when its file holds a fleet."""
    from simd.core.sim import SimConfig, Simulation
    from simd.engine import checkpoint

    args = flags.args
    config = SimConfig(
        seed=args.seed,
        noise=not args.no_noise,
        cmd_timeout=args.cmd_timeout,
        max_robots=args.max_robots,
        odom_noise=args.odom_noise,
    )
    sim = Simulation(flags.world, config)
    teardown.callback(sim.close)
    if not args.state:
        return sim, None, None
    state_path = Path(args.state)
    if not state_path.parent.is_dir():
        raise Refused(f"--state {args.state}: directory {state_path.parent} does not exist")
    try:
        saved = checkpoint.read(state_path)
        restored = 0 if saved is None else checkpoint.restore(sim, saved, state_path)
    except checkpoint.StateFileError as e:
        raise Refused(str(e)) from None
    if saved is None:
        print(f"simd: state {state_path}: none yet, the fleet will be kept there", flush=True)
    else:
        print(f"simd: state {state_path}: restored {restored} robots at sim time {sim.time:.3f} s", flush=True)
    return sim, saved, checkpoint.Saver(state_path)


def _open_ros_session(args: argparse.Namespace, teardown: contextlib.ExitStack) -> RosSession:
    """The ROS 2 session, first: with --ros-serve-router the fleet session connects to it."""
    import zenoh

    from simd.adapters.ros2.session import RosConfigError, session_config

    try:
        ros = session_config(args.ros_router, serve=args.ros_serve_router, mode=args.ros_mode, env=os.environ)
    except RosConfigError as e:
        raise Refused(str(e)) from None
    try:
        session = zenoh.open(ros.config)
    except (ValueError, zenoh.ZError) as e:
        msg = zenoh_error_text(e)
        if "in use" in msg.lower():
            msg = "address already in use (is rmw_zenohd running there? then leave out --ros-serve-router)"
        raise Refused(f"cannot open the ROS 2 session on {ros.router or ros.source}: {msg}") from None
    teardown.callback(session.close)
    exposed = exposed_without_authentication(ros.config, ros.mode)
    if exposed:
        print(f"simd: warning: the ROS 2 session listens on {', '.join(exposed)} without authentication: "
              "anyone who can reach it can call its services and drive the robots (docs/security.md)",
              file=sys.stderr, flush=True)  # fmt: skip
    return RosSession(session, ros.router, ros.source)


def _open_fleet_session(args: argparse.Namespace, router: str | None, teardown: contextlib.ExitStack) -> FleetSession:
    """The fleet protocol's session: on its own port, or through the ROS router when there is one
    and no --listen or --config says otherwise."""
    import zenoh

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
        raise Refused(f"bad zenoh configuration: {zenoh_error_text(e)}") from None
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as e:
        msg = zenoh_error_text(e)
        if "in use" in msg.lower():
            raise Refused(
                f"cannot listen on {opts.endpoints()}: address already in use (is another simd running?)"
            ) from None
        raise Refused(f"cannot open zenoh session on {opts.endpoints()}: {msg}") from None
    teardown.callback(session.close)
    exposed = exposed_without_authentication(conf, opts.mode)
    if exposed:
        print(f"simd: warning: listening on {', '.join(exposed)} without authentication: anyone who can reach it "
              "can spawn, delete and drive robots and answer in the daemon's place; for a secured fleet see "
              "docs/security.md (fleet-security init)", file=sys.stderr, flush=True)  # fmt: skip
    return FleetSession(session, conf, opts, through_router)


def _overloaded(e: Exception, keys: Keys) -> Refused:
    return Refused(f"{e}; is the network or the fleet at prefix {keys.prefix!r} overloaded?")


def _join_fleet(flags: CheckedFlags, session: zenoh.Session, sim: Simulation) -> None:
    """Whether the fleet at the prefix takes this daemon (asked, not listened for: the answer
    does not depend on how busy the fleet is); with --join, the fleet's clock."""
    from simd.adapters.fleet.presence import Unanswered, fleet_tick, infos, refusal, serving

    args, keys = flags.args, flags.keys
    try:
        there = infos(session, keys)
        others = sorted(set(serving(session, keys)) | {i.id for i in there})
        why = refusal(others, there, args.id, flags.world.name, args.join, keys.prefix)
    except Unanswered as e:
        raise _overloaded(e, keys) from None
    if why is not None:
        raise Refused(why)
    if args.join and others:
        tick = fleet_tick(session, keys)
        if tick is not None and sim.tick == 0 and len(sim.robots) == 0:
            sim.start_at(tick)  # the fleet's clock: stepped together, its daemons' ticks agree


def _attach_adapters(
    flags: CheckedFlags, engine: Engine, fleet: FleetSession, ros: RosSession | None, teardown: contextlib.ExitStack
) -> None:
    """The fleet adapter (on a command session of its own behind a router), the shared fleet's
    ghosts and presence, and the ROS 2 adapter."""
    import zenoh

    from simd.adapters.fleet.adapter import FleetAdapter
    from simd.adapters.fleet.commands import command_session_needed
    from simd.adapters.fleet.presence import Members, Presence, Unanswered, refusal, twin

    args, keys, session = flags.args, flags.keys, fleet.session
    command_session: zenoh.Session | None = None
    if command_session_needed(fleet.options.mode):  # the same router, the same credentials
        command_session = zenoh.open(fleet.config)
        teardown.callback(command_session.close)
    members = Members(session, keys, args.id) if args.join else None
    adapter = FleetAdapter(session, keys, engine, args.id, members, command_session)
    teardown.callback(adapter.close)
    if members is not None:
        from simd.adapters.fleet.ghosts import GhostFeed

        ghost_feed = GhostFeed(session, keys, members)
        teardown.callback(ghost_feed.close)
        engine.ghost_source = ghost_feed
    presence = Presence(session, keys, args.id, flags.world.name, shared=args.join)
    teardown.callback(presence.close)
    if args.join:  # another with this id may have started at the same moment: the later leaves
        try:
            first = twin(session, keys, presence.info)
        except Unanswered as e:
            raise _overloaded(e, keys) from None
        if first is not None:
            raise Refused(refusal([args.id], [first], args.id, flags.world.name, True, keys.prefix) or "")
    if ros is not None:
        from simd.adapters.ros2.adapter import Ros2Adapter, RosOptions
        from simd.adapters.ros2.shared_fleet import SharedFleet

        options = RosOptions(
            flags.ros_domain, flags.ros_distro, args.ros_world_frame, args.ros_cmd_vel,  # type: ignore[arg-type]
            namespaced_tf=args.ros_tf == "namespaced", localization=args.ros_localization,
        )  # fmt: skip
        shared = SharedFleet(session, keys, args.id) if args.join else None
        ros_adapter = Ros2Adapter(ros.session, engine, options, shared)
        teardown.callback(ros_adapter.close)
        how = "serving as the router on" if args.ros_serve_router else "joining the router at"
        print(f"simd: ROS 2 ({flags.ros_distro}, domain {flags.ros_domain}) {how} {ros.router or '(no router named)'}; "
              f"session config: {ros.source}", flush=True)  # fmt: skip


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
