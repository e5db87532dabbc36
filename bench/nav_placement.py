"""Where the navigator should run: inside the daemon, or as a process of its own beside it.

    python -m bench.nav_placement                       # 100 and 1 000 burgers: A and B 60 sim s, C 30
    python -m bench.nav_placement --sizes 100 --seconds 30 --out placement.json

Issue "nav" asks to measure both placements before choosing. The navigator inside the daemon
exists (simd/nav/navigator.py, run by the engine's tick on the simulation thread); a second,
outside navigator is not built to be measured: what it would cost *at least* is measured instead,
the I/O that any navigator in another process must do, with nothing else in it.

For each fleet size, in the generated warehouse (``worlds.warehouse``, as ``bench.nav_bench``),
with the same robots spawned at the same places:

- **A, in the daemon**: ``simd`` in real time with navigation on, every robot with a goal at all
  times (a new random goal as soon as one ends, as nav_bench does). Measured: the daemon's CPU
  seconds per sim second, the navigator's own work per sim second (``P/navigation``'s
  ``work_seconds``, wall time on the simulation thread) and the real-time factor.
- **B, outside, at least**: ``simd --no-nav`` in real time and a separate client process (this
  module with ``--client``) that does an outside navigator's I/O and nothing more: it follows the
  fleet's odometry (``P/odometry``, every robot every tick) and scans (``P/scans``: an outside
  navigator needs the lidar for what the map does not show), and at the navigator's control rate
  (every 3 ticks, ``NavConfig.control_every``) puts every robot's ``P/<ns>/cmd_vel``, on one
  declared publisher per robot (``FleetClient.drive``, as teleop). The protocol has no packed
  multi-robot command key in real time (``commands`` exists only in a ``P/sim/step`` request,
  i.e. lockstep), so per-robot Twist puts are the cheapest correct path. The commands alternate
  each robot between (+0.05 m/s, +0.5 rad/s) and (-0.05 m/s, -0.5 rad/s) every 30 ticks,
  staggered over the fleet: small, varying, and the robot stays about where it is. Measured: the
  daemon's and the client's CPU per sim second, the RTF, the share of ticks whose odometry the
  client got and of the scans it should have got, the control steps it missed, the commands a
  second, and the command latency in ticks: from the tick of the odometry a command was computed
  from to the first tick whose odometry shows the robot's turn rate moving toward it (1 is the
  least possible, and what the in-daemon navigator gets by construction: it computes before tick
  t from the poses of tick t-1, and tick t applies it).
- **C, the daemon alone**: ``simd --no-nav --cmd-timeout 0`` in real time, every robot sent
  (+0.05 m/s, +0.5 rad/s) once and holding it: the robots move, nobody listens, nobody commands.

What navigating costs the daemon is A - C, in CPU (``work_seconds`` is wall time on the
simulation thread: on a loaded machine it also counts the time that thread waited for a CPU, so
it is shown but not used). What the I/O of an outside navigator costs is B - C in the daemon plus
B's client. An outside navigator would run the same planning and control code, so
B total = B daemon + B client + (A - C) is a lower bound of what the separate process design
costs, to compare with A. Each run measures a window of ``--seconds`` sim seconds (C:
``--baseline-seconds``) after ``--settle`` sim seconds (the first goals' planning burst), cut
short after ``--max-wall`` wall seconds (the RTF reached says how far it got). The machine's load
is printed with each run: the daemon, the client and this process share its cores.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import select
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bench.measure import proc_cpu_seconds, thread_schedstat
from bench.nav_bench import TOLERANCE_M, _connect, _spread, warehouse_goals
from bench.processes import PREEXEC, ROOT, DaemonProc, start_daemon, stop_process
from bench.report import machine_info, machine_line
from bench.wire import PREFIX

TICK_HZ = 30
CONTROL_EVERY = 3  # ticks: NavConfig.control_every (10 Hz)
SCAN_HZ = 5
#: the client's commands: each robot alternates between (+V, +W) and (-V, -W) every SWITCH ticks
V, W, SWITCH = 0.05, 0.5, 30
#: a change of turn rate (rad/s) from one odometry to the next that shows a new command applied
#: (a wheel may change by 1/30 m/s a tick: a burger's turn rate by ~0.4 rad/s)
SEEN_W = 0.05
PROGRESS_S = 10.0


def _tick(stamp: Any) -> int:
    return round(float(stamp.sec + stamp.nanosec * 1e-9) * TICK_HZ)


def _sim_now(client: Any) -> float:
    c = client.clock()
    return float(c.clock.sec + c.clock.nanosec * 1e-9)


def _loadavg() -> list[float]:
    return [round(v, 2) for v in os.getloadavg()]


@dataclass
class Window:
    """CPU and time of one measured window of a run."""

    daemon_pid: int
    extra_pid: int | None = None
    sim0: float = 0.0
    wall0: float = 0.0
    cpu0: float = 0.0
    extra0: float = 0.0
    wait0: float = 0.0
    run0: float = 0.0

    def start(self, sim: float) -> None:
        self.sim0, self.wall0 = sim, time.monotonic()
        self.cpu0 = proc_cpu_seconds(self.daemon_pid) or 0.0
        self.extra0 = (proc_cpu_seconds(self.extra_pid) or 0.0) if self.extra_pid else 0.0
        self.run0, self.wait0 = thread_schedstat(self.daemon_pid) or (0.0, 0.0)

    def end(self, sim: float) -> dict[str, Any]:
        wall = time.monotonic() - self.wall0
        simd = sim - self.sim0
        cpu = (proc_cpu_seconds(self.daemon_pid) or 0.0) - self.cpu0
        extra = ((proc_cpu_seconds(self.extra_pid) or 0.0) - self.extra0) if self.extra_pid else None
        run, wait = thread_schedstat(self.daemon_pid) or (0.0, 0.0)
        run, wait = run - self.run0, wait - self.wait0

        def per(v: float | None) -> float | None:
            return round(v / simd, 4) if v is not None and simd > 0 else None

        return {
            "sim_s": round(simd, 2),
            "wall_s": round(wall, 2),
            "rtf": round(simd / wall, 3) if wall > 0 else None,
            "daemon_cpu_per_sim_s": per(cpu),
            "client_cpu_per_sim_s": per(extra),
            "sim_thread_cpu_per_sim_s": per(run),
            "sim_thread_wait_per_sim_s": per(wait),
            "load_at_end": _loadavg(),
        }

    def progress(self, label: str, sim: float, horizon: float) -> str:
        wall = time.monotonic() - self.wall0
        cpu = (proc_cpu_seconds(self.daemon_pid) or 0.0) - self.cpu0
        simd = sim - self.sim0
        rtf = simd / wall if wall > 0 else 0.0
        per = cpu / simd if simd > 0 else 0.0
        return (
            f"  {label}: sim {simd:5.1f}/{horizon:g} s, RTF {rtf:.2f}, daemon CPU {per:.3f} s/sim s, "
            f"load {_loadavg()[0]}"
        )


def _setup(size: int, seed: int, tmp: Path, extra: list[str]) -> tuple[DaemonProc, Any, list[str], Any, Any]:
    """A daemon on the size's warehouse, its robots spawned apart: (daemon, client, names, goals,
    where each robot stands)."""
    from protocol.control import SpawnRequest
    from worlds.warehouse import warehouse_for_robots

    rng = np.random.default_rng(seed)
    path = tmp / f"warehouse-{size}.map"
    if not path.exists():
        path.write_text(warehouse_for_robots(size))
    goals = warehouse_goals(path.read_text(), 0.5)
    daemon = start_daemon(path, 1.0, max(size, 10), tmp, ["--cell-size", "0.5", *extra])
    try:
        client = _connect(daemon)
        names = [f"r{k}" for k in range(size)]
        spots = _spread(goals, size, rng)
        t0 = time.monotonic()
        client.spawn_many([SpawnRequest(name=n, x=float(px), y=float(py), yaw=float(rng.uniform(-np.pi, np.pi)))
                           for n, (px, py) in zip(names, spots, strict=True)])  # fmt: skip
        print(f"  spawned {size} in {time.monotonic() - t0:.1f} s", flush=True)
    except BaseException:
        daemon.stop()
        raise
    return daemon, client, names, goals, spots


def _run_window(label: str, client: Any, win: Window, seconds: float, max_wall: float, alive: Any,
                each: Any = None) -> float:  # fmt: skip
    """Wait until ``seconds`` of sim time passed since ``win.sim0`` (or ``max_wall``); the sim
    time reached. ``each(sim_now)`` runs every ~0.2 s wall."""
    sim = win.sim0
    next_print = time.monotonic() + PROGRESS_S
    while sim - win.sim0 < seconds and time.monotonic() - win.wall0 < max_wall and alive():
        time.sleep(0.2)
        sim = _sim_now(client)
        if each is not None:
            each(sim)
        if time.monotonic() >= next_print:
            next_print += PROGRESS_S
            print(win.progress(label, sim, seconds), flush=True)
    if sim - win.sim0 < seconds:
        print(f"  {label}: stopped after {max_wall:g} s of wall time, {sim - win.sim0:.1f} sim s", flush=True)
    return sim


def _settle(label: str, client: Any, settle: float, alive: Any, each: Any = None) -> float:
    """Let ``settle`` sim seconds pass (at most 3 x that in wall time, and 60 s)."""
    t0, w0 = _sim_now(client), time.monotonic()
    sim = t0
    while sim - t0 < settle and time.monotonic() - w0 < min(3 * settle, 60.0) and alive():
        time.sleep(0.2)
        sim = _sim_now(client)
        if each is not None:
            each(sim)
    print(f"  {label}: settled {sim - t0:.1f} sim s in {time.monotonic() - w0:.1f} s", flush=True)
    return sim


# -- A: the navigator in the daemon -----------------------------------------------------------------


def run_in_daemon(size: int, seconds: float, settle: float, max_wall: float, seed: int, tmp: Path) -> dict[str, Any]:
    from protocol.codec import decode
    from protocol.navigation import NavigateRequest, NavigationResult

    label = f"A {size}"
    load0 = _loadavg()
    daemon, client, names, goals, spots = _setup(size, seed, tmp, [])
    rng = np.random.default_rng(seed + 1)
    try:
        where = {n: (float(x), float(y)) for n, (x, y) in zip(names, spots, strict=True)}
        done: deque[NavigationResult] = deque()
        nav: list[tuple[float, float]] = []  # (stamp, work_seconds) of P/navigation
        counts = {"reached": 0, "failed": 0}

        def on_result(sample: Any) -> None:
            try:
                done.append(decode(sample.payload.to_bytes(), NavigationResult))
            except Exception:
                pass

        def on_nav(msg: Any) -> None:
            nav.append((msg.stamp.sec + msg.stamp.nanosec * 1e-9, msg.work_seconds))

        client.session.declare_subscriber(client.keys.navigate_result("*"), on_result)
        client.on_navigation(on_nav)

        def new_goal(name: str) -> tuple[str, NavigateRequest]:
            x0, y0 = where[name]
            while True:
                gx, gy = goals.points[rng.integers(len(goals.points))]
                if math.hypot(gx - x0, gy - y0) >= 1.0:
                    return name, NavigateRequest(x=float(gx), y=float(gy), tolerance=TOLERANCE_M)

        def more_goals(sim: float) -> None:
            batch = []
            while done:
                r = done.popleft()
                if r.reason == "preempted" or r.robot not in where:
                    continue
                where[r.robot] = (r.pose.x, r.pose.y)
                counts["reached" if r.status == "reached" else "failed"] += 1
                batch.append(new_goal(r.robot))
            if batch:
                client.send_goals(batch)

        client.send_goals([new_goal(n) for n in names])
        _settle(label, client, settle, daemon.alive, more_goals)
        win = Window(daemon.pid)
        win.start(_sim_now(client))
        nav_start = nav[-1] if nav else (win.sim0, 0.0)
        reached0 = dict(counts)
        sim = _run_window(label, client, win, seconds, max_wall, daemon.alive, more_goals)
        out = win.end(sim)
        time.sleep(0.6)  # the next P/navigation (2 Hz of sim time)
        nav_end = nav[-1] if nav else nav_start
        dt = nav_end[0] - nav_start[0]
        out["nav_work_per_sim_s"] = round((nav_end[1] - nav_start[1]) / dt, 4) if dt > 0 else None
        out["goals_reached"] = counts["reached"] - reached0["reached"]
        out["goals_failed"] = counts["failed"] - reached0["failed"]
        out["goals_reached_per_sim_min"] = round(out["goals_reached"] / out["sim_s"] * 60, 1) if out["sim_s"] else None
        out["load_at_start"] = load0
        out["daemon_alive"] = daemon.alive()
        return out
    finally:
        client.close()
        daemon.stop()


# -- C: the daemon alone, robots moving, no navigation and no I/O --------------------------------------


def run_baseline(size: int, seconds: float, settle: float, max_wall: float, seed: int, tmp: Path) -> dict[str, Any]:
    """``simd --no-nav --cmd-timeout 0``, every robot sent (V, W) once and holding it: what the
    daemon costs with its robots moving and nobody listening or commanding."""
    label = f"C {size}"
    load0 = _loadavg()
    daemon, client, names, _, _ = _setup(size, seed, tmp, ["--no-nav", "--cmd-timeout", "0"])
    try:
        for ns in names:
            client.drive(ns, V, W)
        _settle(label, client, settle, daemon.alive)
        win = Window(daemon.pid)
        win.start(_sim_now(client))
        sim = _run_window(label, client, win, seconds, max_wall, daemon.alive)
        out = win.end(sim)
        out["load_at_start"] = load0
        out["daemon_alive"] = daemon.alive()
        return out
    finally:
        client.close()
        daemon.stop()


# -- B: the daemon without navigation, and an outside navigator's I/O ----------------------------------


def run_outside(size: int, seconds: float, settle: float, max_wall: float, seed: int, tmp: Path) -> dict[str, Any]:
    label = f"B {size}"
    load0 = _loadavg()
    daemon, client, _, _, _ = _setup(size, seed, tmp, ["--no-nav"])
    log = (tmp / f"client-{size}.log").open("w")
    proc = subprocess.Popen(
        [sys.executable, "-m", "bench.nav_placement", "--client", daemon.endpoint, "--robots", str(size)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=log,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
        start_new_session=True,
        preexec_fn=PREEXEC,
    )
    try:
        _expect(proc, "ready", 60.0)
        alive = lambda: daemon.alive() and proc.poll() is None  # noqa: E731
        _settle(label, client, settle, alive)
        win = Window(daemon.pid, proc.pid)
        _say(proc, "mark")
        _expect(proc, "marked", 10.0)
        win.start(_sim_now(client))
        sim = _run_window(label, client, win, seconds, max_wall, alive)
        out = win.end(sim)
        _say(proc, "stop")
        line = _expect(proc, "{", 30.0)
        out["client"] = json.loads(line)
        out["load_at_start"] = load0
        out["daemon_alive"] = daemon.alive()
        return out
    finally:
        if proc.poll() is None:
            proc.terminate()
        stop_process(proc, 5.0)
        log.close()
        client.close()
        daemon.stop()


def _say(proc: subprocess.Popen[str], line: str) -> None:
    assert proc.stdin is not None
    proc.stdin.write(line + "\n")
    proc.stdin.flush()


def _expect(proc: subprocess.Popen[str], start: str, timeout: float) -> str:
    """The client's next line that starts with ``start``."""
    assert proc.stdout is not None
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stdout], [], [], 0.5)
        if ready:
            line = proc.stdout.readline()
            if not line:
                break
            if line.startswith(start):
                return line.strip()
        elif proc.poll() is not None:
            break
    raise RuntimeError(f"the navigator client did not say {start!r} (exit code {proc.poll()})")


