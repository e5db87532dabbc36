"""The daemon's tick rate while ROS 2 cmd_vel floods in: ``python -m bench.ros_cmd_vel``.

A ``simd --ros2 --ros-serve-router --rtf 0`` with ``--robots`` robots runs as fast as it can;
a second process puts Twist CDR on every robot's ``/<ns>/cmd_vel`` (rmw_zenoh's keys) ``--hz``
times a second (teleops and Nav2 controllers send at 10 to 20 Hz). The sim seconds the daemon
advances per wall second are measured with and without the commands, ``--seconds`` each,
``--runs`` times: what the commands cost the simulation is what taking them costs it (the ROS
adapter's cmd_vel intake).
"""

from __future__ import annotations

import argparse
import itertools
import multiprocessing
import statistics
import struct
import subprocess
import sys
import time
from typing import TYPE_CHECKING

import zenoh

from bench.processes import ROOT, free_port, stop_process
from clients.api import FleetClient
from protocol.control import SpawnRequest

if TYPE_CHECKING:
    from multiprocessing.sharedctypes import Synchronized

TWIST_KEY = "0/{ns}/cmd_vel/geometry_msgs::msg::dds_::Twist_/TypeHashNotSupported"  # any hash chunk is taken
TWIST = b"\x00\x01\x00\x00" + struct.pack("<6d", 0.1, 0.0, 0.0, 0.0, 0.0, 0.3)  # CDR, little endian


def flood(router: str, namespaces: list[str], hz: float, seconds: float, sent: Synchronized[int]) -> None:
    """Put a Twist on every robot's cmd_vel ``hz`` times a second, for ``seconds``."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", f'["{router}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(conf) as session:
        pubs = [session.declare_publisher(TWIST_KEY.format(ns=ns)) for ns in namespaces]
        n = 0
        start = time.monotonic()
        for k in itertools.count():
            due = start + k / hz
            if due > start + seconds:
                break
            time.sleep(max(0.0, due - time.monotonic()))
            for pub in pubs:
                pub.put(TWIST)
            n += len(pubs)
        sent.value = n


def sim_rate(client: FleetClient, seconds: float) -> float:
    """Sim seconds per wall second over ``seconds``."""
    t0, s0 = time.monotonic(), client.clock().clock.to_seconds()
    time.sleep(seconds)
    t1, s1 = time.monotonic(), client.clock().clock.to_seconds()
    return (s1 - s0) / (t1 - t0)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.ros_cmd_vel", description=__doc__.splitlines()[0])
    p.add_argument("--robots", type=int, default=100)
    p.add_argument("--hz", type=float, default=20.0, help="commands a second to each robot (default: %(default)s)")
    p.add_argument("--seconds", type=float, default=5.0)
    p.add_argument("--runs", type=int, default=3)
    args = p.parse_args(argv)
    router, fleet = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    cmd = [sys.executable, "-m", "simd.cli", "--world", "empty", "--rtf", "0", "--no-noise", "--no-nav",
           "--max-robots", str(args.robots), "-l", fleet, "--ros2", "--ros-serve-router", "--ros-router", router,
           "--log-level", "warning"]  # fmt: skip
    daemon = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL)
    try:
        with FleetClient(fleet, timeout=10.0) as c:
            deadline = time.monotonic() + 30
            while True:
                try:
                    c.clock()
                    break
                except Exception:
                    if time.monotonic() > deadline or daemon.poll() is not None:
                        raise
                    time.sleep(0.2)
            side = int(args.robots**0.5) + 1
            c.spawn_many(
                SpawnRequest(name=f"r{i}", x=-4.0 + 0.6 * (i % side), y=-4.0 + 0.6 * (i // side))
                for i in range(args.robots)
            )
            namespaces = [r.namespace for r in c.robots()]
            quiet, flooded, rates = [], [], []
            spawner = multiprocessing.get_context("spawn")  # a fork would copy this process's zenoh session
            for _ in range(args.runs):
                quiet.append(sim_rate(c, args.seconds))
                sent = spawner.Value("q", 0)
                flood_args = (router, namespaces, args.hz, args.seconds + 2.0, sent)
                proc = spawner.Process(target=flood, args=flood_args)
                proc.start()
                time.sleep(1.0)  # the flooder's session is up and putting
                flooded.append(sim_rate(c, args.seconds))
                proc.join()
                rates.append(sent.value / (args.seconds + 2.0))
        print(f"robots {args.robots}, cmd_vel at {args.hz:g} Hz each, {args.runs} runs of {args.seconds:g} s "
              "(medians):")  # fmt: skip
        print(f"  sim s per wall s, quiet:   {statistics.median(quiet):.2f}  {[round(q, 2) for q in quiet]}")
        print(f"  sim s per wall s, flooded: {statistics.median(flooded):.2f}  {[round(f, 2) for f in flooded]}")
        print(f"  cmd_vel put per wall s:    {statistics.median(rates):.0f}")
    finally:
        daemon.terminate()
        stop_process(daemon, 10.0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
