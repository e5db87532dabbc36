"""How fast a learning loop steps a large fleet: in process, through the PettingZoo env, and
on a lockstep daemon, side by side.

    python -m bench.learn_bench                       # 1 000 robots, 5 interleaved runs of each
    python -m bench.learn_bench --robots 200 --steps 30 --runs 3

A learner steps every robot 0.2 s at a time (six 30 Hz ticks, one lidar period) and reads every
robot's odometry and scan back. Issue "learn" asks for 1 000 robots that see each other stepped
at a real-time factor of at least 20 (sim seconds per wall second; ticks × robots per second is
RTF × 30 × robots). What is timed, each in the benchmark's arena for N robots (bench/arena.py:
robots 2 m apart among pillars, every robot sees several others):

- ``core``: the simulation core in this process (no env, no network): each step sets every
  robot's command, runs six ticks and gathers the odometry and latest scans of all robots as
  arrays (what a packed step returns). The ceiling of embedded stepping.
- ``env``: ``FleetNavigateEnv(robots=N)`` in this process: the same plus the env's work
  (rewards, observations of 24 sectors, PettingZoo's dicts), random actions.
- ``daemon messages``: ``simd --lockstep`` stepped over Zenoh as before the fast mode: every
  tick published, each robot's odometry and scan as its own message in the step's reply.
- ``daemon packed``: the same daemon stepped with ``publish=False, packed=True`` and the
  commands as arrays (``commands=``).
- ``env remote``: ``FleetNavigateEnv(endpoint=..., publish=False)`` on that daemon.

Every run of a part starts from the same world (reset, same seed) and drives the same seeded
commands; the runs of the parts are interleaved, so that load on a shared machine falls on all
of them alike. Medians of the runs are compared; ``daemon packed`` against ``daemon messages``
is the fast mode's gain.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from bench.arena import Arena, make_arena, write_world
from bench.processes import DaemonProc, start_daemon
from bench.progress import Progress
from bench.report import machine_info, machine_line
from bench.wire import PREFIX

STEP_TICKS = 6
STEP_SECONDS = STEP_TICKS / 30.0
SEED = 1
TARGET_ROBOTS, TARGET_RTF = 1000, 20.0  # issue "learn"


def _commands(rng: np.random.Generator, n: int, held: np.ndarray | None) -> np.ndarray:
    """A wander: each robot keeps its (v, w) and redraws it with probability 0.1 a step."""
    fresh = np.stack([rng.uniform(0.0, 0.22, n), rng.uniform(-1.0, 1.0, n)], axis=1)
    if held is None:
        return fresh
    redraw = rng.random(n) < 0.1
    return np.where(redraw[:, None], fresh, held)


class Part:
    """One way of stepping; ``run`` returns the wall seconds of ``steps`` steps from a reset."""

    name = ""

    def run(self, steps: int) -> float:
        raise NotImplementedError

    def close(self) -> None:
        pass


class CorePart(Part):
    name = "core"

    def __init__(self, arena: Arena) -> None:
        from protocol.control import SpawnRequest
        from simd.core.sim import SimConfig, Simulation
        from simd.core.worldfile import world_from_dict

        self.sim = Simulation(world_from_dict(arena.world), SimConfig(seed=SEED, cmd_timeout=0))
        for i, (x, y, yaw) in enumerate(arena.poses):
            self.sim.spawn(SpawnRequest(name=f"r{i}", x=x, y=y, yaw=yaw))
        self.n = len(arena.poses)

    def run(self, steps: int) -> float:
        sim, t, n = self.sim, self.sim.robots, self.n
        sim.reset(SEED)
        rng = np.random.default_rng(SEED)
        rows = np.arange(n)
        scans = np.full((n, sim.config.lidar.samples), np.nan, dtype=np.float32)
        latest: dict[str, int] = {ns: i for i, ns in enumerate(t.namespaces)}
        cmd = None
        start = time.perf_counter()
        for _ in range(steps):
            cmd = _commands(rng, n, cmd)
            snaps = []
            for _ in range(STEP_TICKS):
                sim.command_rows(rows, cmd[:, 0], cmd[:, 1])
                snaps.append(sim.step())
            for snap in snaps:  # read after the ticks: the lidar thread casts beside the physics
                if snap.scan_namespaces:
                    scans[[latest[ns] for ns in snap.scan_namespaces]] = snap.scans
            last = snaps[-1]
            odom = np.stack([last.x, last.y, last.yaw, last.linear_x, last.linear_y, last.angular_z], axis=1)
            assert odom.shape == (n, 6)
        return time.perf_counter() - start

    def close(self) -> None:
        self.sim.close()


class EnvPart(Part):
    def __init__(self, world: Path, n: int, endpoint: str | None = None) -> None:
        from learn.navigate_fleet import FleetNavigateEnv

        self.name = "env" if endpoint is None else "env remote"
        self.env = FleetNavigateEnv(
            robots=n, world=str(world), max_steps=10**6, endpoint=endpoint, prefix=PREFIX, publish=False
        )
        self.left: list[int] = []  # agents still in the episode at the end of each run

    def run(self, steps: int) -> float:
        env = self.env
        env.reset(seed=SEED)
        rng = np.random.default_rng(SEED)
        n = len(env.possible_agents)
        # gentle random actions (forward, turning a little): most agents are still there at the end
        actions = np.stack([rng.uniform(0.0, 0.6, (steps, n)), rng.uniform(-0.4, 0.4, (steps, n))], axis=2)
        index = {a: i for i, a in enumerate(env.possible_agents)}
        start = time.perf_counter()
        for k in range(steps):
            act = actions[k]
            env.step({a: act[index[a]] for a in env.agents})
        wall = time.perf_counter() - start
        self.left.append(len(env.agents))
        return wall

    def close(self) -> None:
        self.env.close()


class DaemonPart(Part):
    def __init__(self, daemon: DaemonProc, n: int, packed: bool) -> None:
        from clients.api import FleetClient

        self.name = "daemon packed" if packed else "daemon messages"
        self.client = FleetClient(daemon.endpoint, prefix=PREFIX, timeout=60.0)
        self.names = [f"r{i}" for i in range(n)]
        self.packed = packed

    def run(self, steps: int) -> float:
        from clients.api import observed_arrays

        c, names, n = self.client, self.names, len(self.names)
        c.reset(SEED)
        rng = np.random.default_rng(SEED)
        cmd = None
        start = time.perf_counter()
        for _ in range(steps):
            cmd = _commands(rng, n, cmd)
            if self.packed:
                reply = c.step(STEP_TICKS, commands=(names, cmd), observe=names, packed=True, publish=False)
                assert reply.packed is not None
                seen = observed_arrays(reply.packed)
                assert seen.odom.shape == (n, 6)
            else:
                v, w = cmd[:, 0].tolist(), cmd[:, 1].tolist()
                cmd_vel = {ns: (v[i], w[i]) for i, ns in enumerate(names)}
                reply = c.step(STEP_TICKS, cmd_vel=cmd_vel, observe=names)
                odom = np.array([[o.odom.pose.pose.position.x, o.odom.pose.pose.position.y]
                                 for o in reply.observations.values()])  # fmt: skip
                assert odom.shape == (n, 2)
        return time.perf_counter() - start

    def close(self) -> None:
        self.client.close()


def _spawn_fleet(daemon: DaemonProc, arena: Arena) -> None:
    from clients.api import FleetClient

    with FleetClient(daemon.endpoint, prefix=PREFIX, timeout=60.0) as c:
        for i, (x, y, yaw) in enumerate(arena.poses):
            c.spawn(f"r{i}", x, y, yaw)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.learn_bench", description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", type=int, default=1000, help="fleet size (default 1000)")
    ap.add_argument("--steps", type=int, default=50, help="steps (0.2 s each) a run (default 50)")
    ap.add_argument("--runs", type=int, default=5, help="runs of each part, interleaved (default 5)")
    ap.add_argument(
        "--parts",
        nargs="+",
        default=["core", "env", "daemon-messages", "daemon-packed", "env-remote"],
        choices=["core", "env", "daemon-messages", "daemon-packed", "env-remote"],
    )
    args = ap.parse_args(argv)
    if args.robots < 1 or args.steps < 1 or args.runs < 1:
        ap.error("--robots, --steps and --runs must be at least 1")
    info = machine_info()
    print(f"# learn_bench: {args.robots} robots, {args.steps} steps x {args.runs} runs")
    print(f"machine: {machine_line(info)}")
    progress = Progress()
    arena = make_arena(args.robots)
    x, y, yaw = arena.poses[0]  # the envs draw where the robots can drive from the spawn: the open floor, not a pen
    arena.world["default_spawn"] = {"x": x, "y": y, "yaw": yaw}
    parts: list[Part] = []
    daemons: list[DaemonProc] = []
    with tempfile.TemporaryDirectory(prefix="learn_bench_") as tmp_name:
        tmp = Path(tmp_name)
        world = tmp / "arena.yaml"
        write_world(arena, world)
        try:
            builders: dict[str, Callable[[], Part]] = {}

            def daemon(extra: list[str]) -> DaemonProc:
                d = start_daemon(world, 1.0, args.robots + 10, tmp, ["--lockstep", "--cmd-timeout", "0", *extra])
                daemons.append(d)
                _wait_up(d)
                return d

            if "core" in args.parts:
                builders["core"] = lambda: CorePart(arena)
            if "env" in args.parts:
                builders["env"] = lambda: EnvPart(world, args.robots)
            if {"daemon-messages", "daemon-packed"} & set(args.parts):
                shared: list[DaemonProc] = []

                def fleet_daemon() -> DaemonProc:
                    if not shared:
                        shared.append(daemon([]))
                        progress.update(f"spawning {args.robots} robots on the daemon", force=True)
                        _spawn_fleet(shared[0], arena)
                    return shared[0]

                if "daemon-messages" in args.parts:
                    builders["daemon-messages"] = lambda: DaemonPart(fleet_daemon(), args.robots, packed=False)
                if "daemon-packed" in args.parts:
                    builders["daemon-packed"] = lambda: DaemonPart(fleet_daemon(), args.robots, packed=True)
            if "env-remote" in args.parts:
                builders["env-remote"] = lambda: EnvPart(world, args.robots, _env_daemon(daemon))
            for key in args.parts:
                progress.update(f"setting up {key}", force=True)
                parts.append(builders[key]())
            walls: dict[str, list[float]] = {p.name: [] for p in parts}
            for r in range(args.runs):
                for p in parts:
                    progress.update(f"run {r + 1}/{args.runs}: {p.name}", force=True)
                    walls[p.name].append(p.run(args.steps))
            progress.done("")
        finally:
            for p in parts:
                p.close()
            for d in daemons:
                d.stop()
    _report(walls, parts, args.steps, args.robots)
    return 0


def _env_daemon(daemon: Callable[[list[str]], DaemonProc]) -> str:
    return daemon([]).endpoint


def _wait_up(d: DaemonProc) -> None:
    from clients.api import FleetClient
    from protocol.errors import FleetError

    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline:
        if not d.alive():
            sys.exit(f"learn_bench: the daemon died:\n{d.log_tail()}")
        try:
            with FleetClient(d.endpoint, prefix=PREFIX, timeout=2.0) as c:
                c.clock()
                return
        except FleetError:
            time.sleep(0.2)
    sys.exit("learn_bench: the daemon did not answer within 30 s")


def _report(walls: dict[str, list[float]], parts: list[Part], steps: int, robots: int) -> None:
    sim_seconds = steps * STEP_SECONDS
    print()
    print("| part | RTF min | RTF median | RTF max | ms a step (median) | note |")
    print("|---|---|---|---|---|---|")
    medians: dict[str, float] = {}
    for p in parts:
        rtf = sorted(sim_seconds / w for w in walls[p.name])
        med = statistics.median(rtf)
        medians[p.name] = med
        note = ""
        if isinstance(p, EnvPart):
            note = f"agents left at the end: {min(p.left)}-{max(p.left)}"
        step_ms = statistics.median(walls[p.name]) / steps * 1e3
        print(f"| {p.name} | {rtf[0]:.1f} | **{med:.1f}** | {rtf[-1]:.1f} | {step_ms:.1f} | {note} |")
    if "daemon packed" in medians and "daemon messages" in medians:
        ratio = medians["daemon packed"] / medians["daemon messages"]
        print(f"\ndaemon packed / daemon messages (ratio of medians): {ratio:.2f}x")
    if robots == TARGET_ROBOTS:
        for name, value in medians.items():
            verdict = "met" if value >= TARGET_RTF else "not met"
            print(f"target RTF >= {TARGET_RTF:g} with {robots} robots, {name}: {verdict} ({value:.1f})")


if __name__ == "__main__":
    sys.exit(main())
