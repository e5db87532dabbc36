"""What a driver with a publisher per robot costs a zenoh peer that holds the robots' keys,
in bare zenoh (no simd): does every command arrive, and how long do the declarations a spawn
and a delete make take meanwhile?

    python -m bench.zenoh_declare                        # 8 000 robots' keys, a client driving at 10 Hz
    python -m bench.zenoh_declare --driver-mode peer     # the driver a zenoh peer instead
    python -m bench.zenoh_declare --driver batched       # every command of a cycle in one message
    python -m bench.zenoh_declare --tokens 0             # the control: no keys held here

This process plays the daemon: a peer that listens, holds a liveliness token per robot
(``fleet/r<i>/alive``) and ring subscribers on ``fleet/*/cmd_vel`` and ``fleet/commands`` that
it drains as the simulation thread does. A driver, in a process of its own, connects (as a
zenoh client, as FleetClient and the fleet tools do, or as a peer) and declares a publisher per
robot (``FleetClient.drive``; with ``--driver batched`` one publisher on ``fleet/commands`` that
carries every robot's command of a cycle in one message, as ``FleetClient.drive_many``). Then,
twice side by side, first with the driver silent (``quiet``) and then putting every robot's
command at ``--rate`` Hz (``driven``), this process times what a spawn and a delete ask of
zenoh: declare a token (``P/<ns>/alive``, before a spawn's reply), declare a publisher (a
robot's odometry), put once on a key string (no publisher), undeclare the token (before a
delete's reply). It prints each one's p50 and p99 in ms for both, the ratio driven / quiet, and
how many commands a second the driver put and how many arrived. The numbers are in
docs/robustness.md ("What a publisher per robot costs zenoh").
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from bench.numbers import percentile
from bench.processes import PREEXEC, free_port

if TYPE_CHECKING:
    import zenoh

OPERATIONS = ("token", "publisher", "key_put", "token_undeclare")
#: A Twist in MessagePack is ~60 bytes; an Odometry ~1.1 kB.
COMMAND, ODOMETRY = b"c" * 60, b"o" * 1100


def _config(mode: str, listen: str | None = None, connect: str | None = None) -> zenoh.Config:
    from fleetcommon.zenoh_config import ZenohOptions

    return ZenohOptions(mode=mode, listen=[listen] if listen else [], connect=[connect] if connect else []).build()


def _drive(endpoint: str, publishers: int, rate: float, batched: bool, mode: str) -> None:
    """The driver: a publisher per robot (or one for all, ``batched``); puts every robot's
    command at ``rate`` Hz while the last line read from stdin was ``on``; ends at EOF. A
    zenoh ``client`` (as FleetClient and the fleet tools connect) or a ``peer``."""
    import threading

    import zenoh

    with zenoh.open(_config(mode, connect=endpoint)) as session:
        if batched:  # (names and two float64 a robot, about what PackedCommands carries)
            pubs, payload = [session.declare_publisher("fleet/commands")], COMMAND[:24] * publishers
        else:
            pubs, payload = [session.declare_publisher(f"fleet/r{i}/cmd_vel") for i in range(publishers)], COMMAND
        driving = threading.Event()
        done = threading.Event()

        def read() -> None:
            for line in sys.stdin:
                (driving.set if line.strip() == "on" else driving.clear)()
            done.set()

        threading.Thread(target=read, daemon=True).start()
        print("ready", flush=True)
        period, next_t = 1.0 / rate, time.monotonic()
        puts, driven_s = 0, 0.0
        while not done.is_set():
            if driving.is_set():
                t0 = time.monotonic()
                for p in pubs:
                    p.put(payload)
                puts += len(pubs)
                driven_s += max(period, time.monotonic() - t0)  # a cycle late takes its own time
            next_t = max(next_t + period, time.monotonic() - period)  # (late: no burst to catch up)
            time.sleep(max(0.0, next_t - time.monotonic()))
        per_message = publishers if batched else 1
        print(json.dumps({"commands_per_s": puts * per_message / driven_s if driven_s else 0.0}), flush=True)


def _measure(s: zenoh.Session, drain: Callable[[], None], samples: int, tag: str) -> dict[str, list[float]]:
    """Time each operation ``samples`` times on fresh names (as spawns of new robots)."""
    took: dict[str, list[float]] = {op: [] for op in OPERATIONS}
    for k in range(samples):
        drain()
        ns = f"n{tag}{k}"
        t0 = time.perf_counter()
        token = s.liveliness().declare_token(f"fleet/{ns}/alive")
        t1 = time.perf_counter()
        pub = s.declare_publisher(f"fleet/{ns}/odom")
        t2 = time.perf_counter()
        s.put(f"fleet/{ns}/scan", ODOMETRY)
        t3 = time.perf_counter()
        token.undeclare()
        t4 = time.perf_counter()
        pub.undeclare()
        for op, seconds in zip(OPERATIONS, (t1 - t0, t2 - t1, t3 - t2, t4 - t3), strict=True):
            took[op].append(seconds * 1e3)
        time.sleep(0.02)  # requests one after another, as overload's
    return took


def _ms(values: list[float], p: float) -> float:
    found = percentile(values, p)
    assert found is not None  # (every phase times at least one of each)
    return found


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--publishers", type=int, default=8000, help="robots, each with a publisher (default 8000)")
    ap.add_argument("--rate", type=float, default=10.0, help="commands a second per robot when driven (default 10)")
    ap.add_argument("--samples", type=int, default=200, help="of each operation, per phase (default 200)")
    ap.add_argument("--settle", type=float, default=3.0, help="seconds after the driver starts putting (default 3)")
    ap.add_argument(
        "--driver",
        choices=("robots", "batched"),
        default="robots",
        help="a publisher per robot (default), or every command of a cycle in one message",
    )
    ap.add_argument(
        "--driver-mode",
        choices=("client", "peer"),
        default="client",
        help="how the driver connects: a zenoh client, as FleetClient and the fleet tools do (default), or a peer",
    )
    ap.add_argument("--tokens", type=int, help="robots' tokens this peer holds (default: --publishers; 0: none)")
    ap.add_argument("--drive-endpoint", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.drive_endpoint:
        _drive(args.drive_endpoint, args.publishers, args.rate, args.driver == "batched", args.driver_mode)
        return 0
    if args.publishers < 1 or args.samples < 1 or not args.rate > 0 or args.settle < 0:
        ap.error("--publishers and --samples must be at least 1, --rate above 0, --settle not negative")
    tokens_held = args.publishers if args.tokens is None else args.tokens
    if tokens_held < 0:
        ap.error("--tokens must not be negative")
    import zenoh

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with zenoh.open(_config("peer", listen=endpoint)) as session:
        ring = session.declare_subscriber("fleet/*/cmd_vel", zenoh.handlers.RingChannel(65536))
        batches = session.declare_subscriber("fleet/commands", zenoh.handlers.RingChannel(64))
        tokens = [session.liveliness().declare_token(f"fleet/r{i}/alive") for i in range(tokens_held)]

        received = [0]  # robots' commands taken from the rings (a batch holds every robot's)

        def drain() -> None:
            while ring.try_recv() is not None:
                received[0] += 1
            while batches.try_recv() is not None:
                received[0] += args.publishers

        driver = subprocess.Popen(
            [sys.executable, "-m", "bench.zenoh_declare", "--drive-endpoint", endpoint,
             "--publishers", str(args.publishers), "--rate", str(args.rate), "--driver", args.driver,
             "--driver-mode", args.driver_mode],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, preexec_fn=PREEXEC,
        )  # fmt: skip
        assert driver.stdin is not None and driver.stdout is not None
        try:
            if driver.stdout.readline().strip() != "ready":
                print("zenoh_declare: the driver did not start", file=sys.stderr)
                return 1
            time.sleep(min(args.settle, 1.0))  # its publishers' declarations reach this peer
            quiet = _measure(session, drain, args.samples, "q")
            driver.stdin.write("on\n")
            driver.stdin.flush()
            time.sleep(args.settle)
            drain()
            received[0], since = 0, time.monotonic()
            driven = _measure(session, drain, args.samples, "d")
            drain()
            commands_per_s = received[0] / (time.monotonic() - since)
        finally:
            driver.stdin.close()
            said = driver.stdout.read()
            driver.wait(10.0)
        try:
            sent_per_s = float(json.loads(said.strip().splitlines()[-1])["commands_per_s"])
        except (ValueError, IndexError, KeyError):
            sent_per_s = float("nan")
        for t in tokens:
            t.undeclare()
    how = "one message a cycle on fleet/commands" if args.driver == "batched" else f"{args.publishers} publishers"
    print(f"{tokens_held} robots' tokens here; a driver ({args.driver_mode}) with {how}, every robot's command "
          f"{args.rate:g} times a second when driven: it put {sent_per_s:,.0f} commands a second of "
          f"{args.publishers * args.rate:,.0f}, {commands_per_s:,.0f} a second arrived here; "
          f"{args.samples} of each operation (ms)")  # fmt: skip
    print("| operation | quiet p50 | quiet p99 | driven p50 | driven p99 | p99 driven / quiet |")
    print("|---|---:|---:|---:|---:|---:|")
    for op in OPERATIONS:
        q50, q99, d50, d99 = (_ms(phase[op], p) for phase in (quiet, driven) for p in (50, 99))
        print(f"| {op} | {q50:.2f} | {q99:.2f} | {d50:.2f} | {d99:.2f} | {d99 / max(q99, 1e-9):.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
