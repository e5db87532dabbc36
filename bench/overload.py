"""A daemon overloaded on purpose: does its control plane still answer, and how fast?

    python -m bench.overload --sizes 8000 10000 20000          # the issue's sizes
    python -m bench.overload --sizes 2000 --paused-s 5 --running-s 10   # a short look

For each fleet size N, all real processes on loopback: ``simd`` on the benchmark's arena for N
burgers (``--max-robots N+1``: one more spawn fits, the next is refused), started paused and
filled; one subscriber process on the fleet topics (``P/odometry``, ``P/scans``); this process
subscribes to a few robots' own topics (so the daemon encodes and puts every robot's odometry
and scans, as it does whenever anybody follows one robot); a driver process commands every
robot at 10 Hz, as bench/driver.py does: every robot's command of a cycle in one message on
``P/commands`` (``FleetClient.drive_many``), or with ``--driver robots`` through one declared
publisher per robot (``FleetClient.drive``, or a ROS tool per robot).

Then two phases, each a loop of requests one after another as a user's tools send them: the
clock, the robot list (``robots``: all of it; ``named``: one robot by name, as ``fleet list
NAME`` asks; ``page``: 1 000 robots after a name, as a tool reading a big fleet page by page
asks), the world, a spawn (accepted), a spawn beyond the limit (refused), the delete of the
spawned one, a pause and a resume (only while running). ``paused``: right after
the driver attached (its thousands of publishers being declared), with time stopped; ``running``:
time runs on, at whatever factor the machine manages (far below real time at these sizes).
Every request is timed from this process (p50/p95/p99/max per kind, per phase); one that gets no
answer within ``--timeout`` counts as lost. The real-time factor achieved is read from the
clock's ticks over ``--settle`` seconds of running before the requests (which pause it).
Beside the daemon, in each phase, a process that does nothing but nap 5 ms at a time says how
late the machine wakes it (bench/sleeper.py): no process answers faster than the machine lets
it run, so a run on a machine shared with other work shows it there. Writes ``overload.json``
(``--out``).
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from bench.arena import make_arena, write_world
from bench.client import Fleet, spawn_request
from bench.numbers import percentile
from bench.processes import PREEXEC, ROOT, DaemonProc, raise_exit, start_daemon, stop_process
from bench.progress import Progress
from bench.report import DRIVEN, machine_info, machine_line
from bench.sleeper import Sleeper
from bench.subscriber import Subscriber
from bench.wire import PREFIX, TICK_HZ
from protocol.control import DeleteRequest, ListRequest

#: What the issue asks of every request kind: answered within this, p99, however loaded.
BOUND_S = 0.100
KINDS = ("clock", "robots", "named", "page", "world", "spawn", "spawn_refused", "delete", "pause", "resume")
#: Records in a page of the list (``page``: what a tool showing a big fleet asks for).
PAGE = 1000
#: What ``--driver`` puts, for the report.
DRIVERS = {
    "robots": "a publisher per robot, 10 Hz",
    "batched": "every robot's command in one message on P/commands, 10 Hz",
}
#: Robots of the fleet whose own topics this process follows (the daemon then encodes and puts
#: every robot's odometry and scans: its per-robot topics are on).
WATCHED = 4


def driver_main(endpoint: str, robots: int, seed: int, batched: bool) -> int:
    """A separate process: drives robots r0..r{robots-1} at 10 Hz (bench/driver.py); prints
    ``READY`` once its publishers are declared, stops on EOF of stdin or SIGTERM."""
    from bench.driver import Driver

    signal.signal(signal.SIGTERM, raise_exit)
    fleet = Fleet(endpoint)
    try:
        driver = Driver(fleet, [f"r{i}" for i in range(robots)], seed, batched=batched)
        driver.start()
        print("READY", flush=True)
        sys.stdin.read()
        driver.stop()
        print(json.dumps(driver.stats()), flush=True)
    finally:
        fleet.close()
    return 0


class DriverProc:
    """The driver process, from this side."""

    def __init__(self, endpoint: str, robots: int, seed: int, log: Path, how: str = "batched") -> None:
        self.log = log.open("w")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "bench.overload", "--role", "driver", "--endpoint", endpoint,
             "--robots", str(robots), "--seed", str(seed), "--driver", how],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.log, text=True, cwd=ROOT,
            env={**os.environ, "PYTHONUNBUFFERED": "1"}, start_new_session=True, preexec_fn=PREEXEC,
        )  # fmt: skip

    def wait_ready(self, timeout: float) -> None:
        stdout = self.proc.stdout
        assert stdout is not None
        done = threading.Event()
        line: list[str] = []

        def read() -> None:
            line.append(stdout.readline())
            done.set()

        threading.Thread(target=read, daemon=True).start()
        if not done.wait(timeout) or not line or not line[0].startswith("READY"):
            raise RuntimeError(f"the driver was not ready within {timeout:g} s ({line})")

    def stop(self) -> dict[str, Any]:
        stats: dict[str, Any] = {}
        try:
            out, _ = self.proc.communicate("", timeout=10.0)
            stats = json.loads(out.strip().splitlines()[-1]) if out.strip() else {}
        except (subprocess.TimeoutExpired, ValueError, OSError):
            pass
        stop_process(self.proc, 1.0)
        self.log.close()
        return stats


class Probe:
    """Requests one after another, timed; each kind's latencies and losses."""

    def __init__(self, fleet: Fleet, timeout: float, robots: int) -> None:
        self.fleet = fleet
        self.timeout = timeout
        self.robots = robots
        self.seconds: dict[str, list[float]] = {k: [] for k in KINDS}
        self.lost: dict[str, int] = {k: 0 for k in KINDS}
        self.unexpected: list[str] = []

    def ask(self, kind: str, key: str, request: object | None, want_ok: bool = True) -> bytes | None:
        ok, payload, seconds = self.fleet.query(f"{PREFIX}/{key}", request, self.timeout)
        if not ok and payload in ("timeout", "no daemon answered"):
            self.lost[kind] += 1
            return None
        self.seconds[kind].append(seconds)
        if ok != want_ok:
            self.unexpected.append(f"{kind}: {payload if not ok else 'accepted'}")
        return payload if ok else None

    def cycle(self, pen: tuple[float, float], running: bool, k: int) -> None:
        """One round of every kind."""
        self.ask("clock", "clock", None)
        self.ask("robots", "robots", None)
        self.ask("named", "robots", ListRequest(names=[f"r{(k * 7919) % self.robots}"]))
        self.ask("page", "robots", ListRequest(after=f"r{(k * 104729) % self.robots}", limit=PAGE))
        self.ask("world", "world", None)
        self.ask("spawn", "spawn", spawn_request(f"extra{k}", pen[0], pen[1], 0.0))
        self.ask("spawn_refused", "spawn", spawn_request(f"over{k}", pen[0] + 0.5, pen[1], 0.0), want_ok=False)
        self.ask("delete", "delete", _delete(f"extra{k}"))
        if running:
            self.ask("pause", "sim/pause", None)
            self.ask("resume", "sim/resume", None)

    def summary(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for kind in KINDS:
            s = self.seconds[kind]
            if not s and not self.lost[kind]:
                continue
            out[kind] = {
                "n": len(s), "lost": self.lost[kind],
                "p50_ms": _ms(percentile(s, 50)), "p95_ms": _ms(percentile(s, 95)),
                "p99_ms": _ms(percentile(s, 99)), "max_ms": _ms(max(s, default=None)),
            }  # fmt: skip
        return out


def _delete(name: str) -> object:
    return DeleteRequest(name=name)


def _ms(s: float | None) -> float | None:
    return None if s is None else round(s * 1e3, 1)


def _clock(fleet: Fleet, timeout: float) -> tuple[float, Any]:
    c = fleet.clock(timeout)
    return time.monotonic(), c


def run(n: int, args: argparse.Namespace, tmp: Path, progress: Progress) -> dict[str, Any]:
    label = f"[N={n}]"
    out: dict[str, Any] = {"robots": n, "status": "ok"}
    arena = make_arena(n, args.seed)
    world = tmp / f"arena_{n}.yaml"
    write_world(arena, world)
    with contextlib.ExitStack() as stack:
        try:
            daemon: DaemonProc = start_daemon(world, 1.0, n + 1, tmp, ["--paused", "--cmd-timeout", "0"])
            stack.callback(daemon.stop)
            progress.update(f"{label} starting", force=True)
            fleet = Fleet(daemon.endpoint)
            stack.callback(fleet.close)
            fleet.wait_for_daemon(60.0)
            names = [f"r{i}" for i in range(n)]
            reqs = [spawn_request(nm, *pose) for nm, pose in zip(names, arena.poses, strict=True)]
            results, spawn_s = fleet.spawn_batch(reqs, 64, max(60.0, 0.05 * n),
                                                 lambda d, t: progress.update(f"{label} spawn {d}/{t}"))  # fmt: skip
            spawned = sum(ok for _, ok, _ in results)
            out["spawned"], out["spawn_s"] = spawned, round(spawn_s, 1)
            if spawned != n:
                why = collections.Counter(err for _, ok, err in results if not ok).most_common(2)
                raise RuntimeError(f"spawned {spawned} of {n} (the refusals: {why})")
            sub = Subscriber(daemon.endpoint, "r0", tmp / f"subscriber-{n}.log", "fleet")
            stack.callback(sub.stop)
            sub.wait_ready(60.0)
            watched = [0]
            for i in range(WATCHED):
                for topic in ("odom", "scan"):
                    fleet.session.declare_subscriber(f"{PREFIX}/r{i}/{topic}",
                                                     lambda s: watched.__setitem__(0, watched[0] + 1))  # fmt: skip
            driver = DriverProc(daemon.endpoint, n, args.seed, tmp / f"driver-{n}.log", args.driver)
            stack.callback(driver.stop)
            driver.wait_ready(120.0)
            pen = arena.extra
            paused = Probe(fleet, args.timeout, n)
            sleeper = Sleeper()
            stack.callback(sleeper.stop)
            t_end, k = time.monotonic() + args.paused_s, 0
            while time.monotonic() < t_end:
                progress.update(f"{label} paused, driver attached: round {k}")
                paused.cycle(pen, False, k)
                k += 1
            out["paused"] = paused.summary()
            out["machine"] = {"paused": sleeper.stop()}
            fleet.query(f"{PREFIX}/sim/resume", None, 30.0)
            time.sleep(1.0)
            # A driver's commands reach the robots only once zenoh has matched its publishers
            # (with one per robot, a publisher put before that is dropped at the driver): the
            # running phase is about a driven fleet, so it waits for one, and says if it came not.
            t_wait = time.monotonic()
            while (moving := fleet.moving(30.0)) < DRIVEN * n and time.monotonic() - t_wait < args.wait_driven:
                progress.update(f"{label} waiting for the fleet to be driven: {moving}/{n} moving")
                time.sleep(1.0)
            out["moving_at_start"], out["driven_after_s"] = moving, round(time.monotonic() - t_wait, 1)
            w0, c0 = _clock(fleet, 30.0)  # the factor over the settling, where nothing pauses it
            t_settle = time.monotonic()
            while time.monotonic() - t_settle < args.settle:
                progress.update(f"{label} settle {time.monotonic() - t_settle:4.1f}/{args.settle:g} s")
                time.sleep(0.2)
            w1, c1 = _clock(fleet, 30.0)
            out["rtf"] = round((c1.tick - c0.tick) / TICK_HZ / (w1 - w0), 3)
            out["clock_says"] = {
                "real_time_factor": round(c1.real_time_factor, 3), "falling_behind": c1.falling_behind,
                "tick_ms": round(c1.tick_s * 1e3, 1), "capacity_robots": c1.capacity_robots,
            }  # fmt: skip
            running = Probe(fleet, args.timeout, n)
            sleeper = Sleeper()
            stack.callback(sleeper.stop)
            t_end = time.monotonic() + args.running_s
            while time.monotonic() < t_end:
                progress.update(f"{label} running: round {k}")
                running.cycle(pen, True, k)
                k += 1
                time.sleep(args.gap)
            out["running"] = running.summary()
            out["machine"]["running"] = sleeper.stop()
            out["moving_at_end"] = fleet.moving(30.0)
            out["unexpected"] = paused.unexpected + running.unexpected
            out["watched_messages"] = watched[0]
            out["driver"] = driver.stop()
            if not daemon.alive():
                raise RuntimeError(f"simd died: {daemon.log_tail()}")
        except Exception as e:  # the run's record says what went wrong; the next size goes on
            out["status"] = f"failed: {type(e).__name__}: {e}"
    progress.done(f"{label} {_line(out)}")
    return out


def _line(r: dict[str, Any]) -> str:
    if r["status"] != "ok":
        return str(r["status"])
    worst = max((v["p99_ms"] or 0.0 for ph in ("paused", "running") for v in r[ph].values()), default=0.0)
    lost = sum(v["lost"] for ph in ("paused", "running") for v in r[ph].values())
    moving = f"{r['moving_at_start']}/{r['robots']} moving"
    return f"RTF {r['rtf']:.2f}; {moving}; worst p99 {worst:.0f} ms; {lost} lost"


def table(runs: list[dict[str, Any]]) -> str:
    """The markdown table of every run: a row per size, phase and request kind."""
    lines = ["| robots | phase | request | n | p50 ms | p95 ms | p99 ms | max ms | lost |",
             "|---:|---|---|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    for r in runs:
        if r["status"] != "ok":
            lines.append(f"| {r['robots']} | – | {r['status']} | | | | | | |")
            continue
        for phase in ("paused", "running"):
            for kind, v in r[phase].items():
                cells = [v[f] if v[f] is not None else "–" for f in ("p50_ms", "p95_ms", "p99_ms", "max_ms")]
                lines.append(f"| {r['robots']} | {phase} | {kind} | {v['n']} | " + " | ".join(map(str, cells))
                             + f" | {v['lost']} |")  # fmt: skip
    lines.append("")
    lines.append("| robots | phase | the machine: a process that only naps woke late by, p50 ms | p99 ms | max ms |")
    lines.append("|---:|---|---:|---:|---:|")
    for r in runs:
        for phase, m in r.get("machine", {}).items():
            if m.get("n"):
                lines.append(f"| {r['robots']} | {phase} | {m['p50_ms']} | {m['p99_ms']} | {m['max_ms']} |")
    lines.append("")
    lines.append(
        "| robots | RTF achieved | robots moving: at the start / the end of running (waited s) | the clock says |"
    )
    lines.append("|---:|---:|---|---|")
    for r in runs:
        if r["status"] == "ok":
            c = r["clock_says"]
            said = f"RTF {c['real_time_factor']:.2f}, falling behind {c['falling_behind']}, tick {c['tick_ms']} ms"
            moving = f"{r['moving_at_start']} / {r['moving_at_end']} ({r['driven_after_s']:g})"
            lines.append(f"| {r['robots']} | {r['rtf']:.2f} | {moving} | {said}, capacity {c['capacity_robots']} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.overload", description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[8000, 10000, 20000], help="fleet sizes")
    p.add_argument("--paused-s", type=float, default=10.0, help="seconds of requests while paused (default 10)")
    p.add_argument("--running-s", type=float, default=30.0, help="seconds of requests while running (default 30)")
    p.add_argument("--settle", type=float, default=10.0, help="seconds running first (default 10)")
    p.add_argument("--gap", type=float, default=0.1, help="seconds between two rounds (default 0.1)")
    p.add_argument("--timeout", type=float, default=10.0, help="a request unanswered this long is lost")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument(
        "--wait-driven",
        type=float,
        default=60.0,
        help=f"seconds to wait, once running, for {DRIVEN:.0%}% of the fleet to move (default 60)",
    )
    p.add_argument("--driver", default="batched", choices=("batched", "robots"),
                   help="how the driver sends: every command of a cycle in one message on P/commands "
                        "(default: what a program driving thousands of robots does), or through a "
                        "publisher per robot, whose commands zenoh drops until it has matched them "
                        "(at 20 000 robots, for longer than the benchmark waits)")  # fmt: skip
    p.add_argument("--out", default="bench-out", help="directory for overload.json (default: %(default)s)")
    p.add_argument("--role", default="bench", choices=("bench", "driver"), help=argparse.SUPPRESS)
    p.add_argument("--endpoint", help=argparse.SUPPRESS)
    p.add_argument("--robots", type=int, default=0, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.role == "driver":
        return driver_main(args.endpoint, args.robots, args.seed, args.driver == "batched")
    if any(n < 1 for n in args.sizes):
        p.error("--sizes must be at least 1")
    signal.signal(signal.SIGTERM, raise_exit)
    info = machine_info()
    print(f"machine: {machine_line(info)}")
    progress = Progress()
    runs = []
    with tempfile.TemporaryDirectory(prefix="overload_") as tmp:
        for n in args.sizes:
            runs.append(run(n, args, Path(tmp), progress))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    record = {"machine": info, "bound_ms": BOUND_S * 1e3, "driver": args.driver, "runs": runs}
    (out / "overload.json").write_text(json.dumps(record, indent=1))
    print(f"driver: {DRIVERS[args.driver]}")
    print(table(runs))
    worst = [v["p99_ms"] or 0.0 for r in runs if r["status"] == "ok" for ph in ("paused", "running")
             for v in r[ph].values()]  # fmt: skip
    lost = sum(v["lost"] for r in runs if r["status"] == "ok" for ph in ("paused", "running") for v in r[ph].values())
    met = all(r["status"] == "ok" for r in runs) and not lost and max(worst, default=0.0) <= BOUND_S * 1e3
    idle = [r for r in runs if r["status"] == "ok" and r["moving_at_start"] < DRIVEN * r["robots"]]
    for r in idle:
        print(f"\nN={r['robots']}: the driver's commands had reached only {r['moving_at_start']} of the robots "
              f"after {r['driven_after_s']:g} s: the running phase measured a fleet mostly standing still")  # fmt: skip
    met = met and not idle
    print(f"\nevery request answered within {BOUND_S * 1e3:.0f} ms p99: {'yes' if met else 'no'}")
    print(f"wrote {out / 'overload.json'}")
    return 0 if met else 1


if __name__ == "__main__":
    sys.exit(main())
