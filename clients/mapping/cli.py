"""``fleet-map``: build an occupancy map from the fleet's scans and save it as a map_server map.

    fleet-map                               # every robot, until Ctrl-C; writes map.pgm + map.yaml
    fleet-map -o maps/world --robots TB3_1,TB3_2 --duration 120
    fleet-map -o maps/world --force         # replace an existing map

It follows the daemon's fleet topics (a tick's odometry and scans of the whole fleet in one
message each), places every scan at its robot's pose of the same tick plus the lidar's mounting
offset, and fuses the scans of all the robots it follows into one log-odds grid (grid.py),
0.05 m a cell as the TurtleBot3 Cartographer setup. It shows its progress while it runs and
writes, on Ctrl-C or after ``--duration``: ``NAME.pgm`` and ``NAME.yaml`` as nav2's map saver
does (nav2_map_server loads them as they are), and ``NAME.png``, the map with each robot's path.
The poses are the daemon's odometry, exact in this simulation (ground truth, as Gazebo's)
unless ``simd --odom-noise``; for odometry that drifts, ``--match`` corrects each scan by scan
matching (match.py) and closes loops (backend.py), as a SLAM node does.
"""

from __future__ import annotations

import argparse
import queue
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clients.api import FleetClient
from clients.fleet_args import add_daemon_args
from clients.follow import UpToStop, drain, follow, stop_on_signals
from clients.mapping.explore import Explorer
from clients.mapping.grid import LogOddsGrid
from clients.mapping.mapper import Mapper
from clients.tick_merge import stamp_ns
from fleetcommon.mapfile import MapFileError, OccupancyMap, pixels_of, write_map
from fleetcommon.zenoh_config import options_from_args
from protocol import FleetError
from protocol.control import StepReply
from protocol.errors import ErrorCode
from protocol.messages import FleetOdometry, FleetScans, LaserScan

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_NO_DAEMON = 0, 1, 2, 3
#: how often the explorer picks new goals: wall seconds in real time, steps in lockstep
PLAN_EVERY_S = 0.5
PLAN_EVERY_STEPS = 5
#: ticks a lockstep step runs with the commands held (10 Hz of sim time, as a teleop)
TICKS_A_STEP = 3
#: what is added around the world's bounds, so walls on the edge are inside the map
MARGIN_M = 0.5
PATH_COLOURS = [(228, 26, 28), (55, 126, 184), (77, 175, 74), (152, 78, 163), (255, 127, 0), (166, 86, 40)]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="fleet-map", description="Map the world from the fleet's scans; save a map_server map (pgm + yaml)."
    )
    p.add_argument("-o", "--output", default="map", metavar="NAME", help="writes NAME.pgm, NAME.yaml, NAME.png")
    p.add_argument("--robots", metavar="NS,...", help="namespaces whose scans to use (default: every robot)")
    p.add_argument("--resolution", type=float, default=0.05, metavar="M", help="metres a cell (default: 0.05)")
    p.add_argument(
        "--duration", type=float, default=0.0, metavar="S", help="stop after S wall seconds (default: Ctrl-C)"
    )
    p.add_argument("--force", action="store_true", help="replace NAME.pgm / NAME.yaml / NAME.png if they exist")
    p.add_argument(
        "--match",
        action="store_true",
        help="correct each scan's pose by scan matching against the map before fusing it, and close loops (a pose "
        "graph of keyframes, bent back when a robot sees again what it or another mapped): for odometry that "
        "drifts (simd --odom-noise, a real robot); off by default, as simd's odometry is exact unless told",
    )
    p.add_argument(
        "--no-loops",
        action="store_true",
        help="with --match: scan matching only, no loop closure (as slam_toolbox's do_loop_closing: false)",
    )
    p.add_argument(
        "--explore",
        action="store_true",
        help="drive the robots to the frontiers of the map until none is reachable (a --lockstep or paused "
        "daemon is stepped as fast as it goes)",
    )
    p.add_argument(
        "--explore-limit", type=float, default=300.0, metavar="S", help="stop exploring after S sim seconds (300)"
    )
    add_daemon_args(p)
    return p


@dataclass
class Plan:
    stem: Path
    robots: set[str] | None
    resolution: float
    duration: float
    force: bool
    explore: bool = False
    explore_limit: float = 300.0
    matching: bool = False
    loops: bool = True


