"""The measurements of one fleet size: spawn, real-time factor and delivery, CPU, latencies.

Each phase takes the run's ``Context`` (the daemon, the subscriber and the benchmark's session)
and returns the record that goes into ``results.json``. The CPU and memory figures are read
from /proc, so that they cover the daemon's every thread without instrumenting it.
"""

from __future__ import annotations

import itertools
import os
import random
import time
from dataclasses import dataclass, field
from typing import Any

from bench.arena import PROBE, Arena
from bench.client import Fleet, spawn_request
from bench.numbers import fmt_f, fmt_ms, fmt_pct, fmt_rate, median, percentile
from bench.processes import DaemonProc
from bench.progress import Progress
from bench.subscriber import Subscriber
from bench.wire import BEAMS, MSGPACK, PREFIX, SCAN_EVERY, TICK_HZ

_CLK_TCK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def proc_cpu_seconds(pid: int) -> float | None:
    """utime + stime of a process, all its threads included (/proc/<pid>/stat)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / _CLK_TCK  # fields 14 and 15 of stat(5)
    except (OSError, IndexError, ValueError):
        return None


def cpu_ticks() -> tuple[int, int] | None:
    """(steal, total) jiffies of all CPUs since boot (/proc/stat): on a virtual machine the
    hypervisor gives some of our CPU time to other guests, and that shows only here."""
    try:
        with open("/proc/stat") as f:
            values = [int(v) for v in f.readline().split()[1:]]
        return (values[7] if len(values) > 7 else 0), sum(values[:8])
    except (OSError, ValueError):
        return None


def proc_status_kb(pid: int, key: str) -> int | None:
    """A ``kB`` line of /proc/<pid>/status, e.g. VmRSS or VmHWM."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        pass
    return None


def thread_schedstat(pid: int, tid: int | None = None) -> tuple[float, float] | None:
    """(seconds on a CPU, seconds runnable but waiting for a CPU) of one thread
    (/proc/<pid>/task/<tid>/schedstat). The wait is what other load on the machine costs it."""
    try:
        with open(f"/proc/{pid}/task/{tid or pid}/schedstat") as f:
            run_ns, wait_ns = f.read().split()[:2]
        return int(run_ns) / 1e9, int(wait_ns) / 1e9
    except (OSError, ValueError):
        return None


@dataclass
class Settings:
    """The command line's choices that every fleet size is measured with."""

    duration: float
    settle: float
    spawn_concurrency: int
    latency_reps: int
    extra_spawns: int
    seed: int
    simd_args: list[str] = field(default_factory=list)


@dataclass
class Context:
    """What the phases of one run share; ``names`` are the robots that were actually spawned."""

    n: int
    label: str
    daemon: DaemonProc
    sub: Subscriber
    fleet: Fleet
    names: list[str] = field(default_factory=list)


def spawn_fleet(ctx: Context, arena: Arena, s: Settings, progress: Progress) -> dict[str, Any]:
    names = [f"r{i}" for i in range(ctx.n)]
    reqs = [spawn_request(nm, *pose) for nm, pose in zip(names, arena.poses, strict=True)]

    def on_progress(done: int, total: int) -> None:
        progress.update(f"{ctx.label} spawn {done}/{total}")

    results, total = ctx.fleet.spawn_batch(reqs, s.spawn_concurrency, max(30.0, 0.2 * ctx.n), on_progress)
    ok_lat = [lat for lat, ok, _ in results if ok]
    ctx.names = [nm for nm, (_, ok, _) in zip(names, results, strict=True) if ok]
    errors = [err for _, ok, err in results if not ok]
    out = {
        "requested": ctx.n,
        "spawned": len(ctx.names),
        "refused": len(errors),
        "first_error": errors[0] if errors else None,
        "concurrency": s.spawn_concurrency,
        "total_s": total,
        "per_second": len(ok_lat) / total if total > 0 else None,
        "p50_s": percentile(ok_lat, 50),
        "p99_s": percentile(ok_lat, 99),
        "max_s": max(ok_lat, default=None),
    }
    progress.done(
        f"{ctx.label} spawned {len(ctx.names)}/{ctx.n} in {total:.2f} s "
        f"(p50 {fmt_ms(out['p50_s'])} ms, p99 {fmt_ms(out['p99_s'])} ms, {s.spawn_concurrency} in flight)"
    )
    return out


