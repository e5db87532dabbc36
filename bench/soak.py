"""Soak: a driven fleet under everything a day throws at it, for sim minutes; does anything
leak, get lost or go unanswered?

    python -m bench.soak                                   # 1 000 robots, 10 sim minutes
    python -m bench.soak --robots 200 --duration 60        # a shorter look

One ``simd`` (real time, the benchmark's arena) and, each a process of its own
(bench/soak_workers.py): ``--drivers`` drivers (each its share of the robots, cmd_vel at 10 Hz
through declared publishers, as fleet controllers do); ``--subscribers`` subscribers counting
every odometry row and scan of the fleet topics (bench/subscriber.py); a churn of spawns and
deletes (``--churn-rate`` a second, robots coming and going in a closed pen); hostile traffic
at ``--fuzz-rate`` a second (random bytes, deeply nested documents, huge arrays, invalid UTF-8,
as queries to every key and as puts on real and ghost robots' cmd_vel). After a third of the
run the fleet is paused for ``--pause`` wall seconds and resumed; after two thirds it is reset.
The run lasts ``--duration`` seconds of **sim** time (time paused, and the time a reset takes
back, do not count), however slowly the machine runs it.

Every ``--every`` seconds it records the daemon's resident memory, threads and open file
descriptors, the real-time factor, the robots still listed and, for each subscriber, the share
of odometry rows and scans delivered. At the end it judges:

- **replies**: every request of the soak (its clock and list queries, pause, resume, reset),
  of the churn and every hostile query got an answer or a structured refusal: none lost;
- **robots**: every robot of the fleet listed in every sample, and at the end the list is the
  fleet plus exactly the churned robots the churn believes alive; the daemon alive;
- **pause and reset**: the clock stood still while paused and ran again after the resume;
  the reset took the clock back to 0 and kept every robot;
- **memory**: RSS drift, the last sample against the first one after the warm-up
  (``--warmup``, default a fifth of the run, at least a minute: the allocator and zenoh's
  buffers grow for about that long), within 5 %;
- **threads and file descriptors**: none more at the end than after the warm-up;
- delivery and RTF over the run (median and worst interval), reported, not judged (a shared
  machine's slow spell is not a leak).

Writes the record as JSON (``--out``) and a PNG beside it; exit code 0 when every judgement holds.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench.arena import PROBE, make_arena, write_world
from bench.measure import proc_status_kb
from bench.numbers import median
from bench.processes import PREEXEC, ROOT, DaemonProc, start_daemon, stop_process
from bench.report import machine_info, machine_line
from bench.soak_workers import REPLY_TIMEOUT_S, Tally
from bench.subscriber import Subscriber
from bench.wire import PREFIX

#: the RSS drift allowed after the warm-up
RSS_FLAT = 0.05


@dataclass
class Settings:
    robots: int = 1000
    duration: float = 600.0  # sim seconds
    drivers: int = 10
    subscribers: int = 5
    churn_rate: float = 2.0
    fuzz_rate: float = 20.0
    every: float = 10.0
    pause: float = 5.0  # wall seconds
    warmup: float | None = None  # wall seconds; None: max(60, duration / 5)

    @property
    def warmup_s(self) -> float:
        return self.warmup if self.warmup is not None else max(60.0, self.duration / 5)

    @property
    def max_wall_s(self) -> float:
        """A run that cannot reach its sim duration in this long stops and says so."""
        return 5 * self.duration + self.pause + 120


def _worker(role: str, *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "bench.soak_workers", role, *args], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, cwd=ROOT, preexec_fn=PREEXEC)  # fmt: skip


def _finish(worker: subprocess.Popen[str]) -> dict[str, Any]:
    """Tell a worker to stop (close its stdin) and read its record."""
    assert worker.stdin is not None and worker.stdout is not None
    worker.stdin.close()
    line = worker.stdout.readline()
    stop_process(worker, 30.0)
    return json.loads(line) if line.strip() else {}


def _fds(pid: int) -> int | None:
    try:
        return len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return None


class Soak:
    """One soak run: the processes, the samples, the events (see the module docstring)."""

    def __init__(self, s: Settings, tmp: Path) -> None:
        self.s = s
        self.tmp = tmp
        self.arena = make_arena(s.robots)
        self.names = [f"r{i}" for i in range(s.robots)]
        self.odom_keys = [f"{PREFIX}/{n}/odom" for n in self.names]
        self.scan_keys = [f"{PREFIX}/{n}/scan" for n in self.names]
        self.tally = Tally()  # the soak's own requests
        self.samples: list[dict[str, Any]] = []
        self.events: list[dict[str, Any]] = []
        self.t0 = 0.0
        self.daemon: DaemonProc | None = None
        self.subs: list[Subscriber] = []
        self.workers: list[subprocess.Popen[str]] = []

    # -- what the soak measures -----------------------------------------------------------

    def _baseline(self) -> tuple[float, int, list[dict[str, Any]]] | None:
        clock = self.tally.ask(self.client.clock)
        if clock is None:
            return None
        return time.monotonic(), clock.tick, [sub.snapshot() for sub in self.subs]

    def _delivered(self, before: dict[str, Any], after: dict[str, Any], topic: str, keys: list[str]) -> int:
        b, a = before[topic], after[topic]
        return sum(a.get(k, 0) - b.get(k, 0) for k in keys)

    def _sample(self, base: tuple[float, int, list[dict[str, Any]]], progress: float) -> dict[str, Any] | None:
        """One sample against ``base``; None when the clock query was lost (counted)."""
        assert self.daemon is not None
        clock = self.tally.ask(self.client.clock)
        snaps = [sub.snapshot() for sub in self.subs]
        listed = self.tally.ask(self.client.robots)
        now = time.monotonic()
        if clock is None:
            return None
        ticks = clock.tick - base[1]
        dt = clock.dt
        expected_odom, expected_scans = self.s.robots * ticks, self.s.robots * ticks / 6  # a scan every 6th tick
        pairs = list(zip(base[2], snaps, strict=True))  # each subscriber's counts before and after
        odom = [self._delivered(b, a, "odom", self.odom_keys) / max(1, expected_odom) for b, a in pairs]
        scans = [self._delivered(b, a, "scan", self.scan_keys) / max(1, expected_scans) for b, a in pairs]
        names = {r.name for r in listed} if listed is not None else None
        return {
            "t": round(now - self.t0, 1), "sim_s": round(progress + ticks * dt, 2),
            "rss_mb": (proc_status_kb(self.daemon.pid, "VmRSS") or 0) / 1024,
            "threads": proc_status_kb(self.daemon.pid, "Threads"), "fds": _fds(self.daemon.pid),
            "tick": clock.tick, "ticks": ticks, "rtf": ticks * dt / (now - base[0]),
            "rtf_daemon": clock.real_time_factor, "behind_s": clock.behind_s, "falling_behind": clock.falling_behind,
            "listed": len(names) if names is not None else None,
            "missing": sum(n not in names for n in self.names) if names is not None else None,
            "odom_delivered": min(odom, default=0.0), "scans_delivered": min(scans, default=0.0),
            "load1": os.getloadavg()[0],  # the machine's (other work on a shared machine shows here)
        }  # fmt: skip

    # -- the events ---------------------------------------------------------------------------

    def _pause(self) -> None:
        """Pause for ``--pause`` wall seconds (a pause is wall time by nature), then resume, and
        see the clock stand still between and run again after."""
        t = round(time.monotonic() - self.t0, 1)
        paused = self.tally.ask(self.client.pause)
        time.sleep(self.s.pause)
        during = self.tally.ask(self.client.clock)
        resumed = self.tally.ask(self.client.resume)
        ran = False
        deadline = time.monotonic() + 30
        while during is not None and not ran and time.monotonic() < deadline:
            c = self.tally.ask(self.client.clock)
            ran = c is not None and c.tick > during.tick and not c.paused
            time.sleep(0.1)
        self.events.append({
            "event": "pause", "t": t, "paused_s": self.s.pause,
            "stood_still": paused is not None and during is not None and during.paused and during.tick == paused.tick,
            "resumed": resumed is not None and ran,
        })  # fmt: skip

    def _reset(self) -> None:
        t = round(time.monotonic() - self.t0, 1)
        before = self.tally.ask(self.client.clock)
        after = self.tally.ask(self.client.reset)
        listed = self.tally.ask(self.client.robots)
        names = {r.name for r in listed} if listed is not None else set()
        self.events.append({
            "event": "reset", "t": t, "tick_before": before.tick if before else None,
            "tick_after": after.tick if after else None,
            "to_zero": after is not None and after.tick == 0,
            "kept_robots": all(n in names for n in self.names),
        })  # fmt: skip

    # -- the run --------------------------------------------------------------------------

    def start(self) -> None:
        from clients.api import FleetClient
        from protocol.control import SpawnRequest

        s, world = self.s, self.tmp / "arena.yaml"
        write_world(self.arena, world)
        self.daemon = start_daemon(world, 1.0, s.robots + 16, self.tmp)
        endpoint = self.daemon.endpoint
        self.subs = [Subscriber(endpoint, PROBE, self.tmp / f"subscriber-{i}.log", "fleet")
                     for i in range(s.subscribers)]  # fmt: skip
        deadline = time.monotonic() + 30
        while True:
            try:
                self.client = FleetClient(endpoint, prefix=PREFIX, timeout=REPLY_TIMEOUT_S)
                self.client.clock()
                break
            except Exception:
                if time.monotonic() > deadline or not self.daemon.alive():
                    raise RuntimeError(f"simd did not start:\n{self.daemon.log_tail()}") from None
                time.sleep(0.2)
        for sub in self.subs:
            sub.wait_ready(30)
        self.client.spawn_many(SpawnRequest(name=n, x=x, y=y, yaw=yaw)
                               for n, (x, y, yaw) in zip(self.names, self.arena.poses, strict=True))  # fmt: skip
        share = -(-s.robots // s.drivers)
        for k in range(s.drivers):
            part = self.names[k * share : (k + 1) * share]
            if part:
                self.workers.append(_worker("drive", "--endpoint", endpoint, "--names", ",".join(part),
                                            "--seed", str(k)))  # fmt: skip
        self.churner = _worker("churn", "--endpoint", endpoint, "--rate", f"{s.churn_rate:g}",
                               "--pen", "{:g},{:g}".format(*self.arena.extra))  # fmt: skip
        self.fuzzer = _worker("fuzz", "--endpoint", endpoint, "--rate", f"{s.fuzz_rate:g}")
        self.workers += [self.churner, self.fuzzer]

    def run(self) -> dict[str, Any]:
        s = self.s
        assert self.daemon is not None
        self.t0 = time.monotonic()
        progress = 0.0
        base = self._baseline()
        paused = reset = False
        while progress < s.duration and time.monotonic() - self.t0 < s.max_wall_s:
            if base is None:
                base = self._baseline()
                continue
            time.sleep(max(0.0, s.every - (time.monotonic() - base[0])))
            if not self.daemon.alive():
                raise RuntimeError(f"simd died:\n{self.daemon.log_tail()}")
            sample = self._sample(base, progress)
            if sample is None:
                base = None
                continue
            self.samples.append(sample)
            progress = sample["sim_s"]
            print(f"soak {sample['t']:6.0f} s, sim {progress:6.0f} s: RSS {sample['rss_mb']:6.1f} MB, threads "
                  f"{sample['threads']}, fds {sample['fds']}, RTF {sample['rtf']:.3f}, listed {sample['listed']}, "
                  f"delivered odom {sample['odom_delivered']:.3f} scans {sample['scans_delivered']:.3f}",
                  file=sys.stderr, flush=True)  # fmt: skip
            if not paused and progress >= s.duration / 3:
                paused = True
                self._pause()
            elif not reset and progress >= 2 * s.duration / 3:
                reset = True
                self._reset()
            base = self._baseline()
        return self.finish(progress)

    def finish(self, progress: float) -> dict[str, Any]:
        s = self.s
        assert self.daemon is not None
        churn, fuzz = _finish(self.churner), _finish(self.fuzzer)
        listed = self.tally.ask(self.client.robots)
        expected = set(self.names) | set(churn.get("alive", []))
        final_exact = listed is not None and {r.name for r in listed} == expected
        self.client.close()
        settled = [x for x in self.samples if x["t"] >= s.warmup_s] or self.samples
        lost = self.tally.lost + churn.get("lost", 0) + fuzz.get("no_reply", 0)

        def growth(field: str) -> int | None:
            values = [x[field] for x in settled if x[field] is not None]
            return values[-1] - values[0] if values else None

        result: dict[str, Any] = {
            "settings": vars(s) | {"warmup_s": s.warmup_s}, "sim_s": progress,
            "wall_s": round(time.monotonic() - self.t0, 1), "completed": progress >= s.duration,
            "alive": self.daemon.alive(), "samples": self.samples, "events": self.events,
            "requests": {"soak": self.tally.record(), "churn": churn, "fuzz": fuzz}, "lost_replies": lost,
            "missing_robots_max": max((x["missing"] or 0 for x in self.samples), default=0),
            "final_list_exact": final_exact,
            "rss_drift": settled[-1]["rss_mb"] / settled[0]["rss_mb"] - 1.0 if settled else None,
            "rss_settled_mb": (settled[0]["rss_mb"], settled[-1]["rss_mb"]) if settled else None,
            "threads_growth": growth("threads"), "fds_growth": growth("fds"),
            "threads": (settled[0]["threads"], settled[-1]["threads"]) if settled else None,
            "fds": (settled[0]["fds"], settled[-1]["fds"]) if settled else None,
            "rtf_median": median([x["rtf"] for x in self.samples]),
            "rtf_min": min((x["rtf"] for x in self.samples), default=None),
            "odom_delivered_median": median([x["odom_delivered"] for x in self.samples]),
            "odom_delivered_min": min((x["odom_delivered"] for x in self.samples), default=None),
            "scans_delivered_min": min((x["scans_delivered"] for x in self.samples), default=None),
        }  # fmt: skip
        result["verdict"] = judge(result)
        return result

    def stop(self) -> None:
        for w in self.workers:
            if w.stdin is not None and not w.stdin.closed:
                w.stdin.close()
            stop_process(w, 5.0)
        for sub in self.subs:
            sub.stop()
        if self.daemon is not None:
            self.daemon.stop()


def judge(r: dict[str, Any]) -> dict[str, bool]:
    """Each of the soak's promises, held or not."""
    events = {e["event"]: e for e in r["events"]}
    pause, reset = events.get("pause", {}), events.get("reset", {})
    return {
        "completed": r["completed"],
        "alive": r["alive"],
        "no_lost_reply": r["lost_replies"] == 0,
        "hostile_refused": r["requests"]["fuzz"].get("accepted_hostile") == 0,
        "no_lost_robot": r["missing_robots_max"] == 0 and r["final_list_exact"],
        "churned": r["requests"]["churn"].get("answered", 0) > 0,
        "paused_and_resumed": bool(pause.get("stood_still") and pause.get("resumed")),
        "reset": bool(reset.get("to_zero") and reset.get("kept_robots")),
        "rss_flat": r["rss_drift"] is not None and abs(r["rss_drift"]) <= RSS_FLAT,
        "threads_flat": r["threads_growth"] is not None and r["threads_growth"] <= 0,
        "fds_flat": r["fds_growth"] is not None and r["fds_growth"] <= 0,
    }


