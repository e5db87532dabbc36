"""How large a fleet runs in real time with 1, 2 or 3 daemons sharing it through a router, and
what the daemons' seeing each other (ghosts) costs.

    python -m bench.scale_bench                                  # 1 2 3 daemons x 2 000 4 000 6 000 robots
    python -m bench.scale_bench --daemons 1 2 --sizes 4000 --duration 10
    python -m bench.scale_bench --ghost-cost-only                # the in-process ghost cost alone

Each run, all real processes on loopback: ``fleet-router``; K daemons ``simd -m client -e
ROUTER --join --id dI`` on the benchmark's arena for N robots (robots 2 m apart among pillars,
each seeing several others: bench/arena.py); one subscriber process on the fleet topics
(``P/odometry``, ``P/scans``) through the router, counting every robot's rows; the N robots
spawned through the router (each placed on a daemon by its name) and driven by the wander
driver (``--drive-hz``, 2 by default: the daemons keep the last command). After ``--settle``
seconds, and once every daemon answers its clock within 0.5 s again (``settled_s`` in the
record), a window of ``--duration`` seconds: each daemon's RTF from its own clock
(``P/daemons/<id>/clock``) at both ends, the odometry rows and scans delivered against what the
daemons simulated, and the CPU of every process (/proc).

"Real time" is the issue's: RTF >= 0.98 on every daemon and >= 99 % of odometry and scans
delivered. The ghosts' cost is measured apart, in one process (``ghost_cost``): ticks of a
world of N own robots with and without G ghosts moving every tick, and the size of the
``DaemonTick`` a daemon puts each tick (what every other daemon receives).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.arena import PROBE, make_arena, write_world
from bench.client import Fleet, spawn_request
from bench.driver import Driver
from bench.measure import proc_cpu_seconds
from bench.processes import free_port, terminate
from bench.progress import Progress
from bench.report import DRIVEN, machine_info, machine_line
from bench.subscriber import Subscriber
from bench.wire import PREFIX, SCAN_EVERY, TICK_HZ

ROOT = Path(__file__).resolve().parent.parent
TARGET_RTF, TARGET_DELIVERED, TARGET_ROBOTS = 0.98, 0.99, 6000  # issue "scale-out"


def _start(cmd: list[str], log: Path) -> subprocess.Popen[str]:
    with log.open("w") as f:
        return subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, text=True, cwd=ROOT)


def _daemon_clock(fleet: Fleet, daemon_id: str) -> tuple[float, int]:
    """(monotonic time of the answer, the daemon's tick)."""
    from protocol.codec import decode
    from protocol.control import Clock

    ok, payload, _ = fleet.query(f"{PREFIX}/daemons/{daemon_id}/clock", None, 10.0)
    if not ok:
        raise RuntimeError(f"daemon {daemon_id} did not answer its clock: {payload}")
    return time.monotonic(), decode(payload, Clock).tick


def _steady_clocks(fleet: Fleet, ids: list[str], within: float = 0.5, wait: float = 60.0) -> dict[str, Any]:
    """Every daemon's clock, once they all answer within ``within`` s again. The driver's first
    round declares a publisher for each robot, and through a router the daemons answer late for
    a few seconds after (6 s at 6 000 robots on 3 daemons): the window starts after that."""
    deadline = time.monotonic() + wait
    while True:
        asked = time.monotonic()
        try:
            clocks = {d: _daemon_clock(fleet, d) for d in ids}
        except RuntimeError:
            if time.monotonic() > deadline:
                raise
            continue
        if max(t for t, _ in clocks.values()) - asked < within * len(ids) or time.monotonic() > deadline:
            return clocks
        time.sleep(0.5)


def run(k: int, n: int, args: argparse.Namespace, tmp: Path, progress: Progress) -> dict[str, Any]:
    label = f"[{k} daemon{'s' if k > 1 else ''}, {n} robots]"
    arena = make_arena(n, args.seed)
    world = tmp / f"arena_{n}.yaml"
    write_world(arena, world)
    router_ep = f"tcp/127.0.0.1:{free_port()}"
    procs: dict[str, subprocess.Popen[str]] = {}
    out: dict[str, Any] = {"daemons": k, "robots": n, "status": "ok"}
    with contextlib.ExitStack() as stack:
        try:
            logs = tmp / f"{k}x{n}"  # each run's logs apart, for a failed run to be read after
            logs.mkdir(exist_ok=True)
            procs["router"] = _start([sys.executable, "-m", "simd.router", "-l", router_ep], logs / "router.log")
            stack.callback(terminate, procs["router"], 10.0)
            ids = [f"d{i}" for i in range(k)]
            for d in ids:
                cmd = [sys.executable, "-m", "simd.cli", "-m", "client", "-e", router_ep, "--join", "--id", d,
                       "--world", str(world), "--max-robots", str(n + 100), "--seed", "1", "--log-level", "warning",
                       "--cmd-timeout", "0"]  # fmt: skip
                procs[d] = _start(cmd, logs / f"simd-{d}.log")
                stack.callback(terminate, procs[d], 10.0)
            progress.update(f"{label} starting", force=True)
            fleet = Fleet(router_ep)
            stack.callback(fleet.close)
            deadline = time.monotonic() + 60
            while True:
                try:
                    for d in ids:
                        _daemon_clock(fleet, d)
                    break
                except RuntimeError:
                    if time.monotonic() > deadline or any(p.poll() is not None for p in procs.values()):
                        raise
                    time.sleep(0.3)
            sub = Subscriber(router_ep, PROBE, logs / "subscriber.log", "fleet")
            stack.callback(sub.stop)
            sub.wait_ready(60.0)
            names = [f"r{i}" for i in range(n)]
            reqs = [spawn_request(nm, *pose) for nm, pose in zip(names, arena.poses, strict=True)]
            results, spawn_s = fleet.spawn_batch(
                reqs, 16, max(60.0, 0.2 * n), lambda d, t: progress.update(f"{label} spawn {d}/{t}")
            )
            spawned = [nm for nm, (_, ok, _) in zip(names, results, strict=True) if ok]
            out["spawned"], out["spawn_s"] = len(spawned), spawn_s
            per_daemon: dict[str, int] = {}
            for listed in fleet.robot_lists(30.0, every_daemon=True):
                for r in listed.robots:
                    per_daemon[r.daemon] = per_daemon.get(r.daemon, 0) + 1
            out["robots_per_daemon"] = per_daemon
            driver = Driver(fleet, spawned, args.seed, rate_hz=args.drive_hz)
            driver.start()
            stack.callback(driver.stop)
            t_settle = time.monotonic()
            while time.monotonic() - t_settle < args.settle:
                progress.update(f"{label} settle {time.monotonic() - t_settle:4.1f}/{args.settle:g} s")
                time.sleep(0.2)
            c0 = _steady_clocks(fleet, ids)
            out["settled_s"] = time.monotonic() - t_settle
            s0 = sub.snapshot()
            t0 = time.monotonic()
            cpu0 = {p: proc_cpu_seconds(proc.pid) for p, proc in procs.items()}
            cpu0["subscriber"] = proc_cpu_seconds(sub.pid)
            while (el := time.monotonic() - t0) < args.duration:
                if any(p.poll() is not None for p in procs.values()):
                    raise RuntimeError("a process died during the window")
                progress.update(f"{label} measure {el:4.1f}/{args.duration:g} s")
                time.sleep(0.2)
            s1 = sub.snapshot()
            cpu1 = {p: proc_cpu_seconds(proc.pid) for p, proc in procs.items()}  # before the clocks: a loaded
            cpu1["subscriber"] = proc_cpu_seconds(sub.pid)  # daemon may take seconds to answer them
            t1 = time.monotonic()
            c1 = {d: _daemon_clock(fleet, d) for d in ids}
            out["moving"] = fleet.moving(30.0, every_daemon=True)  # the driver's commands reached them
            wall = s1["t"] - s0["t"]
            rtf = {d: (c1[d][1] - c0[d][1]) / TICK_HZ / (c1[d][0] - c0[d][0]) for d in ids}
            # what the daemons simulated in the subscriber's window: each daemon's robots at its own RTF
            expected_odom = sum(per_daemon.get(d, 0) * rtf[d] * TICK_HZ * wall for d in ids)
            got_odom = sum(s1["odom"].values()) - sum(s0["odom"].values())
            got_scan = sum(s1["scan"].values()) - sum(s0["scan"].values())
            cpu: dict[str, float] = {}
            for name, before in cpu0.items():
                after = cpu1.get(name)
                if before is not None and after is not None:
                    cpu[name] = 100 * (after - before) / (t1 - t0)
            out.update(
                rtf=rtf,
                rtf_min=min(rtf.values()),
                odom_fraction=got_odom / expected_odom if expected_odom else None,
                scan_fraction=got_scan / (expected_odom / SCAN_EVERY) if expected_odom else None,
                cpu_pct=cpu,
                wall_s=wall,
            )
            out["real_time"] = bool(
                out["moving"] >= DRIVEN * len(spawned)
                and out["rtf_min"] >= TARGET_RTF
                and (out["odom_fraction"] or 0) >= TARGET_DELIVERED
                and (out["scan_fraction"] or 0) >= TARGET_DELIVERED
            )
        except Exception as e:  # the run's record says what went wrong; the next run goes on
            out["status"] = f"failed: {type(e).__name__}: {e}"
    progress.done(f"{label} {_line(out)}")
    return out


def _line(r: dict[str, Any]) -> str:
    if r["status"] != "ok":
        return str(r["status"])
    cpu = ", ".join(f"{p} {v:.0f}%" for p, v in r["cpu_pct"].items())
    return (
        f"RTF {r['rtf_min']:.2f} (slowest daemon), odometry {r['odom_fraction']:.3f}, scans {r['scan_fraction']:.3f} "
        f"delivered; {r['moving']}/{r['spawned']} moving; real time: {'yes' if r['real_time'] else 'no'}; CPU: {cpu}"
    )


def ghost_cost(own: int, ghosts: int, layout: str = "interleaved", ticks: int = 150) -> dict[str, Any]:
    """Ticks of ``own`` robots alone and beside ``ghosts`` ghosts that move every tick, in this
    process, interleaved; and the ``DaemonTick`` a daemon of ``ghosts`` robots puts a tick.
    ``layout`` "interleaved": the arena of own + ghosts robots, every other robot a ghost (as
    placement by name spreads a fleet over daemons); "beside": each ghost 0.4 m beside one of
    the robots (every ghost near one: the worst case, all of them bodies)."""
    import msgspec

    from protocol.control import DaemonTick, SpawnRequest
    from simd.core.ghosts import GhostColumns
    from simd.core.sim import SimConfig, Simulation
    from simd.core.worldfile import world_from_dict

    arena = make_arena(own + ghosts, 1)
    everyone = np.array(arena.poses)
    if layout == "interleaved":
        poses, g = everyone[0::2][:own], everyone[1::2][:ghosts]
    else:
        poses = everyone[:own]
        g = poses[:ghosts] + np.array([0.0, 0.4, 0.0])
    sims = {}
    for label, with_ghosts in (("alone", False), ("with ghosts", True)):
        sim = Simulation(world_from_dict(arena.world), SimConfig(seed=1, cmd_timeout=0))
        for i in range(own):
            sim.spawn(SpawnRequest(name=f"r{i}", x=float(poses[i, 0]), y=float(poses[i, 1]), yaw=float(poses[i, 2])))
        rng = np.random.default_rng(1)
        sim.command_rows(np.arange(own), rng.uniform(0.05, 0.22, own), rng.uniform(-1, 1, own))
        sims[label] = (sim, with_ghosts)
    names = [f"g{i}" for i in range(ghosts)]
    bodies = 0
    per_tick: dict[str, list[float]] = {k: [] for k in sims}
    for k in range(ticks):
        for label, (sim, with_ghosts) in sims.items():
            t = time.perf_counter()
            if with_ghosts:  # the ghosts creep forward 5 mm a tick: new poses every tick, as from a daemon
                step = 0.005 * (k + 1)
                cols = GhostColumns(names, ["burger"] * ghosts, g[:, 0] + step * np.cos(g[:, 2]),
                                    g[:, 1] + step * np.sin(g[:, 2]), g[:, 2].copy())  # fmt: skip
                sim.set_ghosts(cols)
            sim.step()
            per_tick[label].append(time.perf_counter() - t)
            if with_ghosts:
                bodies = max(bodies, sim._ghosts.bodies)
    for sim, _ in sims.values():
        sim.close()
    tick = DaemonTick(daemon="d1", tick=123456, namespaces=[f"r{i}" for i in range(ghosts)], models=["burger"] * ghosts,
                      poses=np.zeros((ghosts, 3)).tobytes())  # fmt: skip
    med = {label: statistics.median(v[20:]) * 1e3 for label, v in per_tick.items()}
    return {
        "own": own,
        "ghosts": ghosts,
        "layout": layout,
        "ghost_bodies": bodies,
        "tick_ms_alone": med["alone"],
        "tick_ms_with_ghosts": med["with ghosts"],
        "ghost_ms_per_tick": med["with ghosts"] - med["alone"],
        "daemon_tick_bytes": len(msgspec.msgpack.encode(tick)),
        "daemon_tick_mb_per_s": len(msgspec.msgpack.encode(tick)) * TICK_HZ / 1e6,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.scale_bench", description=__doc__.split("\n\n")[0])
    p.add_argument("--daemons", type=int, nargs="+", default=[1, 2, 3], help="daemon counts (default: 1 2 3)")
    p.add_argument("--sizes", type=int, nargs="+", default=[2000, 4000, 6000], help="fleet sizes")
    p.add_argument("--duration", type=float, default=10.0, help="seconds measured per run (default 10)")
    p.add_argument("--settle", type=float, default=5.0, help="seconds of driving before (default 5)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument(
        "--drive-hz",
        type=float,
        default=2.0,
        help="commands a second to every robot (default 2: the daemons hold the last one, --cmd-timeout 0, so "
        "thousands of robots keep moving without the driver's puts dominating the load)",
    )
    p.add_argument("--ghost-cost-only", action="store_true", help="only the in-process ghost cost")
    p.add_argument(
        "--ghost-robots",
        type=int,
        nargs="+",
        default=[1000, 3000],
        help="robots (and as many ghosts) of the ghost cost, interleaved; the largest also beside (default: 1000 3000)",
    )
    p.add_argument("--out", default="bench-out", help="directory for scale.json (default: %(default)s)")
    args = p.parse_args(argv)
    if any(k < 1 for k in [*args.daemons, *args.sizes, *args.ghost_robots]):
        p.error("--daemons, --sizes and --ghost-robots must be at least 1")
    info = machine_info()
    print(f"machine: {machine_line(info)}")
    progress = Progress()
    costs = []
    cases = [(g, g, "interleaved") for g in args.ghost_robots] + [(max(args.ghost_robots),) * 2 + ("beside",)]
    for own, ghosts, layout in cases:
        progress.update(f"ghost cost: {own} robots, {ghosts} ghosts {layout}", force=True)
        costs.append(ghost_cost(own, ghosts, layout))
        c = costs[-1]
        progress.done(f"ghost cost: {own} robots and {ghosts} ghosts {layout} ({c['ghost_bodies']} of them bodies): "
                      f"tick {c['tick_ms_alone']:.2f} ms alone, {c['tick_ms_with_ghosts']:.2f} ms with them "
                      f"(+{c['ghost_ms_per_tick']:.2f} ms); a daemon of {ghosts} robots puts "
                      f"{c['daemon_tick_bytes'] / 1e3:.0f} kB a tick ({c['daemon_tick_mb_per_s']:.1f} MB/s to every "
                      "other daemon)")  # fmt: skip
    runs = []
    if not args.ghost_cost_only:
        with tempfile.TemporaryDirectory(prefix="scale_bench_") as tmp:
            for n in args.sizes:
                for k in args.daemons:
                    runs.append(run(k, n, args, Path(tmp), progress))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "scale.json").write_text(json.dumps({"machine": info, "ghost_cost": costs, "runs": runs}, indent=1))
    if runs:
        print("\n| daemons | robots | RTF (slowest daemon) | odometry / scans delivered | moving | real time | CPU % |")
        print("|---:|---:|---:|---|---:|---|---|")
        for r in runs:
            if r["status"] != "ok":
                print(f"| {r['daemons']} | {r['robots']} | – | – | – | {r['status']} | – |")
                continue
            cpu = ", ".join(f"{p} {v:.0f}" for p, v in r["cpu_pct"].items())
            real = "yes" if r["real_time"] else "no"
            print(f"| {r['daemons']} | {r['robots']} | {r['rtf_min']:.2f} | {r['odom_fraction']:.3f} / "
                  f"{r['scan_fraction']:.3f} | {r['moving']} | {real} | {cpu} |")  # fmt: skip
        best = max((r["robots"] for r in runs if r.get("real_time")), default=0)
        verdict = "met" if best >= TARGET_ROBOTS else "not met"
        print(f"\nlargest fleet in real time: {best} robots; target {TARGET_ROBOTS}: {verdict}")
    print(f"wrote {out / 'scale.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