def settle(ctx: Context, seconds: float, progress: Progress) -> None:
    t0 = time.monotonic()
    while (el := time.monotonic() - t0) < seconds:
        _check_alive(ctx)
        o, sc = ctx.sub.rates()
        progress.update(
            f"{ctx.label} settle {el:4.1f}/{seconds:g} s  rtf {_clock_rtf(ctx):.2f}  "
            f"odom {fmt_rate(o)}/s  scan {fmt_rate(sc)}/s"
        )
        time.sleep(0.2)


def _check_alive(ctx: Context) -> None:
    if not ctx.daemon.alive():
        raise RuntimeError(f"simd exited with {ctx.daemon.proc.returncode}")
    if ctx.sub.proc.poll() is not None:
        raise RuntimeError(f"the subscriber exited with {ctx.sub.proc.returncode}")


def _clock_rtf(ctx: Context) -> float:
    c = ctx.fleet.clock_samples
    return c[-1][2] if c else 0.0


def _per_second_rtf(samples: list[tuple[float, int, float]], t0: float, t1: float) -> list[float]:
    """Sim seconds per wall second over consecutive 1 s windows, from the clock messages."""
    pts = [(t, tick) for t, tick, _ in samples if t0 <= t <= t1]
    out = []
    i = 0
    for j in range(1, len(pts)):
        if pts[j][0] - pts[i][0] >= 1.0:
            out.append((pts[j][1] - pts[i][1]) / TICK_HZ / (pts[j][0] - pts[i][0]))
            i = j
    return out


def _tick_at(samples: list[tuple[float, int, float]], t: float) -> float | None:
    """The daemon's tick at monotonic time ``t``, interpolated between clock messages."""
    before = next((x for x in reversed(samples) if x[0] <= t), None)
    after = next((x for x in samples if x[0] >= t), None)
    if before is None or after is None:
        return None
    if after[0] <= before[0]:
        return float(before[1])
    return before[1] + (after[1] - before[1]) * (t - before[0]) / (after[0] - before[0])


def _deciles(per_robot: list[int], expected_each: float) -> list[float]:
    """Delivered fraction of each tenth of the fleet, in spawn order (fewer groups if N < 10)."""
    if not per_robot or expected_each <= 0:
        return []
    k = min(10, len(per_robot))
    bounds = [round(i * len(per_robot) / k) for i in range(k + 1)]
    return [round(sum(per_robot[a:b]) / ((b - a) * expected_each), 4) for a, b in itertools.pairwise(bounds)]


