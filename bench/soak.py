"""Soak: a driven fleet, hostile traffic beside it, for as long as you like; does anything leak or die?

    python -m bench.soak                                   # 1 000 robots, 10 drivers, 10 minutes
    python -m bench.soak --robots 200 --duration 60        # a shorter look

One ``simd`` (real time, the benchmark's arena); ``--drivers`` processes drive the robots (each
its share, cmd_vel at 10 Hz through declared publishers, as fleet controllers do); one process
sends hostile traffic at ``--fuzz-rate`` a second: random bytes, deeply nested documents,
huge arrays and invalid UTF-8, as queries to every key and as puts on cmd_vel keys (real
robots' and ghosts'); a subscriber process counts every odometry row and scan of the fleet
topics. Every ``--every`` seconds it records the daemon's resident memory, the real-time factor,
the robots still listed and the share of odometry rows and scans delivered. At the end:

- **RSS drift**: the last sample against the first one after a fifth of the run (at least a
  minute: the allocator and zenoh's buffers grow for about that long); flat means within 5 %;
- **lost robots** (must be 0), the daemon alive, the fuzz requests that got no structured answer;
- delivery and RTF over the run (median and worst interval);
- a PNG of RSS and RTF over time next to the JSON (``--out``).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from bench.arena import PROBE, make_arena, write_world
from bench.measure import proc_status_kb
from bench.numbers import median
from bench.processes import PREEXEC, ROOT, start_daemon, stop_process
from bench.subscriber import Subscriber
from bench.wire import PREFIX, zenoh_config

#: hostile bodies go to these (a pause or reset that happened to decode would stop the soak's
#: fleet: the fuzz test in tests/daemon covers those keys)
QUERY_KEYS = ["spawn", "delete", "robots", "world", "clock", "sim/step"]


def _session(endpoint: str) -> Any:
    """A plain zenoh client session, as any zenoh tool would open."""
    import zenoh

    return zenoh.open(zenoh_config(endpoint, 30.0))


def hostile_body(rng: random.Random) -> bytes:
    """One body a careless or hostile client might send."""
    kind = rng.randrange(7)
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


def _until_stdin_closes(done: Any) -> None:
    sys.stdin.read()
    done.set()


def fuzz_worker(endpoint: str, rate: float, seed: int) -> int:
    """Send hostile traffic until stdin closes; print how many queries got no structured answer."""
    import threading

    rng = random.Random(seed)
    session = _session(endpoint)
    done = threading.Event()
    threading.Thread(target=_until_stdin_closes, args=(done,), daemon=True).start()
    sent = unanswered = 0
    try:
        while not done.wait(1.0 / rate):
            body = hostile_body(rng)
            if rng.random() < 0.5:
                key = f"{PREFIX}/{rng.choice(QUERY_KEYS)}"
                replies = list(session.get(key, payload=body, timeout=5.0))
                if not replies or (replies[0].err is None and key.endswith(("spawn", "delete"))):
                    unanswered += 1  # a hostile spawn or delete must be refused, with a reason
            else:
                session.put(f"{PREFIX}/{rng.choice(['r0', 'ghost', 'r1'])}/cmd_vel", body)
            sent += 1
    finally:
        session.close()
    print(json.dumps({"sent": sent, "unanswered": unanswered}), flush=True)
    return 0


def drive_worker(endpoint: str, names: list[str], seed: int) -> int:
    """Drive ``names`` at 10 Hz until stdin closes."""
    import threading

    import msgspec

    from protocol.messages import Twist, Vector3

    rng = random.Random(seed)
    session = _session(endpoint)
    pubs = [session.declare_publisher(f"{PREFIX}/{n}/cmd_vel") for n in names]
    speeds = [rng.uniform(0.1, 0.22) for _ in names]
    done = threading.Event()
    threading.Thread(target=_until_stdin_closes, args=(done,), daemon=True).start()
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
    return 0


def _worker(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "bench.soak", *args], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, cwd=ROOT, preexec_fn=PREEXEC)  # fmt: skip


def soak(robots: int, duration: float, drivers: int, fuzz_rate: float, every: float, tmp: Path) -> dict[str, Any]:
    from clients.api import FleetClient

    arena = make_arena(robots)
    world = tmp / "arena.yaml"
    write_world(arena, world)
    daemon = start_daemon(world, 1.0, robots + 16, tmp)
    workers: list[subprocess.Popen[str]] = []
    sub = Subscriber(daemon.endpoint, PROBE, tmp / "subscriber.log", "fleet")
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                client = FleetClient(daemon.endpoint, prefix=PREFIX, timeout=5.0)
                client.clock()
                break
            except Exception:
                if time.monotonic() > deadline or not daemon.alive():
                    raise RuntimeError(f"simd did not start:\n{daemon.log_tail()}") from None
                time.sleep(0.2)
        sub.wait_ready(30)
        names = [f"r{i}" for i in range(robots)]
        for name, (x, y, yaw) in zip(names, arena.poses, strict=True):
            client.spawn(name, x, y, yaw)
        share = -(-robots // drivers)
        for k in range(drivers):
            part = names[k * share : (k + 1) * share]
            if part:
                workers.append(_worker("--role", "drive", "--endpoint", daemon.endpoint, "--names", ",".join(part),
                                       "--seed", str(k)))  # fmt: skip
        fuzzer = _worker("--role", "fuzz", "--endpoint", daemon.endpoint, "--rate", f"{fuzz_rate:g}")
        samples: list[dict[str, Any]] = []
        t0 = time.monotonic()
        last = (t0, client.clock().tick, sub.snapshot())
        while time.monotonic() - t0 < duration:
            time.sleep(max(0.0, every - (time.monotonic() - last[0])))
            if not daemon.alive():
                raise RuntimeError(f"simd died:\n{daemon.log_tail()}")
            now, tick, snap = time.monotonic(), client.clock().tick, sub.snapshot()
            ticks = tick - last[1]
            odom = sum(snap["odom"].values()) - sum(last[2]["odom"].values())
            scans = sum(snap["scan"].values()) - sum(last[2]["scan"].values())
            listed = len(client.robots())
            s = {"t": round(now - t0, 1), "rss_mb": (proc_status_kb(daemon.pid, "VmRSS") or 0) / 1024,
                 "rtf": ticks / 30.0 / (now - last[0]), "robots": listed,
                 "odom_delivered": odom / max(1, robots * ticks),
                 "scans_delivered": scans / max(1, robots * ticks / 6)}  # fmt: skip
            samples.append(s)
            print(f"soak {s['t']:6.0f} s: RSS {s['rss_mb']:6.1f} MB, RTF {s['rtf']:.3f}, robots {listed}, "
                  f"delivered odom {s['odom_delivered']:.3f} scans {s['scans_delivered']:.3f}", file=sys.stderr,
                  flush=True)  # fmt: skip
            last = (now, tick, snap)
        assert fuzzer.stdin is not None
        fuzzer.stdin.close()
        fuzz = json.loads((fuzzer.stdout.readline() if fuzzer.stdout else "") or "{}")
        fuzzer.wait(30)
        warm = max(60.0, duration / 5)  # the allocator and zenoh's buffers settle first (~70 s seen)
        settled = [s for s in samples if s["t"] >= warm] or samples
        client.close()
        return {
            "robots": robots, "duration_s": duration, "drivers": drivers, "fuzz_rate": fuzz_rate,
            "samples": samples, "fuzz": fuzz, "alive": daemon.alive(),
            "lost_robots": robots - min(s["robots"] for s in samples),
            "rss_drift": settled[-1]["rss_mb"] / settled[0]["rss_mb"] - 1.0,
            "rtf_median": median([s["rtf"] for s in samples]), "rtf_min": min(s["rtf"] for s in samples),
            "odom_delivered_median": median([s["odom_delivered"] for s in samples]),
            "odom_delivered_min": min(s["odom_delivered"] for s in samples),
            "scans_delivered_min": min(s["scans_delivered"] for s in samples),
        }  # fmt: skip
    finally:
        for w in workers:
            if w.stdin is not None and not w.stdin.closed:
                w.stdin.close()
            stop_process(w, 5.0)
        sub.stop()
        daemon.stop()


def plot(result: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = [s["t"] / 60 for s in result["samples"]]
    fig, (a, b) = plt.subplots(2, 1, figsize=(8, 5), sharex=True)
    a.plot(t, [s["rss_mb"] for s in result["samples"]])
    a.set_ylabel("simd RSS (MB)")
    a.set_title(f"soak: {result['robots']} robots driven, hostile traffic at {result['fuzz_rate']:g}/s")
    b.plot(t, [s["rtf"] for s in result["samples"]], label="RTF")
    b.plot(t, [s["odom_delivered"] for s in result["samples"]], label="odometry delivered")
    b.set_ylim(0.9, 1.02)
    b.set_xlabel("minutes")
    b.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", type=int, default=1000)
    ap.add_argument("--duration", type=float, default=600.0, help="seconds (default 600)")
    ap.add_argument("--drivers", type=int, default=10, help="driver processes (default 10)")
    ap.add_argument("--fuzz-rate", type=float, default=20.0, help="hostile messages a second (default 20)")
    ap.add_argument("--every", type=float, default=10.0, help="seconds between samples (default 10)")
    ap.add_argument("--out", default="bench-out/soak.json", help="the JSON (and a PNG beside it)")
    ap.add_argument("--role", choices=("main", "drive", "fuzz"), default="main", help=argparse.SUPPRESS)
    ap.add_argument("--endpoint", help=argparse.SUPPRESS)
    ap.add_argument("--names", help=argparse.SUPPRESS)
    ap.add_argument("--seed", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--rate", type=float, default=20.0, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.role == "drive":
        return drive_worker(args.endpoint, args.names.split(","), args.seed)
    if args.role == "fuzz":
        return fuzz_worker(args.endpoint, args.rate, args.seed)
    if args.robots < 1 or args.drivers < 1 or args.duration <= 0 or args.fuzz_rate <= 0 or args.every <= 0:
        ap.error("--robots, --drivers, --duration, --fuzz-rate and --every must be positive")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="soak-") as tmp:
        result = soak(args.robots, args.duration, args.drivers, args.fuzz_rate, args.every, Path(tmp))
    out.write_text(json.dumps(result, indent=1) + "\n")
    plot(result, out.with_suffix(".png"))
    flat = abs(result["rss_drift"]) <= 0.05
    print(f"soak: {result['robots']} robots for {result['duration_s']:g} s with {result['fuzz'].get('sent', 0)} "
          f"hostile messages: daemon {'alive' if result['alive'] else 'DEAD'}, lost robots {result['lost_robots']}, "
          f"RSS drift {result['rss_drift'] * 100:+.1f} % ({'flat' if flat else 'NOT flat'}), RTF median "
          f"{result['rtf_median']:.3f} (min {result['rtf_min']:.3f}), odometry delivered median "
          f"{result['odom_delivered_median']:.3f} (min {result['odom_delivered_min']:.3f}), scans min "
          f"{result['scans_delivered_min']:.3f}; unanswered hostile spawns/deletes "
          f"{result['fuzz'].get('unanswered', '?')}; wrote {out} and {out.with_suffix('.png')}")  # fmt: skip
    ok = result["alive"] and result["lost_robots"] == 0 and flat and result["fuzz"].get("unanswered") == 0
    return 0 if ok else 1


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
