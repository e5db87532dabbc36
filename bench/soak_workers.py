"""The soak's child processes: drivers, a churn of spawns and deletes, and hostile traffic.

Each runs as ``python -m bench.soak_workers ROLE ...`` in a process of its own (as a user's
controller or tool would, so none competes with the soak's own queries for a GIL), until its
stdin closes; then it prints one JSON line of what it did, every request it sent accounted for:
answered, refused with a structured error, or lost (no reply within the timeout).
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import threading
from collections.abc import Callable
from typing import Any

from bench.wire import PREFIX, zenoh_config

#: hostile bodies go to these (a pause or reset that happened to decode would stop the soak's
#: fleet: the fuzz test in tests/daemon covers those keys)
QUERY_KEYS = ["spawn", "delete", "robots", "world", "clock", "sim/step"]
#: a reply later than this is lost (the daemon answers in milliseconds even when overloaded)
REPLY_TIMEOUT_S = 5.0


def _session(endpoint: str) -> Any:
    """A plain zenoh client session, as any zenoh tool would open."""
    import zenoh

    return zenoh.open(zenoh_config(endpoint, 30.0))


def _until_stdin_closes() -> threading.Event:
    """An event set when the parent closes our stdin (its way of saying stop)."""
    done = threading.Event()

    def watch() -> None:
        sys.stdin.read()
        done.set()

    threading.Thread(target=watch, daemon=True).start()
    return done


#: the kinds of :func:`hostile_body` that no key may accept. The others are documents of fields
#: a step does not know, which it takes as a valid one-tick step (unknown fields are ignored, as
#: the protocol says; msgspec skips an unknown field's value unread, invalid UTF-8 included), so
#: they go to every key but the step (they would step the soak's paused fleet)
REFUSED_EVERYWHERE = (1, 2, 6)


def hostile_body(rng: random.Random, kinds: tuple[int, ...] = tuple(range(7))) -> bytes:
    """One body a careless or hostile client might send, of one of ``kinds``."""
    kind = rng.choice(kinds)
    if kind == 0:
        return rng.randbytes(rng.randrange(1, 400))
    if kind == 1:
        d = rng.choice([1000, 10_000, 100_000])
        return b'{"name":' + b"[" * d + b"]" * d + b"}"
    if kind == 2:
        return b"\x81\xa4name" + b"\x91" * rng.choice([1000, 100_000]) + b"\xc0"
    if kind == 3:
        return b'{"name": "\xff\xfe", "x": "\xff"}'
    if kind == 4:
        return json.dumps({"name": "x" * rng.randrange(60, 5000), "x": rng.uniform(-1e9, 1e9)}).encode()
    if kind == 5:
        return json.dumps({"linear": {"x": [rng.random()] * rng.randrange(1, 50_000)}}).encode()
    return b'{"ticks": 1000000, "seed": -1, "cmd_vel": {"ghost": {}}}'


def fuzz(endpoint: str, rate: float, seed: int) -> dict[str, Any]:
    """Hostile traffic at ``rate`` a second: half queries (each must get an answer, and a
    hostile spawn, delete or step a refusal), half puts on cmd_vel keys (real robots' and
    ghosts')."""
    rng = random.Random(seed)
    session = _session(endpoint)
    done = _until_stdin_closes()
    sent = queries = no_reply = accepted = 0
    try:
        while not done.wait(1.0 / rate):
            if rng.random() < 0.5:
                key = f"{PREFIX}/{rng.choice(QUERY_KEYS)}"
                acts = key.endswith(("spawn", "delete", "step"))
                body = hostile_body(rng, REFUSED_EVERYWHERE if key.endswith("step") else tuple(range(7)))
                replies = list(session.get(key, payload=body, timeout=REPLY_TIMEOUT_S))
                queries += 1
                if not replies:
                    no_reply += 1
                elif replies[0].err is None and acts:
                    accepted += 1  # a hostile spawn, delete or step must be refused, with a reason
            else:
                body = hostile_body(rng)
                session.put(f"{PREFIX}/{rng.choice(['r0', 'ghost', 'r1'])}/cmd_vel", body)
            sent += 1
    finally:
        session.close()
    return {"sent": sent, "queries": queries, "no_reply": no_reply, "accepted_hostile": accepted}


def drive(endpoint: str, names: list[str], seed: int) -> dict[str, Any]:
    """Drive ``names`` at 10 Hz through declared publishers, as fleet controllers do; a new
    random turn each second."""
    import msgspec

    from protocol.messages import Twist, Vector3

    rng = random.Random(seed)
    session = _session(endpoint)
    pubs = [session.declare_publisher(f"{PREFIX}/{n}/cmd_vel") for n in names]
    speeds = [rng.uniform(0.1, 0.22) for _ in names]
    done = _until_stdin_closes()
    enc = msgspec.msgpack.Encoder()
    k = 0
    try:
        while not done.wait(0.1):
            if k % 10 == 0:
                payloads = [enc.encode(Twist(linear=Vector3(x=v), angular=Vector3(z=rng.uniform(-1.2, 1.2))))
                            for v in speeds]  # fmt: skip
            for p, body in zip(pubs, payloads, strict=True):
                p.put(body)
            k += 1
    finally:
        session.close()
    return {"robots": len(names), "rounds": k}


class Tally:
    """Requests sent and what came of them: answered, refused (a structured error: the daemon
    heard and said why), lost (no reply: the one outcome a daemon must never give)."""

    def __init__(self) -> None:
        self.sent = self.answered = self.refused = self.lost = 0
        self.refusals: dict[str, int] = {}
        self.last_code = ""  # the last request's error code ("" when answered)

    def ask(self, call: Callable[..., Any], *args: Any) -> Any:
        """``call(*args)``, its outcome counted; the answer, or None when refused or lost."""
        from protocol import FleetError
        from protocol.errors import ErrorCode

        self.sent += 1
        self.last_code = ""
        try:
            answer = call(*args)
        except FleetError as e:
            self.last_code = e.code.value
            if e.code in (ErrorCode.TIMEOUT, ErrorCode.UNAVAILABLE):
                self.lost += 1
            else:
                self.refused += 1
                self.refusals[e.code.value] = self.refusals.get(e.code.value, 0) + 1
            return None
        self.answered += 1
        return answer

    def record(self) -> dict[str, Any]:
        return {"sent": self.sent, "answered": self.answered, "refused": self.refused, "lost": self.lost,
                "refusals": self.refusals}  # fmt: skip


def churn_slots(cx: float, cy: float) -> list[tuple[float, float]]:
    """Four places in the arena's closed pen for extra robots (1.6 m inside), 0.9 m apart:
    robots spawned there are never in the way of the wandering fleet, nor it in theirs."""
    return [(cx + dx, cy + dy) for dx in (-0.45, 0.45) for dy in (-0.45, 0.45)]


def churn(endpoint: str, rate: float, cx: float, cy: float) -> dict[str, Any]:
    """Spawn and delete robots at ``rate`` requests a second: the pen's four places fill, then
    each new spawn follows the delete of the oldest. Prints which churned robots are alive at
    the end, so the soak can check the fleet's list against it."""
    from clients.api import FleetClient

    slots = churn_slots(cx, cy)
    alive: list[tuple[str, int]] = []  # (name, slot), oldest first
    tally = Tally()
    done = _until_stdin_closes()
    k = 0
    with FleetClient(endpoint, prefix=PREFIX, timeout=REPLY_TIMEOUT_S) as client:
        while not done.wait(1.0 / rate):
            if len(alive) == len(slots):
                name, _ = alive[0]
                if tally.ask(client.delete, name) is not None or tally.last_code == "not_found":
                    alive.pop(0)  # (not_found: a delete whose reply was lost had happened)
                continue
            free = next(i for i in range(len(slots)) if i not in {s for _, s in alive})
            name, (x, y) = f"churn_{k}", slots[free]
            k += 1
            if tally.ask(client.spawn, name, x, y, 0.0) is not None:
                alive.append((name, free))
    return {**tally.record(), "spawned": k, "alive": [n for n, _ in alive]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("role", choices=("drive", "fuzz", "churn"))
    ap.add_argument("--endpoint", required=True)
    ap.add_argument("--names", default="", help="drive: the robots, comma-separated")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rate", type=float, default=1.0, help="fuzz, churn: requests a second")
    ap.add_argument("--pen", default="0,0", help="churn: the pen's centre, x,y")
    args = ap.parse_args(argv)
    if args.role == "drive":
        record = drive(args.endpoint, args.names.split(","), args.seed)
    elif args.role == "fuzz":
        record = fuzz(args.endpoint, args.rate, args.seed)
    else:
        cx, cy = (float(v) for v in args.pen.split(","))
        record = churn(args.endpoint, args.rate, cx, cy)
    print(json.dumps(record), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
