"""``fleet``: spawn, delete and list the robots of a running ``simd``.

``fleet-spawn ...`` is ``fleet spawn ...``.

The spawner speaks the TurtleBot3 user's language: the positional form of the seed's
``spawn_turtlebot NAME NS X Y Z`` and the flags of gazebo_ros ``spawn_entity.py``
(``-entity``, ``-robot_namespace``, ``-x``, ``-y``, ``-Y``)::

    fleet spawn tb3_0 -2 -0.5                  # name, x, y
    fleet spawn burger_1 TB3_1 -2 -0.5 0.01    # name, namespace, x, y, z (z ignored: 2D)
    fleet-spawn -entity burger_1 -robot_namespace TB3_1 -x -2 -y -0.5 -Y 0
    fleet spawn --file tb3_multi               # the four-robot launch
    fleet list
    fleet delete burger_1

Exit codes: 0 success; 1 refused by the daemon (its reason on stderr as
``fleet: <code>: <message>``); 2 usage error; 3 no daemon answered within ``--timeout``.
"""

from __future__ import annotations

import argparse
import math
import os
import shlex
import sys
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import msgspec
import zenoh

from clients.api import FleetClient
from clients.fleetfile import FleetFileError, FleetRobot, load_fleet
from protocol.control import Clock, RobotRecord, WorldInfo
from protocol.errors import ErrorCode, ErrorReply, FleetError
from protocol.keys import DEFAULT_PREFIX, Keys
from protocol.zenoh_config import (
    DEFAULT_ENDPOINT,
    ZenohOptions,
    add_zenoh_args,
    options_from_args,
)

EXIT_OK = 0
EXIT_REFUSED = 1
EXIT_USAGE = 2
EXIT_NO_DAEMON = 3

#: Error codes that mean "nobody (in time) to talk to", as opposed to a refusal.
NO_DAEMON_CODES = (ErrorCode.UNAVAILABLE, ErrorCode.TIMEOUT)

COMMANDS = ("spawn", "delete", "list", "world", "clock", "pause", "resume", "reset", "step")


class UsageError(Exception):
    """A command line that cannot be run; reported through argparse (exit 2)."""


class Outcome(msgspec.Struct, kw_only=True, omit_defaults=True):
    """One robot's result in ``spawn --file`` and ``delete`` (their ``--json`` output)."""

    name: str
    ok: bool
    robot: RobotRecord | None = None
    error: ErrorReply | None = None


# --- argument parsing -------------------------------------------------------------------------


def _common_parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--prefix", default=DEFAULT_PREFIX, help="key prefix of the daemon (default: %(default)s)")
    common.add_argument(
        "--timeout",
        type=float,
        default=3.0,
        metavar="S",
        help="seconds to wait for the daemon (default: %(default)g)",
    )
    common.add_argument("--json", action="store_true", help="print machine-readable JSON")
    add_zenoh_args(common, server=False)
    return common


SPAWN_USAGE = (
    "%(prog)s [options] NAME [NS] [X Y [Z]]\n"
    "       %(prog)s [options] -entity NAME [-robot_namespace NS] [-x X] [-y Y] [-Y YAW]\n"
    "       %(prog)s [options] --file FLEET"
)


def _add_spawn_arguments(p: argparse.ArgumentParser) -> None:
    p.usage = SPAWN_USAGE
    p.add_argument(
        "words",
        nargs="*",
        metavar="NAME [NS] [X Y [Z]]",
        help="robot name, then optionally its namespace and position in metres "
        "(Z is accepted and ignored: the simulation is 2D)",
    )
    p.add_argument(
        "-entity",
        "--entity",
        dest="entity",
        metavar="NAME",
        help="robot name, as spawn_entity.py -entity",
    )
    p.add_argument(
        "--namespace",
        "-robot_namespace",
        dest="namespace",
        metavar="NS",
        help="namespace of its topics (default: the name)",
    )
    p.add_argument("--x", "-x", dest="x", type=float, metavar="M", help="x in metres (default 0)")
    p.add_argument("--y", "-y", dest="y", type=float, metavar="M", help="y in metres (default 0)")
    p.add_argument("--yaw", "-Y", dest="yaw", type=float, metavar="RAD", help="yaw in radians (default 0)")
    p.add_argument("-z", "--z", dest="z", type=float, metavar="M", help="accepted and ignored (2D)")
    p.add_argument(
        "--model",
        metavar="MODEL",
        help="burger, waffle or waffle_pi (default: $TURTLEBOT3_MODEL, else burger)",
    )
    p.add_argument(
        "-f",
        "--file",
        metavar="FLEET",
        help="spawn every robot of a fleet file: a path, or a shipped fleet by name (tb3_multi)",
    )