def soak(s: Settings, tmp: Path) -> dict[str, Any]:
    run = Soak(s, tmp)
    try:
        run.start()
        return run.run()
    finally:
        run.stop()


def plot(result: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    samples = result["samples"]
    t = [x["t"] / 60 for x in samples]
    s = result["settings"]
    fig, (a, b, c) = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    a.plot(t, [x["rss_mb"] for x in samples])
    a.axvline(s["warmup_s"] / 60, color="grey", linestyle=":", label="end of warm-up")
    a.set_ylabel("simd RSS (MB)")
    a.legend(loc="lower right")
    a.set_title(f"soak: {s['robots']} robots, {s['drivers']} drivers, {s['subscribers']} subscribers, churn "
                f"{s['churn_rate']:g}/s, hostile {s['fuzz_rate']:g}/s")  # fmt: skip
    b.plot(t, [x["threads"] for x in samples], label="threads")
    b.plot(t, [x["fds"] for x in samples], label="open files")
    b.set_ylabel("simd")
    b.legend(loc="center right")
    c.plot(t, [x["rtf"] for x in samples], label="RTF")
    c.plot(t, [x["odom_delivered"] for x in samples], label="odometry delivered (worst subscriber)")
    c.plot(t, [x["scans_delivered"] for x in samples], label="scans delivered (worst subscriber)")
    low = min([0.9] + [x[k] - 0.02 for x in samples for k in ("rtf", "odom_delivered", "scans_delivered")])
    c.set_ylim(max(0.0, low), 1.05)
    c.set_xlabel("wall minutes")
    for e in result["events"]:
        for ax in (a, b, c):
            ax.axvline(e["t"] / 60, color="red", linestyle="--", linewidth=0.8)
        c.text(e["t"] / 60, 0.97, f" {e['event']}", transform=c.get_xaxis_transform(), rotation=90, va="top",
               fontsize=8, color="red")  # fmt: skip
    c.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def summary(r: dict[str, Any]) -> str:
    req, v = r["requests"], r["verdict"]
    failed = [k for k, ok in v.items() if not ok]
    return (
        f"soak: {r['settings']['robots']} robots, {r['sim_s']:.0f} sim s in {r['wall_s']:.0f} wall s: daemon "
        f"{'alive' if r['alive'] else 'DEAD'}; requests: soak {req['soak']['sent']}, churn {req['churn'].get('sent')} "
        f"({req['churn'].get('answered')} answered, {req['churn'].get('refused')} refused), hostile "
        f"{req['fuzz'].get('sent')} ({req['fuzz'].get('accepted_hostile')} hostile spawns, deletes, steps accepted); "
        f"lost replies {r['lost_replies']}; robots missing at worst {r['missing_robots_max']}, final list "
        f"{'exact' if r['final_list_exact'] else 'WRONG'}; RSS drift {(r['rss_drift'] or 0) * 100:+.1f} % "
        f"after warm-up; threads {r['threads']}, fds {r['fds']}; RTF median {r['rtf_median']:.3f} (min "
        f"{r['rtf_min']:.3f}); odometry delivered median {r['odom_delivered_median']:.3f} (min "
        f"{r['odom_delivered_min']:.3f}), scans min {r['scans_delivered_min']:.3f}; "
        + ("every promise held" if not failed else "NOT held: " + ", ".join(failed))
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    d = Settings()
    ap.add_argument("--robots", type=int, default=d.robots)
    ap.add_argument("--duration", type=float, default=d.duration, help="sim seconds (default 600)")
    ap.add_argument("--drivers", type=int, default=d.drivers, help="driver processes (default 10)")
    ap.add_argument("--subscribers", type=int, default=d.subscribers, help="fleet-topic subscribers (default 5)")
    ap.add_argument("--churn-rate", type=float, default=d.churn_rate, help="spawns and deletes a second (default 2)")
    ap.add_argument("--fuzz-rate", type=float, default=d.fuzz_rate, help="hostile messages a second (default 20)")
    ap.add_argument("--every", type=float, default=d.every, help="wall seconds between samples (default 10)")
    ap.add_argument("--pause", type=float, default=d.pause, help="wall seconds paused at a third (default 5)")
    ap.add_argument("--warmup", type=float, default=None,
                    help="wall seconds before RSS, threads, fds are judged (default: a fifth, >= 60)")  # fmt: skip
    ap.add_argument("--out", default="bench-out/soak.json", help="the JSON (and a PNG beside it)")
    args = ap.parse_args(argv)
    s = Settings(args.robots, args.duration, args.drivers, args.subscribers, args.churn_rate, args.fuzz_rate,
                 args.every, args.pause, args.warmup)  # fmt: skip
    if min(s.robots, s.drivers, s.subscribers) < 1 or min(s.duration, s.churn_rate, s.fuzz_rate, s.every) <= 0:
        ap.error("--robots, --drivers, --subscribers, --duration, --churn-rate, --fuzz-rate and --every must be "
                 "positive")  # fmt: skip
    if s.pause < 0 or (s.warmup is not None and s.warmup < 0):
        ap.error("--pause and --warmup must not be negative")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    machine = machine_info()
    print(f"machine: {machine_line(machine)}", flush=True)
    with tempfile.TemporaryDirectory(prefix="soak-") as tmp:
        result = soak(s, Path(tmp))
    result["machine"] = machine
    result["command"] = shlex.join(["python", "-m", "bench.soak", *(sys.argv[1:] if argv is None else argv)])
    out.write_text(json.dumps(result, indent=1) + "\n")
    plot(result, out.with_suffix(".png"))
    print(summary(result) + f"; wrote {out} and {out.with_suffix('.png')}", flush=True)
    return 0 if all(result["verdict"].values()) else 1


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
