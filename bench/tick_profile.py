"""Where one tick of the daemon goes: per-phase times of a free-running fleet, in-process.

    python -m bench.tick_profile --robots 100 --seconds 8

The fleet benchmark (``python -m bench.fleet_bench``) measures what users get; this tool says
why. It builds the benchmark's arena for N robots, runs the daemon's own tick (``Engine.tick``:
commands, physics, lidar, odometry and scan encoding, zenoh puts) as fast as it can on a real
zenoh session, with a separate subscriber process receiving every message, and times each
phase by wrapping the daemon's methods. Robots wander (a new random command per robot every
10 sim-seconds' tick, sent in sim time at 10 Hz as the benchmark's driver does in wall time).

It prints the median and mean of every phase in milliseconds of the sim thread's CPU time
(so that other load on the machine inflates them less than wall time), and the wall time per
tick; the lidar runs in batches (every robot scans every 6th tick), so its mean,
not its median, is its share.
"""

from __future__ import annotations

import argparse
import collections
import random
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from typing import Any

from bench.arena import make_arena
from bench.processes import free_port

_SUBSCRIBER = """
import sys, time, zenoh
c = zenoh.Config()
c.insert_json5("mode", '"client"')
c.insert_json5("connect/endpoints", '["%s"]')
c.insert_json5("scouting/multicast/enabled", "false")
s = zenoh.open(c)
n = [0, 0]
def odom(sample): n[0] += 1
def scan(sample): n[1] += 1
s.declare_subscriber("%s", odom)
s.declare_subscriber("%s", scan)
print("READY", flush=True)
sys.stdin.readline()
print(n[0], n[1], flush=True)
s.close()
"""


def _timed(table: dict[str, list[float]], name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        t = time.thread_time()
        try:
            return fn(*args, **kwargs)
        finally:
            table[name].append(time.thread_time() - t)

    return wrapper


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", type=int, default=100)
    ap.add_argument("--seconds", type=float, default=8.0, help="wall time measured (after 1 s of warm-up)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--substeps", type=int, default=None, help="pymunk steps per tick (default: SimConfig's)")
    ap.add_argument("--iterations", type=int, default=None, help="pymunk solver iterations (default: Physics')")
    ap.add_argument(
        "--follow", choices=("robots", "fleet"), default="robots",
        help="what the subscriber takes: every robot's own topics, or the fleet topics (default: %(default)s)",
    )  # fmt: skip
    args = ap.parse_args(argv)

    import zenoh

    from protocol.control import SpawnRequest
    from protocol.keys import Keys
    from simd.adapters.fleet.adapter import FleetAdapter
    from simd.core.sim import SimConfig, Simulation
    from simd.core.worldfile import world_from_dict
    from simd.engine import Engine

    arena = make_arena(args.robots, args.seed)
    config = SimConfig() if args.substeps is None else SimConfig(substeps=args.substeps)
    sim = Simulation(world_from_dict(arena.world), config)
    if args.iterations is not None:
        sim.physics.space.iterations = args.iterations

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", f'["{endpoint}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("transport/link/tx/queue/size/data", "16")
    conf.insert_json5("transport/link/tx/queue/size/data_low", "16")
    session = zenoh.open(conf)
    topics = ("fleet/*/odom", "fleet/*/scan") if args.follow == "robots" else ("fleet/odometry", "fleet/scans")
    adapter: Any = None
    sub = subprocess.Popen(
        [sys.executable, "-c", _SUBSCRIBER % (endpoint, *topics)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )
    try:
        assert sub.stdout is not None and sub.stdin is not None
        if sub.stdout.readline().strip() != "READY":
            raise SystemExit("the subscriber did not start")
        engine = Engine(sim, rtf=0.0)
        adapter = FleetAdapter(session, Keys(), engine)
        for i, (x, y, yaw) in enumerate(arena.poses):
            engine.submit(SpawnRequest(name=f"r{i}", x=x, y=y, yaw=yaw), lambda r: None)
        engine.serve_pending()
        time.sleep(0.5)

        table: dict[str, list[float]] = collections.defaultdict(list)
        sim.physics.step = _timed(table, "physics", sim.physics.step)  # type: ignore[method-assign]
        space = sim.physics.space
        space.step = _timed(table, "  pymunk steps", space.step)  # type: ignore[method-assign]
        sim.physics.poses = _timed(table, "physics poses", sim.physics.poses)  # type: ignore[method-assign]
        sim._scan = _timed(table, "lidar + noise", sim._scan)  # type: ignore[method-assign]
        sim._sensor_model = _timed(table, "  noise", sim._sensor_model)  # type: ignore[method-assign]
        pub = adapter.publisher
        pub._odom.encode = _timed(table, "odometry encode", pub._odom.encode)
        pub._scans.encode = _timed(table, "scan encode", pub._scans.encode)
        adapter.on_tick = _timed(table, "publish (all)", adapter.on_tick)
        sim.command_many = _timed(table, "commands", sim.command_many)  # type: ignore[method-assign]
        step = _timed(table, "step (all)", sim.step)
        sim.step = step  # type: ignore[method-assign]

        rng = random.Random(args.seed)
        names = list(sim.robots.namespaces)
        speed = {ns: rng.uniform(0.10, 0.22) for ns in names}
        per_tick: list[float] = []
        cpu_tick: list[float] = []
        warm_until = time.perf_counter() + 1.0
        end = warm_until + args.seconds
        measuring = False
        ticks = 0
        t_start = c_start = 0.0
        while True:
            now = time.perf_counter()
            if not measuring and now >= warm_until:
                for v in (*table.values(), per_tick, cpu_tick):
                    v.clear()
                measuring, ticks, t_start, c_start = True, 0, now, time.thread_time()
            if now >= end:
                break
            t0, c0 = time.perf_counter(), time.thread_time()
            if sim.tick % 3 == 0:  # 10 Hz of sim time
                sim.command_many({ns: (speed[ns], rng.uniform(-1.2, 1.2)) for ns in names})
            engine.tick()
            per_tick.append(time.perf_counter() - t0)
            cpu_tick.append(time.thread_time() - c0)
            ticks += 1
        wall = time.perf_counter() - t_start
        cpu = time.thread_time() - c_start
        sub.stdin.write("\n")
        sub.stdin.flush()
        got = sub.stdout.readline().split()
    finally:
        if adapter is not None:
            adapter.close()
        session.close()
        if sub.poll() is None:
            sub.kill()
        sub.wait(5)

    n = len(per_tick)
    print(f"{args.robots} robots, {ticks} ticks in {wall:.1f} s: RTF {ticks * sim.config.dt / wall:.1f} "
          f"(sim thread CPU {cpu / wall * 100:.0f} % of a core)")  # fmt: skip
    print(f"{'phase (CPU)':18s} {'median ms':>10s} {'mean ms':>9s} {'share':>6s}")
    total = statistics.fmean(cpu_tick)
    rows = [("tick (wall)", per_tick), ("tick", cpu_tick), *table.items()]
    for name, vals in rows:
        if not vals:
            continue
        mean = statistics.fmean(vals) * (len(vals) / n)  # per tick, also for phases not run every tick
        print(f"{name:18s} {statistics.median(vals) * 1e3:10.3f} {mean * 1e3:9.3f} {mean / total * 100:5.0f}%")
    if len(got) == 2:
        print(f"subscriber received {int(got[0])} {topics[0]} and {int(got[1])} {topics[1]} messages")
    return 0


if __name__ == "__main__":
    sys.exit(main())