# -- the client: an outside navigator's I/O, nothing else -----------------------------------------------


@dataclass
class OutsideIO:
    """What the outside navigator hears and says; counters read at mark and stop."""

    client: Any
    names: list[str]
    lock: threading.Lock = field(default_factory=threading.Lock)
    wake: threading.Event = field(default_factory=threading.Event)
    stopping: bool = False
    latest: Any = None
    last_tick: int = -1
    odom_msgs: int = 0
    scan_msgs: int = 0
    scan_rows: int = 0
    control_steps: int = 0
    control_missed: int = 0
    commands: int = 0
    latencies: list[int] = field(default_factory=list)
    unseen: int = 0  # switches whose effect no odometry showed before the next switch

    def __post_init__(self) -> None:
        n = len(self.names)
        self.index = {ns: i for i, ns in enumerate(self.names)}
        self.sign = np.zeros(n)  # the command each robot was last sent: +1, -1 (0: none yet)
        self.switched_at = np.full(n, -1, dtype=np.int64)  # odometry tick a new command came from
        self.prev_w = np.full(n, np.nan)
        self.offset = CONTROL_EVERY * (np.arange(n) % (SWITCH // CONTROL_EVERY))
        self._rows_of: list[str] = []
        self._order = np.arange(0)

    def on_odom(self, msg: Any) -> None:
        tick = _tick(msg.stamp)
        if msg.namespaces != self._rows_of:
            self._rows_of = list(msg.namespaces)
            self._order = np.array([self.index.get(ns, -1) for ns in msg.namespaces], dtype=np.int64)
        w = np.full(len(self.names), np.nan)
        ok = self._order >= 0
        w[self._order[ok]] = msg.array("angular_z")[ok]
        with self.lock:
            self.odom_msgs += 1
            self.last_tick = max(self.last_tick, tick)
            pending = self.switched_at >= 0
            seen = pending & (self.sign * (w - self.prev_w) > SEEN_W)
            if seen.any():
                self.latencies.extend((tick - self.switched_at[seen]).tolist())
                self.switched_at[seen] = -1
            self.prev_w = w
            self.latest = msg
        self.wake.set()

    def on_scans(self, msg: Any) -> None:
        rows = msg.ranges_array()  # what a lidar guard would read
        with self.lock:
            self.scan_msgs += 1
            self.scan_rows += rows.shape[0]

    def drive(self) -> None:
        """Every control period: every robot's command from the newest odometry (worker thread)."""
        last_period = -1
        while not self.stopping:
            self.wake.wait(0.5)
            self.wake.clear()
            with self.lock:
                msg, self.latest = self.latest, None
            if msg is None:
                continue
            tick = _tick(msg.stamp)
            period = tick // CONTROL_EVERY
            if period <= last_period:
                continue
            if last_period >= 0:
                self.control_missed += period - last_period - 1
            last_period = period
            control = period * CONTROL_EVERY
            sign = np.where(((control + self.offset) // SWITCH) % 2 == 0, 1.0, -1.0)
            with self.lock:
                new = (sign != self.sign) & (self.sign != 0)
                self.unseen += int(np.count_nonzero(new & (self.switched_at >= 0)))
                self.switched_at[new] = tick
                self.sign = sign
                self.control_steps += 1
            drive = self.client.drive
            for ns, s in zip(self.names, sign.tolist(), strict=True):
                drive(ns, V * s, W * s)
            self.commands += len(self.names)

    def counters(self) -> dict[str, Any]:
        with self.lock:
            return {
                "tick": self.last_tick,
                "odom_msgs": self.odom_msgs,
                "scan_msgs": self.scan_msgs,
                "scan_rows": self.scan_rows,
                "control_steps": self.control_steps,
                "control_missed": self.control_missed,
                "commands": self.commands,
                "latencies": len(self.latencies),
                "unseen": self.unseen,
                "cpu": time.process_time(),
                "wall": time.monotonic(),
            }


def client_main(endpoint: str, robots: int) -> int:
    """The outside navigator's I/O, told by lines on stdin: ``mark`` starts the window, ``stop``
    ends it and prints what was counted in it as one JSON line."""
    from clients.api import FleetClient

    client = FleetClient(endpoint, prefix=PREFIX, timeout=10.0)
    io = OutsideIO(client, [f"r{k}" for k in range(robots)])
    for ns in io.names:  # declare every publisher before the window
        client.drive(ns, 0.0, 0.0)
    client.on_fleet_odom(io.on_odom)
    client.on_fleet_scans(io.on_scans)
    worker = threading.Thread(target=io.drive, name="drive", daemon=True)
    worker.start()
    deadline = time.monotonic() + 30.0
    while io.odom_msgs == 0 and time.monotonic() < deadline:
        time.sleep(0.05)
    print("ready" if io.odom_msgs else "no odometry", flush=True)
    mark: dict[str, Any] = io.counters()
    lat_mark = 0
    for line in sys.stdin:
        cmd = line.strip()
        if cmd == "mark":
            mark = io.counters()
            lat_mark = mark["latencies"]
            print("marked", flush=True)
        elif cmd == "stop":
            end = io.counters()
            d = {k: end[k] - mark[k] for k in end}
            ticks = d["tick"]
            with io.lock:
                lat = io.latencies[lat_mark:]
            out = {
                "robots": robots,
                "ticks": ticks,
                "odom_fraction": round(d["odom_msgs"] / ticks, 4) if ticks > 0 else None,
                "scan_fraction": round(d["scan_rows"] / (robots * SCAN_HZ * ticks / TICK_HZ), 4) if ticks else None,
                "scan_msgs": d["scan_msgs"],
                "control_steps": d["control_steps"],
                "control_missed": d["control_missed"],
                "commands": d["commands"],
                "commands_per_wall_s": round(d["commands"] / d["wall"], 1) if d["wall"] > 0 else None,
                "odom_rows_per_wall_s": round(d["odom_msgs"] * robots / d["wall"], 1) if d["wall"] > 0 else None,
                "client_process_time_per_sim_s": round(d["cpu"] / (ticks / TICK_HZ), 4) if ticks > 0 else None,
                "latency_ticks_samples": len(lat),
                "latency_ticks_p50": statistics.median(lat) if lat else None,
                "latency_ticks_p95": float(np.percentile(lat, 95)) if lat else None,
                "latency_ticks_max": max(lat) if lat else None,
                "switches_unseen": d["unseen"],
            }
            print(json.dumps(out), flush=True)
            break
    io.stopping = True
    worker.join(2.0)
    client.close()
    return 0


# -- the report --------------------------------------------------------------------------------------


def _f(v: float | None, digits: int = 3) -> str:
    return "–" if v is None else f"{v:.{digits}f}"


def combine(size: int, a: dict[str, Any], b: dict[str, Any], c: dict[str, Any]) -> dict[str, Any]:
    """The navigator's CPU is A - C (the daemon with it against the daemon without it, robots
    moving in both); the I/O an outside navigator adds is (B - C) in the daemon plus B's client."""
    ad, bd, bc = a.get("daemon_cpu_per_sim_s"), b.get("daemon_cpu_per_sim_s"), b.get("client_cpu_per_sim_s")
    cd = c.get("daemon_cpu_per_sim_s")
    out: dict[str, Any] = {"robots": size, "a_daemon": ad, "a_nav_work": a.get("nav_work_per_sim_s"), "c_daemon": cd,
                           "b_daemon": bd, "b_client": bc, "a_nav": None, "daemon_io": None, "b_total": None,
                           "ratio": None}  # fmt: skip
    if ad is None or bd is None or bc is None or cd is None:
        return out
    nav = ad - cd
    total = bd + bc + nav
    out.update(
        a_nav=round(nav, 4),
        daemon_io=round(bd - cd, 4),
        b_total=round(total, 4),
        ratio=round(total / ad, 3) if ad > 0 else None,
    )
    return out


def table(rows: list[dict[str, Any]], runs: dict[int, dict[str, Any]]) -> list[str]:
    lines = [
        "CPU in seconds per sim second (all threads of the process). C: the daemon with --no-nav, robots moving, "
        "no subscriber, no commands. Navigator = A - C (its work_seconds, wall time on the sim thread, in "
        "brackets). B total = B daemon + B client + the navigator (A - C).",
        "",
        "| robots | A RTF | A daemon | C daemon | navigator (A - C) [work_seconds] | B RTF | B daemon "
        "| of which I/O (B - C) | B client | B total | B total / A |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        a, b = runs[r["robots"]]["A"], runs[r["robots"]]["B"]
        lines.append(
            f"| {r['robots']} | {_f(a.get('rtf'), 2)} | {_f(r['a_daemon'])} | {_f(r['c_daemon'])} "
            f"| {_f(r['a_nav'])} [{_f(r['a_nav_work'])}] | {_f(b.get('rtf'), 2)} | {_f(r['b_daemon'])} "
            f"| {_f(r['daemon_io'])} | {_f(r['b_client'])} | {_f(r['b_total'])} | {_f(r['ratio'], 2)} |"
        )
    lines += [
        "",
        "| robots | B: odometry ticks got | scans got | control steps missed | commands / s | odom rows / s "
        "| cmd latency p50 / p95 / max (ticks) | samples | sim thread on a CPU / sim s, A / B / C "
        "| sim thread waiting for a CPU / sim s, A / B / C "
        "| load (1 min) at start A / B / C |",
        "|---:|---:|---:|---:|---:|---:|---|---:|---|---|---|",
    ]
    for r in rows:
        a, b, c0 = (runs[r["robots"]][k] for k in "ABC")
        c = b.get("client", {})
        steps = c.get("control_steps", 0) + c.get("control_missed", 0)
        ons = " / ".join(_f(x.get("sim_thread_cpu_per_sim_s")) for x in (a, b, c0))
        waits = " / ".join(_f(x.get("sim_thread_wait_per_sim_s")) for x in (a, b, c0))
        loads = " / ".join(_f((x.get("load_at_start") or [None])[0], 2) for x in (a, b, c0))
        lines.append(
            f"| {r['robots']} | {_f(c.get('odom_fraction'))} | {_f(c.get('scan_fraction'))} "
            f"| {c.get('control_missed', '–')}/{steps} | {_f(c.get('commands_per_wall_s'), 0)} "
            f"| {_f(c.get('odom_rows_per_wall_s'), 0)} "
            f"| {_f(c.get('latency_ticks_p50'), 0)} / {_f(c.get('latency_ticks_p95'), 0)} / "
            f"{c.get('latency_ticks_max', '–')} | {c.get('latency_ticks_samples', '–')} | {ons} | {waits} | {loads} |"
        )
    return lines


def kept_up(b: dict[str, Any]) -> list[str]:
    """What says the client fell behind, if anything."""
    c = b.get("client", {})
    notes = []
    if (c.get("odom_fraction") or 0) < 0.99:
        notes.append(f"it got {_f(c.get('odom_fraction'))} of the ticks' odometry")
    if (c.get("scan_fraction") or 0) < 0.99:
        notes.append(f"{_f(c.get('scan_fraction'))} of the scans")
    steps = c.get("control_steps", 0) + c.get("control_missed", 0)
    if steps and c.get("control_missed", 0) > 0.01 * steps:
        notes.append(f"missed {c['control_missed']} of {steps} control steps")
    if (c.get("latency_ticks_p95") or 0) > 3:
        notes.append(f"its commands took {_f(c.get('latency_ticks_p95'), 0)} ticks to act (p95)")
    if (b.get("rtf") or 0) < 0.95:
        notes.append(f"the daemon ran at RTF {_f(b.get('rtf'), 2)}")
    return notes


def conclusion(rows: list[dict[str, Any]], runs: dict[int, dict[str, Any]]) -> str:
    parts = []
    for r in rows:
        if r["ratio"] is None:
            parts.append(f"At {r['robots']} robots a run did not finish; nothing to compare.")
            continue
        a, b = runs[r["robots"]]["A"], runs[r["robots"]]["B"]
        c = b.get("client", {})
        extra = r["b_total"] - r["a_daemon"]
        s = (
            f"At {r['robots']} robots the daemon with the navigator inside used {r['a_daemon']:.3f} CPU s per sim s "
            f"(RTF {_f(a.get('rtf'), 2)}), {r['a_nav']:.3f} of it the navigator's (A - C); the separate process "
            f"design needs at least {r['b_total']:.3f} ({r['ratio']:.2f}x, {extra:+.3f}): the daemon "
            f"{r['daemon_io']:+.3f} to publish the fleet's odometry and scans and take "
            f"{_f(c.get('commands_per_wall_s'), 0)} commands a second, and the client {r['b_client']:.3f} for "
            f"that I/O alone, before any navigating."
        )
        if r["a_nav_work"] is not None and r["a_nav"] is not None and r["a_nav_work"] > 1.2 * r["a_nav"]:
            s += (
                f" (The navigator's own work_seconds, {r['a_nav_work']:.3f}, is wall time on the sim thread and "
                f"counts the time it waited for a CPU: {_f(a.get('sim_thread_wait_per_sim_s'))} s per sim s.)"
            )
        at, bt = a.get("sim_thread_cpu_per_sim_s"), b.get("sim_thread_cpu_per_sim_s")
        if at is not None and bt is not None:
            s += (
                f" The simulation thread itself carried {at:.3f} s per sim s with the navigator on it and "
                f"{bt:.3f} with it outside (1.0 is all it has at RTF 1)."
            )
        notes = kept_up(b)
        if notes:
            s += " The outside client did not keep up: " + "; ".join(notes) + "."
        else:
            s += (
                f" The client kept up ({_f(c.get('odom_fraction'))} of the ticks' odometry, "
                f"{_f(c.get('scan_fraction'))} of the scans), its commands acting "
                f"{_f(c.get('latency_ticks_p50'), 0)} tick after the odometry they came from at p50 "
                f"({_f(c.get('latency_ticks_p95'), 0)} at p95; 1 in the daemon by construction)."
            )
        parts.append(s)
    done = [r for r in rows if r["ratio"] is not None]
    if done:
        lo, hi = min(r["ratio"] for r in done), max(r["ratio"] for r in done)
        span = f"{lo:.2f}x" if abs(hi - lo) < 0.005 else f"{lo:.2f}–{hi:.2f}x"
        if lo > 1.05:
            parts.append(
                f"So on this machine a navigator in its own process costs at least {span} the CPU of the one in "
                "the daemon (more in practice: its navigation work is taken as equal), and its commands can "
                "only act as soon or later; what it would buy is room on the simulation thread (the "
                "navigator's work on another core), which matters only when that thread runs out."
            )
        elif hi < 0.95:
            parts.append(
                f"So on this machine the separate process would cost less ({span}): the measured case for "
                "moving the navigator out."
            )
        else:
            parts.append(
                f"So on this machine the two cost about the same ({span}): CPU does not decide the placement; "
                "latency, delivery and determinism do."
            )
    return " ".join(parts)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.nav_placement", description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[100, 1000])
    p.add_argument("--seconds", type=float, default=60.0, help="sim seconds measured per run (default: %(default)s)")
    p.add_argument("--baseline-seconds", type=float, default=30.0, help="sim s of run C (default: %(default)s)")
    p.add_argument("--settle", type=float, default=10.0, help="sim seconds before measuring (default: %(default)s)")
    p.add_argument("--max-wall", type=float, default=150.0, help="wall s a window may take (default: %(default)s)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--out", type=Path, default=None, help="also write the results as JSON here")
    p.add_argument("--client", metavar="ENDPOINT", help=argparse.SUPPRESS)  # the B client process
    p.add_argument("--robots", type=int, default=0, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.client:
        return client_main(args.client, args.robots)
    machine = machine_info()
    print(f"nav_placement: {machine_line(machine)}", flush=True)
    runs: dict[int, dict[str, Any]] = {}
    rows = []
    with tempfile.TemporaryDirectory(prefix="nav_placement-") as tmp:
        for size in args.sizes:
            runs[size] = {}
            for kind, fn, where, secs in (
                ("C", run_baseline, "--no-nav, robots moving, no I/O", args.baseline_seconds),
                ("A", run_in_daemon, "navigator in the daemon", args.seconds),
                ("B", run_outside, "--no-nav + an outside navigator's I/O", args.seconds),
            ):
                print(f"-- {kind}: {size} robots, {where}, {secs:g} sim s; load {_loadavg()}", flush=True)
                runs[size][kind] = fn(size, secs, args.settle, args.max_wall, args.seed, Path(tmp))
                print(json.dumps(runs[size][kind]), flush=True)
            rows.append(combine(size, runs[size]["A"], runs[size]["B"], runs[size]["C"]))
    print()
    print(f"Machine: {machine_line(machine)}; load average now {' '.join(map(str, _loadavg()))}")
    print()
    for line in table(rows, runs):
        print(line)
    print()
    print(conclusion(rows, runs))
    if args.out:
        args.out.write_text(json.dumps({"machine": machine, "runs": runs, "summary": rows}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
