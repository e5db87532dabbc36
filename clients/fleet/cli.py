"""``fleet``: spawn, delete and list the robots of a running ``simd`` (the command line and its
talk with the daemon; what it plans and prints is in spawn_plan.py and fleet_output.py).

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
    fleet daemons                              # which daemons serve the fleet
    fleet goto tb3_0 2.0 0.5 --wait            # send it somewhere, follow it there (clients/fleet/goto.py)

Exit codes: 0 success; 1 refused by the daemon (its reason on stderr as
``fleet: <code>: <message>``); 2 usage error; 3 no daemon answered within ``--timeout``;
4 a goal that ``fleet goto --wait`` followed failed.
"""

from __future__ import annotations

import argparse
import math
import os
import queue
import sys
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import msgspec

from clients.api import FleetClient
from clients.fleet import goto
from clients.fleet.output import (
    Outcome,
    describe_clock,
    describe_spawn,
    describe_world,
    format_table,
    in_list_order,
    teleop_command,
)
from clients.fleet.spawn_plan import SpawnPlan, UsageError, plan_spawn
from clients.fleet_args import build_parser, spawn_parser, takes_value
from clients.fleetfile import FleetRobot
from fleetcommon.zenoh_config import (
    ZenohOptions,
    options_from_args,
)
from protocol.control import Clock, RobotRecord
from protocol.errors import ErrorCode, FleetError, not_found
from protocol.keys import DEFAULT_PREFIX, Keys
from protocol.names import check_name
from protocol.programs import runnable

EXIT_OK = 0
EXIT_REFUSED = 1
EXIT_USAGE = 2
EXIT_NO_DAEMON = 3

#: Error codes that mean "nobody (in time) to talk to", as opposed to a refusal.
NO_DAEMON_CODES = (ErrorCode.UNAVAILABLE, ErrorCode.TIMEOUT)


# --- entry points -----------------------------------------------------------------------------


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    top, cmds = build_parser()
    # Options may come before the command too (`fleet -e tcp/host:7447 list`): move them after it.
    first = next((i for i, a in enumerate(argv) if a in cmds and (i == 0 or not takes_value(argv[i - 1]))), None)
    if first:
        argv = [argv[first], *argv[first + 1 :], *argv[:first]]
    if not argv or argv[0] not in cmds:
        top.parse_args(argv)  # prints help or a usage error and exits
        top.print_help(sys.stderr)  # no command at all
        return EXIT_USAGE
    parser = cmds[argv[0]]
    args = parser.parse_intermixed_args(argv[1:])
    return run(argv[0], args, parser)


def spawn_main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = spawn_parser("fleet-spawn")
    return run("spawn", parser.parse_intermixed_args(argv), parser)


