"""What one spawn or delete costs a large fleet, in-process: the simulation thread and the list.

    python -m bench.fleet_change --robots 20000 [--rounds 10]

It builds the benchmark's arena for N robots (bench/arena.py), fills it through the daemon's
own engine and fleet adapter on a real zenoh session (loopback, nobody listening), and then, a
round at a time: spawns one robot in the extra pen, deletes it, and runs a tick, each timed on
the simulation thread as ``Engine.serve_pending`` and ``Engine.tick`` run it (a spawn's time
holds its adapter's work, a delete's too; the tick after a change lays out the physics' rows
again). Between them it times the MessagePack robot list (what ``P/robots`` answers: the
adapter's records in roster order, encoded from templates by simd/wire/list_codec.py) right
after the spawn, right after the delete and again with nothing changed, and after the
delete one robot's record asked by name and a page of 1 000 (protocol/listing.py), as
``P/robots`` answers them in MessagePack. Medians
of the rounds, in wall milliseconds and in the simulation thread's CPU milliseconds (which
other load on a shared machine inflates less); compare runs side by side.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from functools import partial


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", type=int, default=20000)
    ap.add_argument("--rounds", type=int, default=10)
    args = ap.parse_args(argv)
    sys.setswitchinterval(0.001)  # as simd does (simd/cli.py): the threads' GIL handoffs as in the daemon

    import zenoh

    from bench.arena import make_arena
    from bench.processes import free_port
    from protocol.control import DeleteRequest, ListRequest, SpawnRequest
    from protocol.keys import Keys
    from simd.adapters.fleet.adapter import FleetAdapter
    from simd.core.sim import SimConfig, Simulation
    from simd.core.worldfile import world_from_dict
    from simd.engine import Engine

    n = args.robots
    arena = make_arena(n, 1)
    sim = Simulation(world_from_dict(arena.world), SimConfig(max_robots=n + 1))
    conf = zenoh.Config()
    conf.insert_json5("listen/endpoints", f'["tcp/127.0.0.1:{free_port()}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    engine = Engine(sim, rtf=0.0)
    adapter = FleetAdapter(session, Keys(), engine)
    try:
        t0 = time.perf_counter()
        for i, (x, y, yaw) in enumerate(arena.poses):
            engine.submit(SpawnRequest(name=f"r{i}", x=x, y=y, yaw=yaw), lambda r: None)
            if i % 500 == 499:
                engine.serve_pending()
        engine.serve_pending()
        print(f"{len(sim)} robots spawned in {time.perf_counter() - t0:.1f} s")
        for _ in range(3):
            engine.tick()

        def robot_list() -> object:
            # what the adapter answers a MessagePack list with (FleetAdapter._submit)
            r = engine.known().roster
            records = adapter._list_records(r)
            return adapter._list_encoder.encode(r.time, records, r.x, r.y, r.yaw, r.linear, r.angular)

        times: dict[str, list[float]] = {}
        cpu: dict[str, list[float]] = {}

        def timed(what: str, fn: Callable[[], object]) -> None:
            t, c = time.perf_counter(), time.thread_time()
            fn()
            cpu.setdefault(what, []).append((time.thread_time() - c) * 1e3)
            times.setdefault(what, []).append((time.perf_counter() - t) * 1e3)

        robot_list()
        px, py = arena.extra
        for k in range(args.rounds):
            name = f"extra{k}"
            engine.submit(SpawnRequest(name=name, x=px, y=py, yaw=0.0), lambda r: None)
            timed("spawn", engine.serve_pending)
            timed("list after a spawn", robot_list)
            engine.submit(DeleteRequest(name=name), lambda r: None)
            timed("delete", engine.serve_pending)
            timed("list after a delete", robot_list)
            one, page = ListRequest(names=[f"r{k * 997 % n}"]), ListRequest(after=f"r{k * 1999 % n}", limit=1000)
            timed("one by name, after", partial(adapter.msgpack_list, one))
            timed("a page of 1000, after", partial(adapter.msgpack_list, page))
            timed("tick after", engine.tick)
            timed("tick, nothing changed", engine.tick)
            timed("list, nothing changed", robot_list)
        print(f"{'median ms of ' + str(args.rounds):24s} {'wall':>7s} {'cpu':>7s}  (wall min-max)")
        for what, ms in times.items():
            print(f"{what:24s} {statistics.median(ms):7.2f} {statistics.median(cpu[what]):7.2f}  "
                  f"({min(ms):.2f}-{max(ms):.2f})")  # fmt: skip
    finally:
        engine.stop()
        adapter.close()
        session.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