def build_parser(
    prog: str = "fleet",
) -> tuple[argparse.ArgumentParser, dict[str, argparse.ArgumentParser]]:
    """The top-level parser (for help) and one parser per command (for parsing)."""
    common = _common_parser()
    top = argparse.ArgumentParser(
        prog=prog,
        description="Spawn, delete and list the robots of a running fleetsim daemon (simd).",
        epilog="Exit codes: 0 ok, 1 refused by the daemon, 2 usage error, 3 no daemon answered. "
        "Run 'fleet COMMAND --help' for a command's options.",
    )
    sub = top.add_subparsers(dest="command", metavar="COMMAND")
    cmds: dict[str, argparse.ArgumentParser] = {}

    def add(name: str, help_: str) -> argparse.ArgumentParser:
        cmds[name] = sub.add_parser(name, parents=[common], help=help_, description=help_)
        return cmds[name]

    _add_spawn_arguments(add("spawn", "spawn a robot, or a fleet file"))
    add("delete", "delete robots by name or namespace").add_argument("names", nargs="+", metavar="NAME")
    add("list", "list the live robots with model, pose and velocity")
    add("world", "describe the loaded world")
    add("clock", "show the simulation clock")
    add("pause", "pause the simulation")
    add("resume", "resume a paused simulation")
    add("reset", "time to zero, robots back to their spawn poses").add_argument(
        "--seed", type=int, help="new noise seed"
    )
    add("step", "advance a paused simulation by N ticks of 1/30 s").add_argument(
        "ticks", nargs="?", type=int, default=1, metavar="N"
    )
    return top, cmds


def spawn_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=prog,
        parents=[_common_parser()],
        description="Spawn a TurtleBot3 into a running fleetsim daemon (same as 'fleet spawn').",
        epilog="Exit codes: 0 ok, 1 refused by the daemon, 2 usage error, 3 no daemon answered.",
    )
    _add_spawn_arguments(p)
    return p


# --- entry points -----------------------------------------------------------------------------


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    top, cmds = build_parser()
    # Options may come before the command too (`fleet -e tcp/host:7447 list`): move them after it.
    first = next((i for i, a in enumerate(argv) if a in cmds and (i == 0 or not _takes_value(argv[i - 1]))), None)
    if first:
        argv = [argv[first], *argv[first + 1 :], *argv[:first]]
    if not argv or argv[0] not in cmds:
        top.parse_args(argv)  # prints help or a usage error and exits
        top.print_help(sys.stderr)  # no command at all
        return EXIT_USAGE
    parser = cmds[argv[0]]
    args = parser.parse_intermixed_args(argv[1:])
    return run(argv[0], args, parser)


_VALUE_FLAGS = frozenset(
    {"-e", "--connect", "-l", "--listen", "-m", "--mode", "-c", "--config", "--cfg", "--prefix", "--timeout"}
)


def _takes_value(arg: str) -> bool:
    """Whether ``arg`` is a global flag whose value follows it (so the next word is no command)."""
    return arg in _VALUE_FLAGS


def spawn_main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = spawn_parser("fleet-spawn")
    return run("spawn", parser.parse_intermixed_args(argv), parser)