def plan_from_args(args: argparse.Namespace) -> Plan:
    stem = Path(args.output)
    if stem.suffix in (".pgm", ".yaml", ".png"):
        stem = stem.with_suffix("")
    if not stem.parent.is_dir():
        raise ValueError(f"{stem.parent} is not a directory: create it first")
    if not args.force:
        taken = [p for p in (stem.with_name(stem.name + s) for s in (".pgm", ".yaml", ".png")) if p.exists()]
        if taken:
            raise ValueError(f"{taken[0]} already exists: choose another -o, or --force to replace it")
    if not 0.005 <= args.resolution <= 1.0:
        raise ValueError(f"--resolution must be in 0.005..1 m, got {args.resolution}")
    if not args.duration >= 0:
        raise ValueError(f"--duration must be >= 0, got {args.duration}")
    robots = None
    if args.robots is not None:
        robots = {r.strip().strip("/") for r in args.robots.split(",") if r.strip()}
        if not robots:
            raise ValueError("--robots needs at least one namespace")
    if not args.explore_limit > 0:
        raise ValueError(f"--explore-limit must be > 0, got {args.explore_limit}")
    if args.no_loops and not args.match:
        raise ValueError("--no-loops turns off the loop closure of --match: give --match too")
    return Plan(
        stem, robots, args.resolution, args.duration, args.force, args.explore, args.explore_limit,
        args.match, not args.no_loops,
    )  # fmt: skip