def run(command: str, args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """Run one parsed command; the exit code is the return value."""
    try:
        handler = _HANDLERS[command]
        plan = handler.prepare(args) if handler.prepare else None
        opts = _options(args)
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
    except ValueError as e:
        raise UsageError(f"bad zenoh configuration: {e}") from None
    return opts


def _no_daemon(args: argparse.Namespace) -> int:
    opts = options_from_args(args, server=False)
    prefix = f" with prefix '{args.prefix}'" if args.prefix != DEFAULT_PREFIX else ""
    print(
        f"fleet: no fleetsim daemon{prefix} answered at {opts.endpoints()} "
        f"within {args.timeout:g} s ({opts.no_answer_hint()})",
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


def _describe_spawn(rec: RobotRecord, args: argparse.Namespace) -> None:
    print("\n".join(describe_spawn(rec, teleop_command(rec.namespace, args, runnable("fleet-teleop")))), flush=True)


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


def _run_list(client: FleetClient, args: argparse.Namespace, plan: object) -> int:
    """Every robot, or the ones named (each name not there, or not a name, is one line on
    stderr as ``fleet delete`` says it, and the exit code is 1)."""
    refused: list[tuple[str, FleetError]] = []
    asked = []
    for name in args.names:
        try:
            asked.append(check_name(name))
        except FleetError as e:  # told here, so that one bad name does not refuse the others
            refused.append((name, e))
    records = in_list_order(client.robots(asked) if args.names else client.robots())
    listed = {key for r in records for key in (r.name, r.namespace)}
    refused += [(name, not_found(name)) for name in asked if name not in listed]
    if args.json:
        _print_json(records)
    elif records:
        print(format_table(records))
        print("(x, y in m; yaw in rad; v in m/s; w in rad/s)", flush=True)
    elif not args.names:
        print("no robots; spawn one with: fleet spawn tb3_0 -2 -0.5", flush=True)
    for name, why in sorted(refused, key=lambda r: args.names.index(r[0])):
        _refused(why, name)
    return EXIT_REFUSED if refused else EXIT_OK


def _run_daemons(client: FleetClient, args: argparse.Namespace, plan: object) -> int:
    found = client.daemons()
    if args.watch:
        return _watch_daemons(client, args, [d.id for d in found])
    if args.json:
        _print_json(found)
        return EXIT_OK
    if not found:
        return _no_daemon(args)
    now = time.time()
    rows = [("ID", "WORLD", "HOST", "PID", "UP")]
    rows += [(d.id, d.world, d.host, str(d.pid), _duration(now - d.started)) for d in found]
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    for r in rows:
        print("  ".join(cell.ljust(w) for cell, w in zip(r, widths, strict=True)).rstrip(), flush=True)
    return EXIT_OK


def _watch_daemons(client: FleetClient, args: argparse.Namespace, now: list[str]) -> int:
    """The daemons there now, then one line (or JSON object) per daemon that joins or leaves."""
    events: queue.SimpleQueue[tuple[str, bool]] = queue.SimpleQueue()
    live = set(now)

    def say(daemon_id: str, alive: bool) -> None:
        at = time.strftime("%H:%M:%S")
        if args.json:
            _print_json({"time": time.time(), "daemon": daemon_id, "alive": alive})
        else:
            print(f"{at}  {daemon_id} {'joined' if alive else 'left: its robots left the fleet with it'}", flush=True)

    if not args.json:
        print(f"daemons: {', '.join(sorted(live)) or '(none)'}; watching (Ctrl-C to stop)", flush=True)
    with client.on_daemons(lambda d, alive: events.put((d, alive))):
        try:
            while True:
                daemon_id, alive = events.get()
                if alive != (daemon_id in live):  # history repeats the ones already listed
                    (live.add if alive else live.discard)(daemon_id)
                    say(daemon_id, alive)
        except KeyboardInterrupt:
            return EXIT_OK


def _duration(seconds: float) -> str:
    s = max(0, int(seconds))
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


def _run_world(client: FleetClient, args: argparse.Namespace, plan: object) -> int:
    w = client.world()
    if args.json:
        _print_json(w)
        return EXIT_OK
    print("\n".join(describe_world(w)), flush=True)
    return EXIT_OK


def _print_clock(c: Clock, args: argparse.Namespace) -> int:
    if args.json:
        _print_json(c)
        return EXIT_OK
    print(describe_clock(c), flush=True)
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
    "spawn": _Handler(_run_spawn, lambda args: plan_spawn(args, os.environ.get("TURTLEBOT3_MODEL", ""))),
    "delete": _Handler(_run_delete),
    "list": _Handler(_run_list),
    "world": _Handler(_run_world),
    "daemons": _Handler(_run_daemons),
    "clock": _Handler(_run_clock),
    "pause": _Handler(_run_pause),
    "resume": _Handler(_run_resume),
    "reset": _Handler(_run_reset),
    "step": _Handler(_run_step, _prepare_step),
    "goto": _Handler(goto.run, goto.prepare),
}


if __name__ == "__main__":
    sys.exit(main())
