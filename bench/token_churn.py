"""What a robot name spawned once costs zenoh for good: liveliness tokens declared and
undeclared, one name each, while a client watches presence, in bare zenoh (no simd).

    python -m bench.token_churn                        # 4 000 new names, a watcher
    python -m bench.token_churn --names reused         # the same four names over and over
    python -m bench.token_churn --no-watch             # nobody subscribes to the tokens

simd declares a token ``P/<ns>/alive`` for every robot it spawns and undeclares it at the
delete. This process does the same as a zenoh peer (the daemon's side); a client in a process
of its own subscribes to ``P/*/alive`` as ``FleetClient.on_presence`` does (the fleet's other
daemons with ``--join`` do too). It prints both processes' RSS every 1 000 tokens and the
growth per token: a soak's churn (unique names) against a fleet's steady robots.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

from bench.measure import proc_status_kb
from bench.processes import PREEXEC, free_port


def _watch(endpoint: str, subscribe: bool) -> None:
    """The client: subscribe to every robot's token (or not) until stdin closes."""
    import zenoh

    from bench.wire import zenoh_config

    with zenoh.open(zenoh_config(endpoint, 10.0)) as session:
        sub = session.liveliness().declare_subscriber("fleet/*/alive", lambda s: None) if subscribe else None
        print("ready", flush=True)
        sys.stdin.read()
        if sub is not None:
            sub.undeclare()


def _rss_mb(pid: int) -> float:
    return (proc_status_kb(pid, "VmRSS") or 0) / 1024


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tokens", type=int, default=4000)
    ap.add_argument("--rate", type=float, default=100.0, help="tokens a second (default 100)")
    ap.add_argument("--names", choices=("unique", "reused"), default="unique")
    ap.add_argument("--no-watch", action="store_true", help="the client subscribes to nothing")
    ap.add_argument("--watch-endpoint", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.watch_endpoint:
        _watch(args.watch_endpoint, not args.no_watch)
        return 0
    import zenoh

    from fleetcommon.zenoh_config import ZenohOptions

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with zenoh.open(ZenohOptions(mode="peer", listen=[endpoint]).build()) as peer:
        client = subprocess.Popen(
            [sys.executable, "-m", "bench.token_churn", "--watch-endpoint", endpoint]
            + (["--no-watch"] if args.no_watch else []),
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, preexec_fn=PREEXEC,
        )  # fmt: skip
        assert client.stdout is not None and client.stdin is not None
        client.stdout.readline()  # ready
        time.sleep(1.0)  # its subscription reaches the peer
        first = (_rss_mb(os.getpid()), _rss_mb(client.pid))
        for k in range(1, args.tokens + 1):
            name = f"fleet/churn_{k if args.names == 'unique' else k % 4}/alive"
            token = peer.liveliness().declare_token(name)
            time.sleep(1.0 / args.rate)
            token.undeclare()
            if k % 1000 == 0 or k == args.tokens:
                here, there = _rss_mb(os.getpid()), _rss_mb(client.pid)
                record = {"tokens": k, "peer_rss_mb": round(here, 1), "client_rss_mb": round(there, 1),
                          "peer_kb_per_token": round((here - first[0]) * 1024 / k, 2),
                          "client_kb_per_token": round((there - first[1]) * 1024 / k, 2)}  # fmt: skip
                print(json.dumps(record), flush=True)
        client.stdin.close()
        client.wait(10)
    return 0


if __name__ == "__main__":
    sys.exit(main())
