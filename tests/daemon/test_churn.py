"""Robots spawned and deleted for ever, every name new (the soak's churn, bench/soak.py), leave
nothing behind in the daemon: what it keeps is the same after forty robots came and went as
after ten. Counted in objects, on the engine and the fleet adapter in-process on a real zenoh
session, ticked by the test (no wall clock)."""

from __future__ import annotations

import gc
import json
import random
import threading

import zenoh

from clients import FleetClient
from protocol import Keys
from protocol.control import DeleteRequest, SpawnRequest
from simd.adapters.fleet.adapter import FleetAdapter
from simd.core.sim import SimConfig, Simulation
from simd.core.snapshot import TickSnapshot
from simd.core.worldfile import load_world
from simd.engine import Engine
from simd.wire.convert import robot_record
from tests.conftest import free_port


def _session(port: int) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


def _snapshots() -> int:
    gc.collect()
    return sum(isinstance(o, TickSnapshot) for o in gc.get_objects())


def test_a_robot_deleted_while_its_ticks_wait_to_be_sent_leaves_no_snapshot_behind() -> None:
    """A delete is answered at once, while the ticks queued before it still wait for the
    adapter's thread (a slow spell: the outbox is busy). Those ticks name the robot; the scan
    of it they carried was kept as its latest, and with it the whole tick's snapshot (every
    robot's columns and scans: ~0.3 MB at 1 000 robots), for ever, as no robot of that name came
    back. The soak leaked one every few minutes; a day's churn would keep hundreds."""
    sim = Simulation(load_world("empty"), SimConfig(noise=False, scan_every=1))  # every robot scans every tick
    with _session(free_port()) as session:
        engine = Engine(sim, lockstep=True)
        adapter = FleetAdapter(session, Keys(), engine)
        answers: list[object] = []
        try:
            engine.submit(SpawnRequest(name="stays", x=-2.0), answers.append)
            counted: dict[int, int] = {}
            for k in range(40):
                name = f"churn_{k}"
                engine.submit(SpawnRequest(name=name, x=2.0), answers.append)
                engine.serve_pending()
                busy = threading.Event()
                adapter.outbox.put(busy.wait)  # the adapter's thread is busy sending
                engine.tick()  # queued behind it: a tick with the robot's scan
                engine.submit(DeleteRequest(name=name), answers.append)
                engine.serve_pending()  # answered at once
                busy.set()
                assert adapter.outbox.flush()
                assert adapter.publisher.latest_scan(name) is None
                if k + 1 in (10, 40):
                    counted[k + 1] = _snapshots()
            assert counted[40] == counted[10], counted
            assert adapter.publisher.latest_scan("stays") is not None
            assert len(answers) == 81 and all(not isinstance(a, Exception) for a in answers)
        finally:
            adapter.close()


def test_the_robot_list_after_every_spawn_and_delete_is_every_robots_record_in_spawn_order() -> None:
    """The list is made from the last one after a fleet change (the adapter's records and the
    encoder's layout, carried over by identity): after random spawns and deletes, one or a few
    between two lists, a client gets every robot's record as a spawn makes it, in spawn order."""
    port = free_port()
    sim = Simulation(load_world("empty"), SimConfig(noise=False))
    rng = random.Random(7)
    places = [(float(i % 8) - 3.5, float(i // 8) - 3.5) for i in range(64)]
    with _session(port) as session, FleetClient(f"tcp/127.0.0.1:{port}", timeout=10.0) as client:
        engine = Engine(sim, lockstep=True)
        adapter = FleetAdapter(session, Keys(), engine)
        answers: list[object] = []
        try:
            free, made = list(places), 0
            taken: dict[str, tuple[float, float]] = {}
            for _ in range(40):
                for _ in range(rng.choice((1, 1, 1, 2, 3))):
                    if taken and (not free or rng.random() < 0.45):
                        name = rng.choice(sorted(taken))
                        engine.submit(DeleteRequest(name=name), answers.append)
                        free.append(taken.pop(name))
                    else:
                        x, y = free.pop(rng.randrange(len(free)))
                        taken[f"r{made}"] = (x, y)
                        engine.submit(SpawnRequest(name=f"r{made}", x=x, y=y), answers.append)
                        made += 1
                    engine.serve_pending()
                expected = [robot_record(sim.state(r), Keys()) for r in sim.robots.robots]
                assert client.robots() == expected
            assert made > 20 and len(answers) > 40 and all(not isinstance(a, Exception) for a in answers)
        finally:
            adapter.close()
