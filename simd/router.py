"""``fleet-router``: a Zenoh router for a fleet that spans processes and hosts.

Clients on other machines, behind a firewall that opens one port, or many of them, reach the
daemon through a router instead of the daemon's own listener: the daemon connects to the router
(``simd -m client -e ROUTER``), every client connects to the router (``-e ROUTER``), and Zenoh
routes topics, queries and liveliness between them. This is zenoh-python in router mode, the same
routing as the ``zenohd`` binary, which works in its place with the same endpoints (zenohd is not
packaged for pip; docs/scale-out.md).

    fleet-router                                   # tcp/127.0.0.1:7447
    fleet-router -l tcp/0.0.0.0:7447 -c secure/router.json5   # other hosts, with the security config
    fleet-router -l tcp/127.0.0.1:7448 -e tcp/10.0.0.2:7447   # and meshed with another router

It prints where clients and the daemon should connect, warns when it listens beyond this
machine without authentication (as simd does), and runs until Ctrl-C or SIGTERM.
"""

from __future__ import annotations

import argparse
import signal
import sys
from types import FrameType

from fleetcommon.signals import SignalEvent
from fleetcommon.zenoh_config import (
    DEFAULT_ENDPOINT,
    ZenohOptions,
    exposed_without_authentication,
    zenoh_error_text,
)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="fleet-router",
        description="A Zenoh router between fleetsim daemons and clients (docs/scale-out.md).",
    )
    p.add_argument(
        "-l",
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help=f"endpoint to listen on, repeatable (default: {DEFAULT_ENDPOINT}; tcp/0.0.0.0:7447 for other hosts)",
    )
    p.add_argument(
        "-e", "--connect", action="append", metavar="ENDPOINT", help="another router to mesh with (repeatable)"
    )
    p.add_argument("-c", "--config", metavar="FILE", help="zenoh JSON5 configuration file (e.g. from fleet-security)")
    p.add_argument("--cfg", action="append", metavar="KEY:VALUE", help="set a zenoh config key to a JSON5 value")
    p.add_argument("--multicast-scouting", action="store_true", help="enable zenoh multicast scouting (off by default)")
    return p


def fail(message: str) -> int:
    print(f"fleet-router: error: {message}", file=sys.stderr, flush=True)
    return 2


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    opts = ZenohOptions(
        mode="router",
        listen=list(args.listen or []),
        connect=list(args.connect or []),
        config_file=args.config,
        cfg=list(args.cfg or []),
        multicast_scouting=args.multicast_scouting,
    )
    if not opts.config_file and not opts.listen:
        opts.listen = [DEFAULT_ENDPOINT]
    import zenoh

    try:
        conf = opts.build()
    except ValueError as e:  # (one line already: fleetcommon/zenoh_config.py)
        return fail(str(e))
    stop = SignalEvent()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set_from_signal()  # (never Event.set here: fleetcommon/signals.py)

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as e:
        return fail(f"cannot start the router on {opts.endpoints()}: {zenoh_error_text(e)}")
    try:
        where = opts.endpoints()
        print(f"fleet-router: routing on {where} (zenoh id {session.zid()})", flush=True)
        first = where.split(",")[0].strip()
        print(
            f"fleet-router: connect the daemon with: simd -m client -e {first}\n"
            f"fleet-router: and every client with -e {first}, e.g. fleet list -e {first}; fleet-view -e {first}",
            flush=True,
        )
        exposed = exposed_without_authentication(conf, "router")
        if exposed:
            print(
                f"fleet-router: warning: listening on {', '.join(exposed)} without authentication: anyone "
                "who reaches it can drive the fleet (fleet-security init makes a secured setup; docs/security.md)",
                file=sys.stderr,
                flush=True,
            )
        while not stop.wait(0.5):
            pass
    finally:
        session.close()
    print("fleet-router: stopped", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