def measure_window(ctx: Context, duration: float, progress: Progress) -> dict[str, Any]:
    """The window runs from one subscriber snapshot to the next; the daemon's tick at both
    instants comes from its clock messages, so expected and delivered cover the same time."""
    fleet, sub, daemon = ctx.fleet, ctx.sub, ctx.daemon
    q0 = time.perf_counter()
    fleet.clock()
    clock_query_s = time.perf_counter() - q0
    s0 = sub.snapshot()
    t0 = s0["t"]
    cpu0, scpu0, me0 = proc_cpu_seconds(daemon.pid), proc_cpu_seconds(sub.pid), time.process_time()
    ss0 = thread_schedstat(daemon.pid)  # the daemon's main thread runs the simulation loop
    st0 = cpu_ticks()
    while (el := time.monotonic() - t0) < duration:
        _check_alive(ctx)
        o, sc = sub.rates()
        progress.update(
            f"{ctx.label} measure {el:4.1f}/{duration:g} s  rtf {_clock_rtf(ctx):.2f}  "
            f"odom {fmt_rate(o)}/s  scan {fmt_rate(sc)}/s"
        )
        time.sleep(min(0.2, max(0.0, duration - el)))
    s1 = sub.snapshot()
    t1 = s1["t"]
    cpu1, scpu1, me1 = proc_cpu_seconds(daemon.pid), proc_cpu_seconds(sub.pid), time.process_time()
    ss1 = thread_schedstat(daemon.pid)
    st1 = cpu_ticks()
    deadline = time.monotonic() + 3.0
    while time.monotonic() < deadline and not (fleet.clock_samples and fleet.clock_samples[-1][0] >= t1):
        time.sleep(0.02)
    samples = list(fleet.clock_samples)
    k0, k1 = _tick_at(samples, t0), _tick_at(samples, t1)
    if k0 is None or k1 is None:
        raise RuntimeError("no clock messages from simd around the measurement window")
    wall = t1 - t0
    ticks = k1 - k0
    n = len(ctx.names)

    def deltas(topic: str) -> list[int]:
        a, b = s0[topic], s1[topic]
        return [b.get(f"{PREFIX}/{nm}/{topic}", 0) - a.get(f"{PREFIX}/{nm}/{topic}", 0) for nm in ctx.names]

    odom_d, scan_d = deltas("odom"), deltas("scan")
    exp_odom = n * ticks
    exp_scan = n * ticks / SCAN_EVERY
    rtf_s = _per_second_rtf(fleet.clock_samples, t0, t1)
    out = {
        "wall_s": wall,
        "ticks": ticks,
        "sim_s": ticks / TICK_HZ,
        "snapshot_s": [t0, t1],
        "rtf": ticks / TICK_HZ / wall if wall > 0 else None,
        "rtf_median": median(rtf_s) if rtf_s else (ticks / TICK_HZ / wall if wall > 0 else None),
        "rtf_min": min(rtf_s, default=None),
        "rtf_max": max(rtf_s, default=None),
        "rtf_per_second": rtf_s,
        "robots": n,
        "odom_delivered": sum(odom_d),
        "odom_expected": exp_odom,
        "odom_per_s": sum(odom_d) / wall,
        "odom_expected_per_s": exp_odom / wall,
        "odom_fraction": sum(odom_d) / exp_odom if exp_odom else None,
        "scan_delivered": sum(scan_d),
        "scan_expected": exp_scan,
        "scan_per_s": sum(scan_d) / wall,
        "scan_expected_per_s": exp_scan / wall,
        "scan_fraction": sum(scan_d) / exp_scan if exp_scan else None,
        "beams_per_s": BEAMS * sum(scan_d) / wall,
        "beams_simulated_per_s": BEAMS * exp_scan / wall,
        "worst_robot_odom_fraction": min(odom_d) / ticks if ticks and odom_d else None,
        "clock_query_ms": clock_query_s * 1000,
        "worst_robot_scan_fraction": min(scan_d) / (ticks / SCAN_EVERY) if ticks and scan_d else None,
        "robots_silent": sum(1 for d in odom_d if d == 0),
        # by spawn order, which is the daemon's publish order within a tick: losses at the tail of
        # each tick's burst show up as falling fractions here
        "odom_fraction_by_decile": _deciles(odom_d, ticks),
        "scan_fraction_by_decile": _deciles(scan_d, ticks / SCAN_EVERY),
        "bad_payloads": s1["bad"] - s0["bad"],
        # /tf (the ROS subscriber): one message a tick with every robot's transform
        "tf_messages": s1["tf"][0] - s0["tf"][0],
        "tf_fraction": (s1["tf"][0] - s0["tf"][0]) / ticks if ticks and s1["tf"][0] else None,
        "tf_transforms_per_message": (
            (s1["tf"][1] - s0["tf"][1]) / (s1["tf"][0] - s0["tf"][0]) if s1["tf"][0] > s0["tf"][0] else None
        ),
        "daemon_cpu_pct": 100 * (cpu1 - cpu0) / wall if cpu0 is not None and cpu1 is not None else None,
        "subscriber_cpu_pct": 100 * (scpu1 - scpu0) / wall if scpu0 is not None and scpu1 is not None else None,
        "bench_cpu_pct": 100 * (me1 - me0) / wall,
        "sim_thread_cpu_pct": 100 * (ss1[0] - ss0[0]) / wall if ss0 and ss1 else None,
        "sim_thread_wait_pct": 100 * (ss1[1] - ss0[1]) / wall if ss0 and ss1 else None,
        "loadavg_1min": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
        # share of all CPUs' time the hypervisor gave to other guests during the window
        "steal_pct": 100 * (st1[0] - st0[0]) / (st1[1] - st0[1]) if st0 and st1 and st1[1] > st0[1] else None,
    }
    progress.done(
        f"{ctx.label} measured {wall:.1f} s: rtf {fmt_f(out['rtf'])} (median {fmt_f(out['rtf_median'])}), "
        f"odom {fmt_rate(out['odom_per_s'])}/{fmt_rate(out['odom_expected_per_s'])} /s, "
        f"scan {fmt_rate(out['scan_per_s'])}/{fmt_rate(out['scan_expected_per_s'])} /s, "
        f"daemon cpu {fmt_pct(out['daemon_cpu_pct'])}, subscriber {fmt_pct(out['subscriber_cpu_pct'])}, "
        f"bench {fmt_pct(out['bench_cpu_pct'])}; sim thread on a CPU {fmt_pct(out['sim_thread_cpu_pct'])}, "
        f"waiting for one {fmt_pct(out['sim_thread_wait_pct'])}"
    )
    return out