def run(command: str, args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """Run one parsed command; the exit code is the return value."""
    try:
        opts = _options(args)
        handler = _HANDLERS[command]
        plan = handler.prepare(args) if handler.prepare else None
        with FleetClient(options=opts, prefix=args.prefix, timeout=args.timeout) as client:
            return handler.run(client, args, plan)
    except UsageError as e:
        parser.error(str(e))  # exits 2
    except BrokenPipeError:  # `fleet list | head`: the reader left; that is not an error
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 - keeps the interpreter's final flush quiet
        return 0
    except FleetError as e:
        if e.code in NO_DAEMON_CODES:
            return _no_daemon(args)
        _refused(e)
        return EXIT_REFUSED
    except KeyboardInterrupt:
        return 130


def _options(args: argparse.Namespace) -> ZenohOptions:
    if not (args.timeout > 0 and math.isfinite(args.timeout)):
        raise UsageError(f"--timeout must be a positive number of seconds, got {args.timeout:g}")
    try:
        Keys(args.prefix)
    except ValueError as e:
        raise UsageError(str(e)) from None
    opts = options_from_args(args, server=False)
    try:
        opts.build()
    except (ValueError, zenoh.ZError) as e:
        raise UsageError(f"bad zenoh configuration: {e}") from None
    return opts


def _no_daemon(args: argparse.Namespace) -> int:
    opts = options_from_args(args, server=False)
    prefix = f" with prefix '{args.prefix}'" if args.prefix != DEFAULT_PREFIX else ""
    print(
        f"fleet: no fleetsim daemon{prefix} answered at {opts.endpoints()} "
        f"within {args.timeout:g} s (start one with: simd)",
        file=sys.stderr,
        flush=True,
    )
    return EXIT_NO_DAEMON


def _refused(e: FleetError, who: str | None = None) -> None:
    head = f"fleet: {who}: " if who else "fleet: "
    print(f"{head}{e.code.value}: {e.message}", file=sys.stderr, flush=True)


def _print_json(obj: object) -> None:
    sys.stdout.write(msgspec.json.encode(obj).decode() + "\n")
    sys.stdout.flush()


# --- spawn ------------------------------------------------------------------------------------


@dataclass
class SpawnPlan:
    robots: list[FleetRobot]
    from_file: bool
    model_from_env: bool


def _number(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def plan_spawn(args: argparse.Namespace) -> SpawnPlan:
    """Turn the positional and flag forms into robots to spawn; raise UsageError."""
    env_model = os.environ.get("TURTLEBOT3_MODEL", "").strip()
    default_model = args.model or env_model or "burger"
    model_from_env = args.model is None and bool(env_model)
    if args.file is not None:
        extra = [
            flag
            for flag, value in (
                ("NAME/NS/X/Y", args.words),
                ("-entity", args.entity),
                ("--namespace", args.namespace),
                ("--x", args.x),
                ("--y", args.y),
                ("--yaw", args.yaw),
            )
            if value not in (None, [])
        ]
        if extra:
            raise UsageError(f"--file cannot be combined with {', '.join(extra)} (only --model, as a default)")
        try:
            entries = load_fleet(args.file)
        except FleetFileError as e:
            raise UsageError(str(e)) from None
        robots = [r if r.model else msgspec.structs.replace(r, model=default_model) for r in entries]
        return SpawnPlan(robots=robots, from_file=True, model_from_env=model_from_env)

    words = list(args.words)
    name = args.entity
    if name is None:
        if not words:
            raise UsageError("a robot NAME is required (or -entity NAME, or --file FLEET)")
        name = words.pop(0)
    namespace = args.namespace
    if words and _number(words[0]) is None:
        if namespace is not None:
            raise UsageError(f"namespace given twice: {words[0]!r} and --namespace {namespace!r}")
        namespace = words.pop(0)
    numbers = [_number(w) for w in words]
    if any(n is None for n in numbers) or len(numbers) not in (0, 2, 3):
        raise UsageError(
            f"after NAME [NS] expected X Y [Z] (metres), got {' '.join(words)!r} (a namespace starts with a letter)"
        )
    x, y = args.x, args.y
    if numbers:
        if x is not None or y is not None:
            raise UsageError("position given twice: positional X Y and --x/--y")
        x, y = numbers[0], numbers[1]
    robot = FleetRobot(
        name=name,
        namespace=namespace,
        model=default_model,
        x=x if x is not None else 0.0,
        y=y if y is not None else 0.0,
        yaw=args.yaw if args.yaw is not None else 0.0,
    )
    return SpawnPlan(robots=[robot], from_file=False, model_from_env=model_from_env)


def _spawn_one(client: FleetClient, r: FleetRobot) -> RobotRecord:
    return client.spawn(r.name, r.x, r.y, r.yaw, model=r.model or "burger", namespace=r.namespace)


def _run_spawn(client: FleetClient, args: argparse.Namespace, plan: object) -> int:
    assert isinstance(plan, SpawnPlan)
    if not plan.from_file:
        r = plan.robots[0]
        try:
            record = _spawn_one(client, r)
        except FleetError as e:
            if e.code == ErrorCode.UNKNOWN_MODEL and plan.model_from_env:
                e.message += " ($TURTLEBOT3_MODEL is set; pass --model to override)"
            raise
        if args.json:
            _print_json(record)
        else:
            _describe_spawn(record, args)
        return EXIT_OK

    # A fleet: every request at once (the daemon serialises them), results in file order.
    def attempt(r: FleetRobot) -> RobotRecord | FleetError:
        try:
            return _spawn_one(client, r)
        except FleetError as e:
            return e

    with ThreadPoolExecutor(max_workers=min(32, len(plan.robots))) as pool:
        results = list(pool.map(attempt, plan.robots))
    return _report_many(args, [r.name for r in plan.robots], results, _describe_spawn)


def _report_many(
    args: argparse.Namespace,
    names: list[str],
    results: Sequence[RobotRecord | FleetError],
    describe: Callable[[RobotRecord, argparse.Namespace], None],
) -> int:
    errors = [r for r in results if isinstance(r, FleetError)]
    if errors and all(e.code in NO_DAEMON_CODES for e in errors) and len(errors) == len(results):
        return _no_daemon(args)
    outcomes = []
    for name, res in zip(names, results, strict=True):
        if isinstance(res, FleetError):
            outcomes.append(Outcome(name=name, ok=False, error=res.to_reply()))
            _refused(res, name)
        else:
            outcomes.append(Outcome(name=name, ok=True, robot=res))
            if not args.json:
                describe(res, args)
    if args.json:
        _print_json(outcomes)
    if any(e.code in NO_DAEMON_CODES for e in errors):
        return EXIT_NO_DAEMON
    return EXIT_REFUSED if errors else EXIT_OK


def teleop_command(namespace: str, args: argparse.Namespace) -> str:
    """The exact ``fleet-teleop`` command line that reaches the same daemon."""
    parts = ["fleet-teleop", namespace]
    if args.connect and args.connect != [DEFAULT_ENDPOINT]:
        for endpoint in args.connect:
            parts += ["-e", endpoint]
    if args.mode != "client":
        parts += ["-m", args.mode]
    for endpoint in args.listen or []:
        parts += ["-l", endpoint]
    if args.config:
        parts += ["-c", args.config]
    for item in args.cfg or []:
        parts += ["--cfg", item]
    if args.multicast_scouting:
        parts.append("--multicast-scouting")
    if args.prefix != DEFAULT_PREFIX:
        parts += ["--prefix", args.prefix]
    return shlex.join(parts)


def _describe_spawn(rec: RobotRecord, args: argparse.Namespace) -> None:
    p = rec.pose
    print(
        f"spawned {rec.name} ({rec.model}) in namespace {rec.namespace} "
        f"at x {p.x:.3f} m, y {p.y:.3f} m, yaw {p.yaw:.3f} rad ({math.degrees(p.yaw):.1f}°)"
    )
    if rec.topics is not None:
        t = rec.topics
        print(f"  topics: {t.cmd_vel} (in)  {t.odom}  {t.scan}  {t.alive} (liveliness)")
    if rec.frames is not None:
        f = rec.frames
        print(f"  frames: {f.odom}  {f.base_footprint}  {f.base_scan}")
    if rec.limits is not None:
        lim = rec.limits
        print(f"  limits: ±{lim.max_linear_velocity:g} m/s, ±{lim.max_angular_velocity:g} rad/s")
    print(f"  drive it: {teleop_command(rec.namespace, args)}", flush=True)


# --- delete, list, world, clock, sim control ----------------------------------------------------


def _run_delete(client: FleetClient, args: argparse.Namespace, plan: object) -> int:
    results: list[RobotRecord | FleetError] = []
    for name in args.names:
        try:
            results.append(client.delete(name))
        except FleetError as e:
            results.append(e)

    def describe(rec: RobotRecord, _: argparse.Namespace) -> None:
        print(f"deleted {rec.name} (namespace {rec.namespace}, {rec.model})", flush=True)

    return _report_many(args, list(args.names), results, describe)


def format_table(records: Sequence[RobotRecord]) -> str:
    """The ``fleet list`` table: one row per robot, numbers right-aligned."""
    header = ("NAME", "NAMESPACE", "MODEL", "X", "Y", "YAW", "V", "W")
    rows = [
        (
            r.name,
            r.namespace,
            r.model,
            f"{r.pose.x:.3f}",
            f"{r.pose.y:.3f}",
            f"{r.pose.yaw:.3f}",
            f"{r.linear_velocity:.3f}",
            f"{r.angular_velocity:.3f}",
        )
        for r in records
    ]
    widths = [max(len(row[i]) for row in (header, *rows)) for i in range(len(header))]
    lines = []
    for row in (header, *rows):
        cells = [c.ljust(w) if i < 3 else c.rjust(w) for i, (c, w) in enumerate(zip(row, widths, strict=True))]
        lines.append("  ".join(cells).rstrip())
    return "\n".join(lines)


def _run_list(client: FleetClient, args: argparse.Namespace, plan: object) -> int:
    records = client.robots()
    if args.json:
        _print_json(records)
        return EXIT_OK
    if not records:
        print("no robots; spawn one with: fleet spawn tb3_0 -2 -0.5", flush=True)
        return EXIT_OK
    print(format_table(records))
    print("(x, y in m; yaw in rad; v in m/s; w in rad/s)", flush=True)
    return EXIT_OK


def _run_world(client: FleetClient, args: argparse.Namespace, plan: object) -> int:
    w: WorldInfo = client.world()
    if args.json:
        _print_json(w)
        return EXIT_OK
    b, s = w.bounds, w.default_spawn
    print(f"world {w.name}: x in [{b.x_min:g}, {b.x_max:g}] m, y in [{b.y_min:g}, {b.y_max:g}] m")
    print(f"  {len(w.polygons)} polygons, {len(w.circles)} circles")
    print(f"  default spawn: x {s.x:g}, y {s.y:g}, yaw {s.yaw:g}", flush=True)
    return EXIT_OK


def _print_clock(c: Clock, args: argparse.Namespace) -> int:
    if args.json:
        _print_json(c)
        return EXIT_OK
    state = "lockstep" if c.lockstep else ("paused" if c.paused else "running")
    target = "max" if c.target_real_time_factor == 0 else f"{c.target_real_time_factor:g}"
    print(
        f"sim time {c.clock.to_seconds():.3f} s, tick {c.tick}, {state}, "
        f"real-time factor {c.real_time_factor:.2f} (target {target}), robots {c.robots}",
        flush=True,
    )
    return EXIT_OK


def _run_clock(client: FleetClient, args: argparse.Namespace, plan: object) -> int:
    return _print_clock(client.clock(), args)


def _run_pause(client: FleetClient, args: argparse.Namespace, plan: object) -> int:
    return _print_clock(client.pause(), args)


def _run_resume(client: FleetClient, args: argparse.Namespace, plan: object) -> int:
    return _print_clock(client.resume(), args)


def _run_reset(client: FleetClient, args: argparse.Namespace, plan: object) -> int:
    return _print_clock(client.reset(args.seed), args)


def _prepare_step(args: argparse.Namespace) -> None:
    if args.ticks < 1:
        raise UsageError(f"N must be at least 1, got {args.ticks}")


def _run_step(client: FleetClient, args: argparse.Namespace, plan: object) -> int:
    # the reply comes after the ticks ran: allow for them on top of the usual deadline
    timeout = args.timeout + args.ticks / 30.0
    return _print_clock(client.step(args.ticks, timeout=timeout), args)


@dataclass(frozen=True)
class _Handler:
    run: Callable[[FleetClient, argparse.Namespace, object], int]
    prepare: Callable[[argparse.Namespace], object] | None = None


_HANDLERS: dict[str, _Handler] = {
    "spawn": _Handler(_run_spawn, plan_spawn),
    "delete": _Handler(_run_delete),
    "list": _Handler(_run_list),
    "world": _Handler(_run_world),
    "clock": _Handler(_run_clock),
    "pause": _Handler(_run_pause),
    "resume": _Handler(_run_resume),
    "reset": _Handler(_run_reset),
    "step": _Handler(_run_step, _prepare_step),
}


if __name__ == "__main__":
    sys.exit(main())