def picture(grid: OccupancyMap, paths: dict[str, list[tuple[float, float]]], path: Path) -> None:
    """The map with each robot's path, scaled up so that a small world is not a thumbnail."""
    from PIL import Image, ImageDraw

    grey = pixels_of(grid)
    scale = max(1, 800 // max(grid.width, grid.height))
    image = (
        Image.fromarray(grey, mode="L")
        .convert("RGB")
        .resize((grid.width * scale, grid.height * scale), Image.Resampling.NEAREST)
    )
    draw = ImageDraw.Draw(image)
    x0, y0, _ = grid.origin
    for k, (_, points) in enumerate(sorted(paths.items())):
        pixels = [((x - x0) / grid.resolution * scale, (grid.height - (y - y0) / grid.resolution) * scale)
                  for x, y in points]  # fmt: skip
        if len(pixels) > 1:
            draw.line(pixels, fill=PATH_COLOURS[k % len(PATH_COLOURS)], width=max(2, scale // 2))
    tmp = path.with_name(f".{path.name}.tmp.png")
    image.save(tmp)
    tmp.replace(path)


def explorer_for(grid: LogOddsGrid, models: dict[str, str], names: list[str]) -> Explorer:
    """Sized for the widest robot it drives (the footprint's reach), at its speed limits."""
    waffle = any(models.get(ns, "burger") != "burger" for ns in names)
    return Explorer(grid.resolution, grid.origin, radius_m=0.22 if waffle else 0.12,
                    max_linear=0.2, max_angular=1.5 if waffle else 2.0)  # fmt: skip


@dataclass
class Drive:
    """Sends the explorer's commands: in real time from the follow loop, or by stepping a paused daemon."""

    client: FleetClient
    mapper: Mapper
    explorer: Explorer
    names: list[str]
    coverage: list[tuple[float, float]]
    stop: threading.Event
    next_plan: float = 0.0
    sim_time: float = 0.0
    #: per robot, the stamp of the last scan fused from a step reply
    fused: dict[str, tuple[int, int]] = field(default_factory=dict)

    def _replan(self) -> bool:
        """New goals on the current map; False when no robot can reach a frontier."""
        cells = self.mapper.grid.occupancy().cells
        poses = {ns: p for ns, p in self.mapper.latest.items() if ns in self.names}
        if not poses:
            return True  # no odometry yet
        self.coverage.append((self.sim_time, self.mapper.grid.explored_m2()))
        self.explorer.plan(cells, poses)
        return not self.explorer.finished()

    def _commands(self) -> dict[str, tuple[float, float]]:
        latest = self.mapper.latest
        return {ns: self.explorer.command(ns, latest[ns]) for ns in self.names if ns in latest}

    def halt(self) -> None:
        """Stop the robots (at the end, before the messages still on their way are taken)."""
        for ns in self.names:
            self.client.stop(ns)

    def realtime(self) -> None:
        now = time.monotonic()
        self.sim_time = max(0.0, self.mapper.latest_stamp * 1e-9)
        if now >= self.next_plan:
            self.next_plan = now + PLAN_EVERY_S
            if not self._replan():
                self.stop.set()
                return
        for ns, (v, w) in self._commands().items():
            self.client.drive(ns, v, w)

    def lockstep(self, inbox: queue.Queue[FleetOdometry | FleetScans], limit: float, duration: float,
                 progress: Callable[[float], str]) -> None:  # fmt: skip
        """Step the daemon a few ticks at a time with the commands held, fusing each tick's scans
        before deciding the next commands: deterministic, and as fast as the daemon runs."""
        t0 = time.monotonic()
        steps = 0
        reply = self.client.step(1, observe=self.names)
        while not self.stop.is_set() and self.sim_time < limit:
            if duration and time.monotonic() - t0 > duration:
                break
            self._catch_up(inbox, reply)
            self.sim_time = reply.clock.to_seconds()
            if steps % PLAN_EVERY_STEPS == 0 and not self._replan():
                break
            reply = self.client.step(TICKS_A_STEP, cmd_vel=self._commands(), observe=self.names)
            steps += 1
            if steps % 50 == 0:
                print(progress(time.monotonic() - t0), file=sys.stderr, flush=True)
        self._catch_up(inbox, reply)

    def _catch_up(self, inbox: queue.Queue[FleetOdometry | FleetScans], reply: StepReply) -> None:
        """Take the odometry the daemon sent up to the step's end (its fleet topics arrive beside
        the reply), then fuse the scans the reply carries, oldest first: the same order every
        run, so lockstep mapping repeats exactly (the topic's scans may arrive after the next
        plan, and are not used here)."""
        stamp = stamp_ns(reply.clock)
        deadline = time.monotonic() + 5.0
        while self.mapper.latest_stamp < stamp and time.monotonic() < deadline:
            try:
                self._take_odometry(inbox.get(timeout=0.5))
            except queue.Empty:
                pass
        drain(inbox, self._take_odometry)
        for scans in self._new_scans(reply):
            self.mapper.on_scans(scans)

    def _take_odometry(self, msg: FleetOdometry | FleetScans) -> None:
        if isinstance(msg, FleetOdometry):
            self.mapper.on_odometry(msg)

    def _new_scans(self, reply: StepReply) -> list[FleetScans]:
        """The reply's scans not fused yet, one FleetScans per tick (a step of three ticks holds
        at most one scan of each robot, which scans every six)."""
        by_tick: dict[tuple[int, int], list[tuple[str, LaserScan]]] = {}
        for ns, seen in reply.observations.items():
            scan = seen.scan
            if scan is None:
                continue
            stamp = (scan.header.stamp.sec, scan.header.stamp.nanosec)
            if self.fused.get(ns) == stamp:
                continue
            self.fused[ns] = stamp
            by_tick.setdefault(stamp, []).append((ns, scan))
        out = []
        for _, group in sorted(by_tick.items()):
            first = group[0][1]
            out.append(FleetScans(stamp=first.header.stamp, namespaces=[ns for ns, _ in group],
                                  beams=len(first.ranges) // 4, angle_min=first.angle_min,
                                  angle_max=first.angle_max, angle_increment=first.angle_increment,
                                  range_min=first.range_min, range_max=first.range_max,
                                  ranges=b"".join(s.ranges for _, s in group)))  # fmt: skip
        return out


def progress_line(mapper: Mapper, elapsed: float) -> str:
    g = mapper.grid
    return (f"mapping {elapsed:6.1f} s: {_robots(len(mapper.paths))}, {g.scans} scans, "
            f"explored {g.explored_m2():.1f} m²")  # fmt: skip


def _robots(n: int) -> str:
    return f"{n} robot{'s' if n != 1 else ''}"


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        plan = plan_from_args(args)
    except ValueError as e:
        print(f"fleet-map: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    stop = stop_on_signals()
    try:
        client = FleetClient(prefix=args.prefix, timeout=args.timeout, options=options_from_args(args, server=False))
        world = client.world()
        robots = {r.namespace: r.model for r in client.robots()}
        started = client.clock()
    except FleetError as e:
        print(f"fleet-map: {e.message}", file=sys.stderr)
        if e.code is ErrorCode.INVALID_VALUE and e.field == "connect":  # (-e, -c or --cfg)
            return EXIT_USAGE
        return EXIT_NO_DAEMON if e.code in (ErrorCode.UNAVAILABLE, ErrorCode.TIMEOUT) else EXIT_FAILED
    missing = sorted((plan.robots or set()) - set(robots))
    if missing:
        client.close()
        print(f"fleet-map: error: no live robot with namespace {', '.join(missing)} "
              f"(live: {', '.join(sorted(robots)) or 'none'})", file=sys.stderr)  # fmt: skip
        return EXIT_USAGE
    b = world.bounds
    grid = LogOddsGrid((b.x_min - MARGIN_M, b.x_max + MARGIN_M, b.y_min - MARGIN_M, b.y_max + MARGIN_M),
                       plan.resolution)  # fmt: skip
    mapper = Mapper(grid, plan.robots, robots, matching=plan.matching, loops=plan.loops)
    inbox: queue.Queue[FleetOdometry | FleetScans] = queue.Queue()
    client.on_fleet_odom(inbox.put)
    client.on_fleet_scans(inbox.put)
    who = "every robot" if plan.robots is None else ", ".join(sorted(plan.robots))
    print(f"fleet-map: mapping {world.name} from the scans of {who} into {plan.stem}.pgm/.yaml (Ctrl-C stops)",
          file=sys.stderr, flush=True)  # fmt: skip
    coverage: list[tuple[float, float]] = []
    up_to_stop = UpToStop(lambda: client.clock().clock, tick_s=started.dt, hurry=stop.hurry)
    try:
        if plan.explore:
            names = sorted(plan.robots or robots)
            drive = Drive(client, mapper, explorer_for(grid, robots, names), names, coverage, stop)
            if started.paused:
                drive.lockstep(inbox, plan.explore_limit, plan.duration, lambda t: progress_line(mapper, t))
            else:
                follow(inbox, mapper.take, stop, plan.duration, lambda t: progress_line(mapper, t), drive.realtime,
                       up_to_stop, on_stop=drive.halt)  # fmt: skip
        else:
            follow(inbox, mapper.take, stop, plan.duration, lambda t: progress_line(mapper, t), None, up_to_stop)
    finally:
        client.close()
        drain(inbox, mapper.take, up_to_stop)
        mapper.give_up_waiting()
    occupancy = grid.occupancy()
    try:
        pgm, meta = write_map(plan.stem, occupancy, force=plan.force)
        png = plan.stem.with_name(plan.stem.name + ".png")
        picture(occupancy, mapper.paths, png)
    except (MapFileError, OSError) as e:
        print(f"fleet-map: error: {e}", file=sys.stderr)
        return EXIT_FAILED
    cells = occupancy.cells
    if (back := mapper.backend) is not None:
        print(f"fleet-map: loop closure: keyframes {len(back.keyframes)}, closures {back.closures}, "
              f"optimisations {back.optimisations}, redraws {back.redraws}", flush=True)  # fmt: skip
    for line in up_to_stop.report("fleet-map", inbox.qsize()):
        print(line, file=sys.stderr, flush=True)
    if mapper.unpaired:
        print(f"fleet-map: {mapper.unpaired} scans came without their tick's odometry (lost on the way) "
              "and are not in the map", file=sys.stderr, flush=True)  # fmt: skip
    if coverage:
        steps = coverage[:: max(1, len(coverage) // 8)] + coverage[-1:]
        print("fleet-map: explored over sim time: " + ", ".join(f"{t:.0f} s {a:.1f} m²" for t, a in steps), flush=True)
    print(
        f"fleet-map: wrote {meta}, {pgm} and {png}: {occupancy.width}x{occupancy.height} cells of "
        f"{plan.resolution:g} m, {grid.scans} scans from {_robots(len(mapper.paths))}, explored "
        f"{grid.explored_m2():.1f} m² ({np.count_nonzero(cells == 100)} occupied cells)",
        flush=True,
    )
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