def measure_latency(ctx: Context, reps: int, progress: Progress) -> dict[str, Any]:
    """cmd_vel put (this process) → first probe odometry with a non-zero twist (subscriber)."""
    from protocol.codec import encode
    from protocol.messages import Twist, Vector3

    pub = ctx.fleet.session.declare_publisher(f"{PREFIX}/{PROBE}/cmd_vel", encoding=MSGPACK)
    turn = encode(Twist(angular=Vector3(z=1.0)))  # turn in place: the probe stays in its pen
    stop = encode(Twist())
    rng = random.Random(7)
    lat: list[float] = []
    misses = 0
    # A miss is either a lost command or a stalled daemon (a shared machine's slow spell can
    # hold it for seconds): the probe's odometry count over the wait tells which.
    probe_key = f"{PREFIX}/{PROBE}/odom"
    miss_probe_odom: list[int] = []
    st0 = cpu_ticks()
    try:
        for r in range(reps):
            _check_alive(ctx)
            if ctx.sub.moving():
                pub.put(stop)
                ctx.sub.wait_twist(False, time.monotonic(), 3.0)
            before = ctx.sub.snapshot()["odom"].get(probe_key, 0)
            time.sleep(rng.uniform(0.1, 0.3))  # land anywhere in the tick period
            t0 = time.monotonic()
            pub.put(turn)
            t1 = ctx.sub.wait_twist(True, t0, 3.0)
            if t1 is None:
                misses += 1
                miss_probe_odom.append(ctx.sub.snapshot()["odom"].get(probe_key, 0) - before)
            else:
                lat.append(t1 - t0)
            pub.put(stop)
            ctx.sub.wait_twist(False, time.monotonic(), 3.0)
            progress.update(f"{ctx.label} cmd_vel→odom {r + 1}/{reps}  last {fmt_ms(lat[-1] if lat else None)} ms")
    finally:
        pub.undeclare()
    st1 = cpu_ticks()
    out = {
        "reps": reps,
        "misses": misses,
        # probe odometry received from the sleep before each missed put to the end of its 3 s
        # wait: ~100 if the daemon ran (the command was lost), far fewer if it stalled
        "miss_probe_odom": miss_probe_odom,
        "steal_pct": 100 * (st1[0] - st0[0]) / (st1[1] - st0[1]) if st0 and st1 and st1[1] > st0[1] else None,
        "p50_s": median(lat),
        "p95_s": percentile(lat, 95),
        "max_s": max(lat, default=None),
        "samples_s": lat,
    }
    progress.done(
        f"{ctx.label} cmd_vel→odom p50 {fmt_ms(out['p50_s'])} ms, p95 {fmt_ms(out['p95_s'])} ms, "
        f"max {fmt_ms(out['max_s'])} ms ({len(lat)}/{reps})"
    )
    return out


def spawn_single(ctx: Context, arena: Arena, reps: int, progress: Progress) -> dict[str, Any]:
    """Spawn and delete one robot at a time while the fleet runs."""
    from protocol.control import DeleteRequest

    spawn_lat: list[float] = []
    delete_lat: list[float] = []
    errors: list[str] = []
    rng = random.Random(11)
    for i in range(reps):
        _check_alive(ctx)
        name = f"extra{i}"
        time.sleep(rng.uniform(0.0, 0.04))
        ok, err, dt = ctx.fleet.query(f"{PREFIX}/spawn", spawn_request(name, *arena.extra, 0.0), 10.0)
        if not ok:
            errors.append(str(err))
            continue
        spawn_lat.append(dt)
        ok, err, dt = ctx.fleet.query(f"{PREFIX}/delete", DeleteRequest(name=name), 10.0)
        if ok:
            delete_lat.append(dt)
        else:
            errors.append(str(err))
        progress.update(f"{ctx.label} spawn/delete one at a time {i + 1}/{reps}")
    out = {
        "reps": reps,
        "live_robots": len(ctx.names) + 1,
        "spawn_p50_s": percentile(spawn_lat, 50),
        "spawn_p99_s": percentile(spawn_lat, 99),
        "spawn_max_s": max(spawn_lat, default=None),
        "delete_p50_s": percentile(delete_lat, 50),
        "delete_p99_s": percentile(delete_lat, 99),
        "errors": len(errors),
        "first_error": errors[0] if errors else None,
    }
    progress.done(
        f"{ctx.label} one-at-a-time spawn p50 {fmt_ms(out['spawn_p50_s'])} ms, "
        f"p99 {fmt_ms(out['spawn_p99_s'])} ms; delete p50 {fmt_ms(out['delete_p50_s'])} ms"
    )
    return out
