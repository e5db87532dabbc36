"""What the ``fleet`` command prints, built from the daemon's records without any I/O: the
list table (robots in natural name order), a spawn's description, the world and the clock
lines, and the ``fleet-teleop`` command that drives a robot just spawned."""

from __future__ import annotations

import argparse
import math
import shlex
from collections.abc import Sequence

import msgspec

from clients.naming import natural_key
from fleetcommon.zenoh_config import DEFAULT_ENDPOINT
from protocol.control import DEFAULT_DAEMON_ID, Clock, RobotRecord, WorldInfo
from protocol.errors import ErrorReply
from protocol.keys import DEFAULT_PREFIX


class Outcome(msgspec.Struct, kw_only=True, omit_defaults=True):
    """One robot's result in ``spawn --file`` and ``delete`` (their ``--json`` output)."""

    name: str
    ok: bool
    robot: RobotRecord | None = None
    error: ErrorReply | None = None


def in_list_order(records: Sequence[RobotRecord]) -> list[RobotRecord]:
    """``fleet list``'s order: by name, numbers as numbers (burger_2 before burger_10), then by
    namespace; the same whatever order the robots were spawned or answered in."""
    return sorted(records, key=lambda r: (natural_key(r.name), natural_key(r.namespace)))


def format_table(records: Sequence[RobotRecord]) -> str:
    """The ``fleet list`` table: one row per robot, numbers right-aligned; a DAEMON column
    when the robots run on more than one daemon (a shared fleet: docs/scale-out.md)."""
    shared = len({r.daemon for r in records}) > 1
    header = ("NAME", "NAMESPACE", "MODEL", "X", "Y", "YAW", "V", "W", *(("DAEMON",) if shared else ()))
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
            *((r.daemon,) if shared else ()),
        )
        for r in records
    ]
    widths = [max(len(row[i]) for row in (header, *rows)) for i in range(len(header))]
    lines = []
    for row in (header, *rows):
        cells = [
            c.ljust(w) if i < 3 or i == 8 else c.rjust(w) for i, (c, w) in enumerate(zip(row, widths, strict=True))
        ]
        lines.append("  ".join(cells).rstrip())
    return "\n".join(lines)


def teleop_command(namespace: str, args: argparse.Namespace, program: str = "fleet-teleop") -> str:
    """The exact ``fleet-teleop`` command line that reaches the same daemon; ``program`` is how
    the user can run fleet-teleop (a path where it is not on PATH)."""
    parts = [program, namespace]
    if args.connect and args.connect != [DEFAULT_ENDPOINT]:
        for endpoint in args.connect:
            parts += ["-e", endpoint]
    if args.mode and args.mode != "client":
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


def describe_spawn(rec: RobotRecord, teleop: str) -> list[str]:
    """The lines ``fleet spawn`` prints for a spawned robot; ``teleop`` drives it."""
    p = rec.pose
    where = f" on daemon {rec.daemon}" if rec.daemon not in ("", DEFAULT_DAEMON_ID) else ""  # a shared fleet's
    lines = [
        f"spawned {rec.name} ({rec.model}) in namespace {rec.namespace} "
        f"at x {p.x:.3f} m, y {p.y:.3f} m, yaw {p.yaw:.3f} rad ({math.degrees(p.yaw):.1f}°){where}"
    ]
    if rec.topics is not None:
        t = rec.topics
        lines.append(f"  topics: {t.cmd_vel} (in)  {t.odom}  {t.scan}  {t.alive} (liveliness)")
    if rec.frames is not None:
        f = rec.frames
        lines.append(f"  frames: {f.odom}  {f.base_footprint}  {f.base_scan}")
    if rec.limits is not None:
        lim = rec.limits
        lines.append(f"  limits: ±{lim.max_linear_velocity:g} m/s, ±{lim.max_angular_velocity:g} rad/s")
    lines.append(f"  drive it: {teleop}")
    return lines


def describe_world(w: WorldInfo) -> list[str]:
    b, s = w.bounds, w.default_spawn
    return [
        f"world {w.name}: x in [{b.x_min:g}, {b.x_max:g}] m, y in [{b.y_min:g}, {b.y_max:g}] m",
        f"  {len(w.polygons)} polygons, {len(w.circles)} circles",
        f"  default spawn: x {s.x:g}, y {s.y:g}, yaw {s.yaw:g}",
    ]


def describe_clock(c: Clock) -> str:
    state = "lockstep" if c.lockstep else ("paused" if c.paused else "running")
    target = "max" if c.target_real_time_factor == 0 else f"{c.target_real_time_factor:g}"
    line = (
        f"sim time {c.clock.to_seconds():.3f} s, tick {c.tick}, {state}, "
        f"real-time factor {c.real_time_factor:.2f} (target {target}), robots {c.robots}"
    )
    # what a daemon older than these fields does not say is left out (they decode as 0)
    if c.falling_behind:
        line += f", falling behind ({c.behind_s:.1f} s of sim time behind the target)"
    elif c.behind_s >= 0.05:  # what rounds to 0.0 s is not worth a word
        line += f", {c.behind_s:.1f} s of sim time behind the target"
    if c.capacity_robots:
        line += (
            f"; a tick takes {c.tick_s * 1e3:.1f} ms: about {c.capacity_robots} robots like these keep real time here"
        )
    elif c.tick_s > 0 and not c.paused:  # measured, but too few robots to tell a robot's own cost
        line += f"; a tick takes {c.tick_s * 1e3:.1f} ms (how many robots keep real time shows from 20 robots on)"
    return line
