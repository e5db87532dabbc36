"""How long a client that starts following one robot of a big fleet waits for its first odometry.

A daemon running ``--robots`` robots in real time (the arena of bench.overload, spawned while
paused, then resumed and left to run ``--settle`` s with nobody subscribed to any robot's own
topics); then a FleetClient follows the last-spawned robot (``on_odom``, as fleet-teleop does)
and the wall seconds to its first message are measured, with the daemon's ticks in between.
Issue 33: the daemon declares the robots' publishers a few a tick in spawn order, so without
the follower's announcement the last robot came minutes later at 20 000 robots.

    python -m bench.first_odom --robots 8000
"""

from __future__ import annotations

import argparse
import contextlib
import json
import tempfile
import threading
import time
from pathlib import Path

from bench.arena import make_arena, write_world
from bench.processes import DaemonProc, start_daemon
from bench.wire import PREFIX
from clients import FleetClient, wait_until
from protocol import Odometry, SpawnRequest


def run(n: int, settle: float, timeout: float, tmp: Path) -> dict[str, object]:
    arena = make_arena(n, 1)
    world = tmp / f"arena_{n}.yaml"
    write_world(arena, world)
    with contextlib.ExitStack() as stack:
        daemon: DaemonProc = start_daemon(world, 1.0, n + 1, tmp, ["--paused", "--cmd-timeout", "0", "--no-nav"])
        stack.callback(daemon.stop)
        fleet = stack.enter_context(FleetClient(daemon.endpoint, prefix=PREFIX, timeout=120.0))
        if not wait_until(lambda: bool(fleet.daemons()), 60.0):
            raise RuntimeError(f"simd did not answer within 60 s:\n{daemon.log_tail()}")
        t = time.monotonic()
        fleet.spawn_many(SpawnRequest(name=f"r{i}", x=x, y=y, yaw=yaw) for i, (x, y, yaw) in enumerate(arena.poses))
        spawn_s = time.monotonic() - t
        fleet.resume()
        time.sleep(settle)
        last = f"r{n - 1}"
        first = threading.Event()
        got: list[Odometry] = []

        def on_odom(ns: str, msg: Odometry) -> None:
            if not got:
                got.append(msg)
                first.set()

        follower = stack.enter_context(FleetClient(daemon.endpoint, prefix=PREFIX, timeout=10.0))
        before = fleet.clock()
        tick0 = before.tick
        t0 = time.monotonic()
        follower.on_odom(last, on_odom)
        subscribed_s = time.monotonic() - t0
        arrived = first.wait(timeout)
        wait_s = time.monotonic() - t0
        clock = fleet.clock()
        return {
            "robots": n,
            "spawn_s": round(spawn_s, 1),
            "follow": last,
            "on_odom_returned_s": round(subscribed_s, 3),
            "first_odom_s": round(wait_s, 3) if arrived else None,
            "timed_out_after_s": None if arrived else timeout,
            "ticks_meanwhile": clock.tick - tick0,
            "real_time_factor_before": round(before.real_time_factor, 2),
            "real_time_factor_after": round(clock.real_time_factor, 2),
        }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.first_odom", description=__doc__.split("\n\n")[0])
    p.add_argument("--robots", type=int, default=8000)
    p.add_argument("--settle", type=float, default=5.0, help="seconds running before following (default 5)")
    p.add_argument("--timeout", type=float, default=1800.0, help="give up after this many seconds (default 1800)")
    args = p.parse_args(argv)
    if args.robots < 1 or args.settle < 0 or not args.timeout > 0:
        p.error("--robots must be at least 1, --settle 0 or more and --timeout positive")
    with tempfile.TemporaryDirectory(prefix="first-odom-") as tmp:
        print(json.dumps(run(args.robots, args.settle, args.timeout, Path(tmp))), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
