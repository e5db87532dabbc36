"""Time to goal in a crowd, pooled over seeds: the navigator on the simulation in one process.

    python -m bench.nav_crowd                                # 10 burgers, turtlebot3_world, 12 seeds x 300 s
    python -m bench.nav_crowd --robots 1 --seeds 4           # a lone burger, for what the crowd adds
    python -m bench.nav_crowd --first-seed 25 --seeds 24     # seeds 25-48 (held out from tuning)
    python -m bench.nav_crowd --jobs 2                       # seeds in two processes (same numbers)
    python -m bench.nav_crowd --seeds 6 --seconds 200 --out crowd.json

``bench.nav_bench`` runs one daemon over the fleet protocol, and one run of ten robots is one
draw of a chaotic system: its p50 swings by a tenth between seeds. This runs the same
navigator (simd/nav) on the same simulation tick by tick, lockstep, with no daemon and no
network in between, so that many seeds cost little, and pools their goals: each robot always
has a random reachable goal over 1 m away (a new one as soon as one ends, tolerance 0.1 m),
and each goal reached gives its time over the lower bound, the straight line less the
tolerance at the model's top speed (as nav_bench's). Printed: goals reached and failed, the
pooled p50 / p75 / p95 of that ratio, and the closest two robots' centres came; where the time
goes (seconds per goal in each state) and whom waiting robots wait for; and the time lost
against the bound by what the robot did (each step's time less its progress towards the goal
at top speed: a crowd's excess over a lone robot's, by cause). Every number of a seed is the
same on every run (lockstep, seeded goals).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from concurrent.futures import ProcessPoolExecutor
from contextlib import nullcontext
from dataclasses import asdict, dataclass, field
from functools import partial

import numpy as np
import numpy.typing as npt

from protocol.control import SpawnRequest
from protocol.navigation import NavigateRequest
from simd.core.models import MODELS, RobotModel
from simd.core.sim import SimConfig, Simulation
from simd.core.worldfile import WorldGeometry, load_world
from simd.nav.flood import reachable
from simd.nav.navigator import Navigator
from simd.nav.robot import NavRobot

TOLERANCE_M = 0.1
#: goals and spawns this far apart at least (m)
MIN_GOAL_M, MIN_APART_M = 1.0, 0.7


#: a driving robot slower than this (m/s) and turning faster than this (rad/s) turns on the spot
STILL_V, TURNING_W = 0.02, 0.3


@dataclass
class SeedRun:
    seed: int
    ratios: list[float]
    failed: dict[str, int]
    closest_m: float
    #: for each reached goal (as ``ratios``): seconds in each state, and the bound
    parts: list[dict[str, float]]
    #: seconds robots were ``waiting``, by what they did and whom they waited for (``_waits``)
    waits: dict[str, float] = field(default_factory=dict)
    #: seconds lost against the bound (a step's time less its progress towards the goal at top
    #: speed), by what the robot did, summed over every goal's steps (reached or not)
    lost: dict[str, float] = field(default_factory=dict)


def _doing(state: str, command: tuple[float, float]) -> str:
    """What a robot does, as its state says, with ``driving`` split by its command."""
    if state != "driving":
        return state
    v, w = command
    if abs(v) >= STILL_V:
        return "moving"
    return "turning" if abs(w) > TURNING_W else "standing"


def _waits(nav: Navigator, robot: NavRobot, slots: dict[int, NavRobot]) -> str:
    """What a ``waiting`` robot does, and whom it waits for: drives meanwhile (up to its
    cell's border, behind one leaving the next cell), or stands behind one driving out of the
    cell it wants (the cell is promised to it), one driving through or holding it, one making
    way, one waiting itself, one turning or standing."""
    if abs(robot.command[0]) >= STILL_V:
        return "drives meanwhile"
    floor = nav.floor
    other = slots.get(floor.waiting_for(robot))
    if other is None or not other.active:
        return "stands behind one with no goal"
    doing = _doing(other.state, other.command)
    if doing == "moving":
        traffic = floor.traffic
        m = traffic.movers[robot.slot]
        promised = bool(m.needs) and any(int(traffic.pending[c]) == m.slot for c in m.needs[0])
        return "stands behind one driving out of its cell" if promised else "stands behind one driving through"
    return {"yielding": "stands behind one making way", "waiting": "stands behind one waiting itself",
            "turning": "stands behind one turning"}.get(doing, "stands behind one standing")  # fmt: skip


def goal_points(nav: Navigator, world: WorldGeometry, model: RobotModel) -> npt.NDArray[np.float64]:
    """The centres of the costmap's cells a ``model`` reaches from the world's default spawn,
    with 5 cm to spare: where robots are spawned and sent."""
    cm = nav.costmap
    start = cm.grid.cell(*world.default_spawn[:2])
    if start is None:
        raise SystemExit(f"nav_crowd: {world.name}'s default spawn is off its map")
    ok = reachable(np.isfinite(cm.costs(model)), start) & (cm.clearance >= model.radius + 0.05)
    rows, cols = np.nonzero(ok)
    return cm.grid.centres(np.stack([rows, cols], axis=1).astype(np.int32))


def run_seed(world_name: str, robots: int, seconds: float, seed: int) -> SeedRun:
    world = load_world(world_name)
    sim = Simulation(world, SimConfig(seed=0))
    nav = Navigator(world, sim.config.lidar, sim.robots)
    burger = MODELS["burger"]
    points = goal_points(nav, world, burger)
    rng = np.random.default_rng(seed)
    names: list[str] = []
    for _ in range(100_000):
        if len(names) == robots:
            break
        x, y = points[rng.integers(len(points))]
        t = sim.robots
        if len(t.x) and np.hypot(t.x - x, t.y - y).min() < MIN_APART_M:
            continue
        names.append(f"r{len(names)}")
        sim.spawn(SpawnRequest(name=names[-1], x=float(x), y=float(y), yaw=float(rng.uniform(-math.pi, math.pi))))
    bound: dict[str, float] = {}

    def send(name: str) -> None:
        row = sim.robots.row_of(name)
        here = (float(sim.robots.x[row]), float(sim.robots.y[row]))
        while True:
            x, y = points[rng.integers(len(points))]
            d = math.hypot(x - here[0], y - here[1])
            if d > MIN_GOAL_M:
                nav.goal(name, burger, NavigateRequest(x=float(x), y=float(y), tolerance=TOLERANCE_M), sim.time)
                bound[name] = (d - TOLERANCE_M) / burger.max_linear_velocity
                return

    for name in names:
        send(name)
    out = SeedRun(seed, [], {}, math.inf, [])
    slots = {nav.robots[name].slot: nav.robots[name] for name in names}
    spent: dict[str, dict[str, float]] = {name: {} for name in names}
    dt = sim.config.dt
    def left(name: str) -> float:
        row, goal = sim.robots.row_of(name), nav.robots[name].goal
        assert goal is not None
        return math.hypot(goal.x - float(sim.robots.x[row]), goal.y - float(sim.robots.y[row]))

    for k in range(int(seconds / dt)):
        nav.step(sim.robots, sim.tick, sim.time)
        nav.apply(sim.robots, sim.command_rows)
        doing_now = {name: _doing(nav.robots[name].state, nav.robots[name].command) for name in names
                     if nav.robots[name].active}  # fmt: skip
        why_now = {name: _waits(nav, nav.robots[name], slots) for name, d in doing_now.items() if d == "waiting"}
        before = {name: left(name) for name in doing_now}
        nav.observe(sim.step())
        for name, doing in doing_now.items():
            spent[name][doing] = spent[name].get(doing, 0.0) + dt
            what = f"waiting: {why_now[name]}" if doing == "waiting" else doing
            if doing == "moving":  # a longer way than the straight line, or a slower one
                near_top = abs(nav.robots[name].command[0]) >= 0.95 * burger.max_linear_velocity
                what = "moving at top speed" if near_top else "moving slower"
            lost = dt - (before[name] - left(name)) / burger.max_linear_velocity
            out.lost[what] = out.lost.get(what, 0.0) + lost
            if doing == "waiting":
                out.waits[why_now[name]] = out.waits.get(why_now[name], 0.0) + dt
        for r in nav.take_events().results:
            if r.status == "reached":
                out.ratios.append(r.navigation_time / bound[r.robot])
                out.parts.append({**spent[r.robot], "bound": bound[r.robot]})
            else:
                out.failed[r.reason] = out.failed.get(r.reason, 0) + 1
            spent[r.robot] = {}
            send(r.robot)
        if k % 3 == 0 and robots > 1:
            t = sim.robots
            d = np.hypot(t.x[:, None] - t.x[None, :], t.y[:, None] - t.y[None, :]) + np.eye(len(t.x)) * 9.0
            out.closest_m = min(out.closest_m, float(d.min()))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.nav_crowd", description=__doc__.split("\n\n")[0])
    p.add_argument("--robots", type=int, default=10)
    p.add_argument("--world", default="turtlebot3_world")
    p.add_argument("--seeds", type=int, default=12, help="how many seeds (default: 12)")
    p.add_argument("--first-seed", type=int, default=1, help="the first of the seeds (default: 1)")
    p.add_argument("--jobs", type=int, default=1, help="seeds run in this many processes at once (default: 1)")
    p.add_argument("--seconds", type=float, default=300.0, help="sim seconds per seed (default: 300)")
    p.add_argument("--out", help="also write every seed's goals as JSON here")
    args = p.parse_args(argv)
    if args.robots < 1 or args.seeds < 1 or args.jobs < 1 or not args.seconds > 0:
        p.error("--robots, --seeds, --jobs and --seconds must be positive")
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    runs = []
    with ProcessPoolExecutor(args.jobs) if args.jobs > 1 else nullcontext() as pool:
        each = partial(run_seed, args.world, args.robots, args.seconds)
        done = pool.map(each, seeds) if pool is not None else map(each, seeds)
        for seed, run in zip(seeds, done, strict=True):
            runs.append(run)
            mid = f"p50 {statistics.median(run.ratios):.3f}" if run.ratios else "no goal reached"
            print(f"  seed {seed}: {len(run.ratios)} reached, failed {run.failed or 0}, {mid}", flush=True)
    ratios = sorted(r for run in runs for r in run.ratios)
    failed = sum(sum(run.failed.values()) for run in runs)
    if not ratios:
        print("nav_crowd: no goal reached", file=sys.stderr)
        return 1
    q = np.percentile(ratios, [50, 75, 95])
    closest = min(run.closest_m for run in runs)
    print(f"{args.robots} robots, {args.world}, seeds {seeds[0]}-{seeds[-1]} x {args.seconds:g} s: "
          f"{len(ratios)} goals reached, {failed} failed; "
          f"time over the straight-line bound p50 {q[0]:.3f}, p75 {q[1]:.3f}, p95 {q[2]:.3f}; "
          f"closest centres {closest:.3f} m")  # fmt: skip
    parts = [(r, p) for run in runs for r, p in zip(run.ratios, run.parts, strict=True)]
    middle = [p for r, p in parts if abs(r - q[0]) <= 0.1]
    print(_where_time_goes("goals within 0.1 of the median", middle))
    print(_where_time_goes("all reached goals", [p for _, p in parts]))
    waits: dict[str, float] = {}
    for run in runs:
        for k, v in run.waits.items():
            waits[k] = waits.get(k, 0.0) + v
    if waits:
        total = sum(waits.values())
        print(
            f"  waiting ({total:.0f} s in all): "
            + ", ".join(f"{k} {100 * v / total:.0f} %" for k, v in sorted(waits.items(), key=lambda kv: -kv[1]))
        )
    lost: dict[str, float] = {}
    for run in runs:
        for k, v in run.lost.items():
            lost[k] = lost.get(k, 0.0) + v
    if lost:
        print(
            f"  time lost against the bound, s per reached goal ({sum(lost.values()) / len(ratios):.2f} in all): "
            + ", ".join(f"{k} {v / len(ratios):.2f}" for k, v in sorted(lost.items(), key=lambda kv: -kv[1]))
        )
    if args.out:
        with open(args.out, "w") as f:
            json.dump([asdict(run) for run in runs], f)
    return 0


def _where_time_goes(label: str, parts: list[dict[str, float]]) -> str:
    """One line: mean seconds per goal in each state, the bound first."""
    if not parts:
        return f"  {label}: none"
    keys = sorted({k for p in parts for k in p} - {"bound"}, key=lambda k: -sum(p.get(k, 0.0) for p in parts))
    mean = {k: sum(p.get(k, 0.0) for p in parts) / len(parts) for k in ["bound", *keys]}
    return f"  {label} ({len(parts)}), mean s per goal: " + ", ".join(f"{k} {v:.2f}" for k, v in mean.items())


if __name__ == "__main__":
    raise SystemExit(main())
