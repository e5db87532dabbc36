"""Steps a second of ``fleetsim/Navigate-v0`` against ir-sim's environment, side by side.

    python -m bench.env_speed --irsim-python /path/to/irsim-venv/bin/python
    python -m bench.env_speed --irsim-python /path/to/irsim-venv/bin/python --seconds 5 --runs 5
    python -m bench.env_speed --no-vec                      # without the two-process vector env

Issue "learn" asks for the single-robot environment at ten times or more the steps a second of
ir-sim (PyPI ``ir-sim``, import ``irsim``), the Python 2D simulator researchers wrap for
reinforcement learning, measured on the same machine. ir-sim is not a dependency of fleetsim: it
runs in its own interpreter (``--irsim-python``; make one with ``python -m venv /some/venv &&
/some/venv/bin/pip install ir-sim``) as a child process that gets its world as JSON on stdin.

Both sides run the same loop for ``--seconds`` of wall time after a short warm-up: a uniformly
random (linear, angular) velocity within the burger's limits (0.22 m/s, 2.84 rad/s) each step,
the scan read back each step, a new episode after a collision or 500 steps.

- **fleetsim**: ``gymnasium.make("fleetsim/Navigate-v0")`` (burger, turtlebot3_world, lidar noise
  on as by default), ``env.step(env.action_space.sample())``, ``reset()`` on ``terminated`` or
  ``truncated``. One step is 0.2 s of sim time (six 30 Hz ticks) and its observation is the full
  one (24 sectors, goal, velocities) with reward and termination.
- **ir-sim**: the same world built from fleetsim's own world file (each polygon as an ir-sim
  polygon, each pillar as an ir-sim circle, static), one ``diff`` robot with a 0.105 m circular
  footprint, a ``lidar2d`` of 360 beams over 6.28 rad (the LDS-01's), 0.12-3.5 m, Gaussian noise
  0.01 m, mounted 32 mm behind the centre; ``step_time`` 0.2 s, collision mode ``stop``, headless
  (no figure; ``MPLBACKEND=Agg``, no ``DISPLAY``). Each step is ``env.step(velocity)``, then the
  scan's ranges copied and reduced to 24 sector minima (what a wrapper's observation does);
  ``env.reset()`` when the robot collides or arrives, or after 500 steps. Its reset returns to the
  world's default spawn rather than drawing a new start: cheaper than fleetsim's, if anything.
- **fleetsim, 2 processes** (skip with ``--no-vec``): ``gymnasium.make_vec(..., num_envs=2,
  vectorization_mode="async")``, steps counted per environment.

The runs alternate (fleetsim, ir-sim, vector, fleetsim, ...) ``--runs`` times each so that a
machine that gets busier or quieter affects both; the table gives the minimum, median and
maximum steps a second of each, sim seconds a wall second, and the ratio of the medians, under the
machine, the commit and the command. Each run line also gives the stepping process's CPU seconds a
wall second (well under 1: the run shared its core with something else), and the table the steps
a CPU second, a second ratio that a busy machine disturbs less. Results are in docs/learning.md.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shlex
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from bench.processes import ROOT

STEP_S = 0.2  # sim seconds a step, on both sides
MAX_STEPS = 500  # an episode's length limit, on both sides
SECTORS = 24  # fleetsim's default observation; ir-sim's scan is reduced to the same
WARMUP_STEPS = 20
ROBOT_RADIUS = 0.105  # the burger's footprint radius in the TurtleBot3 navigation parameters
INSTALL_HINT = "python -m venv /some/venv && /some/venv/bin/pip install ir-sim"

# The ir-sim side, run by the other interpreter with ``-c``: its settings arrive as JSON on stdin,
# its result leaves as one JSON line, the last on stdout. It imports nothing from fleetsim.
IRSIM_SCRIPT = r"""
import contextlib, json, os, platform, sys, tempfile, time
os.environ["MPLBACKEND"] = "Agg"
cfg = json.load(sys.stdin)
with contextlib.redirect_stdout(sys.stderr):  # ir-sim reports the backends it tried on stdout
    import irsim
import numpy as np
with tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False) as f:
    json.dump(cfg["world"], f)  # JSON is YAML
try:
    env = irsim.make(f.name, display=False, disable_all_plot=True, log_level="WARNING", seed=cfg["seed"])
finally:
    os.unlink(f.name)
rng = np.random.default_rng(cfg["seed"])
limits = np.array(cfg["limits"], dtype=float)
sectors = cfg["sectors"]
robot = env.robot
state = {"episode": 0, "episodes": 1, "collisions": 0, "beams": 0}

def step():
    env.step((rng.uniform(-1.0, 1.0, 2) * limits).reshape(2, 1))
    ranges = np.array(env.get_lidar_scan()["ranges"], dtype=np.float32)
    obs = ranges.reshape(sectors, -1).min(axis=1) / cfg["range_max"]
    state["beams"] = ranges.size
    state["episode"] += 1
    if robot.collision or robot.arrive or state["episode"] >= cfg["max_steps"]:
        state["collisions"] += bool(robot.collision)
        env.reset()
        state["episode"] = 0
        state["episodes"] += 1
    return obs

for _ in range(cfg["warmup"]):
    step()
state.update(episodes=1, collisions=0)
n, t0, c0 = 0, time.perf_counter(), time.process_time()
while time.perf_counter() - t0 < cfg["seconds"]:
    step()
    n += 1
wall, cpu = time.perf_counter() - t0, time.process_time() - c0
import numpy, shapely
print(json.dumps({
    "steps": n, "wall_s": wall, "cpu_s": cpu, "step_time": env.step_time, "episodes": state["episodes"],
    "collisions": state["collisions"], "beams": state["beams"], "irsim": irsim.__version__,
    "python": platform.python_version(), "numpy": numpy.__version__, "shapely": shapely.__version__,
}))
"""


def irsim_world(world: str = "turtlebot3_world") -> dict[str, Any]:
    """ir-sim's YAML configuration (as a dict) for fleetsim's world and one burger at its spawn."""
    from simd.core.models import BURGER
    from simd.core.sim import SimConfig
    from simd.core.worldfile import load_world

    w = load_world(world)
    lidar = SimConfig().lidar
    x0, x1, y0, y1 = w.bounds
    static = {"kinematics": {"name": "static"}}
    obstacles: list[dict[str, Any]] = [
        {"shape": {"name": "polygon", "vertices": p.tolist()}, "state": [0.0, 0.0, 0.0], **static} for p in w.polygons
    ]
    obstacles += [
        {"shape": {"name": "circle", "radius": float(r)}, "state": [float(x), float(y), 0.0], **static}
        for x, y, r in w.circles
    ]
    sx, sy, syaw = w.default_spawn
    vmax, wmax = BURGER.max_linear_velocity, BURGER.max_angular_velocity
    robot = {
        "kinematics": {"name": "diff"},
        "shape": {"name": "circle", "radius": ROBOT_RADIUS},
        "state": [sx, sy, syaw],
        "goal": [-sx, -sy, 0.0],  # somewhere: random actions do not arrive
        "vel_max": [vmax, wmax],
        "vel_min": [-vmax, -wmax],
        "sensors": [
            {
                "name": "lidar2d",
                "number": lidar.samples,
                "angle_range": lidar.angle_max - lidar.angle_min,
                "range_min": lidar.range_min,
                "range_max": lidar.range_max,
                "noise": True,
                "std": SimConfig().noise_stddev,
                "offset": [BURGER.lidar_offset[0], BURGER.lidar_offset[1], 0.0],
            }
        ],
    }
    return {
        "world": {
            "width": x1 - x0,
            "height": y1 - y0,
            "offset": [x0, y0],
            "step_time": STEP_S,
            "collision_mode": "stop",
        },
        "robot": [robot],
        "obstacle": obstacles,
    }


def _child_env() -> dict[str, str]:
    """The ir-sim process's environment: no display to open a window on, matplotlib's Agg backend,
    and none of this checkout on its path (it also runs in ``/``, so ``-c`` cannot import it)."""
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "PYTHONPATH")}
    env["MPLBACKEND"] = "Agg"
    return env


def irsim_available(python: str) -> tuple[bool, str]:
    """(True, version) when ``python`` imports irsim, else (False, why not) in a few words."""
    try:
        p = subprocess.run(
            [python, "-c", "import irsim; print(irsim.__version__)"],
            capture_output=True, text=True, timeout=120, env=_child_env(), cwd="/",
        )  # fmt: skip
    except (OSError, subprocess.SubprocessError) as e:
        return False, f"cannot run {python}: {e.strerror if isinstance(e, OSError) else e}"
    if p.returncode != 0:
        last = (p.stderr.strip().splitlines() or ["exit status " + str(p.returncode)])[-1]
        return False, f"{python} cannot import irsim ({last})"
    return True, (p.stdout.strip().splitlines() or ["?"])[-1]


def run_irsim(python: str, seconds: float, seed: int) -> dict[str, Any]:
    from simd.core.models import BURGER
    from simd.core.sim import SimConfig

    settings = {
        "world": irsim_world(),
        "seconds": seconds,
        "seed": seed,
        "warmup": WARMUP_STEPS,
        "max_steps": MAX_STEPS,
        "sectors": SECTORS,
        "range_max": SimConfig().lidar.range_max,
        "limits": [BURGER.max_linear_velocity, BURGER.max_angular_velocity],
    }
    p = subprocess.run(
        [python, "-c", IRSIM_SCRIPT], input=json.dumps(settings), capture_output=True, text=True,
        timeout=seconds + 180, env=_child_env(), cwd="/",
    )  # fmt: skip
    lines = [line for line in p.stdout.splitlines() if line.startswith("{")]
    if p.returncode != 0 or not lines:
        raise RuntimeError(f"the ir-sim run failed (exit status {p.returncode}):\n{p.stderr[-3000:]}")
    result: dict[str, Any] = json.loads(lines[-1])
    return result


def run_fleetsim(seconds: float, seed: int) -> dict[str, Any]:
    import gymnasium

    import learn  # noqa: F401  (registers the environments)

    env = gymnasium.make("fleetsim/Navigate-v0")
    env.action_space.seed(seed)
    env.reset(seed=seed)
    episodes, collisions = 1, 0

    def step() -> None:
        nonlocal episodes, collisions
        _, _, terminated, truncated, info = env.step(env.action_space.sample())
        if terminated or truncated:
            collisions += bool(info.get("collided"))
            env.reset()
            episodes += 1

    for _ in range(WARMUP_STEPS):
        step()
    episodes, collisions = 1, 0
    n, t0, c0 = 0, time.perf_counter(), time.process_time()
    while time.perf_counter() - t0 < seconds:
        step()
        n += 1
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    env.close()
    return {"steps": n, "wall_s": wall, "cpu_s": cpu, "episodes": episodes, "collisions": collisions}


def run_vector(seconds: float, seed: int, num_envs: int = 2) -> dict[str, Any]:
    """The async vector env (one process an environment); steps counted per environment. Its CPU
    seconds are the parent's only (the workers' are not counted)."""
    import gymnasium

    import learn  # noqa: F401

    envs = gymnasium.make_vec("fleetsim/Navigate-v0", num_envs=num_envs, vectorization_mode="async")
    try:
        envs.action_space.seed(seed)
        envs.reset(seed=seed)
        for _ in range(WARMUP_STEPS):
            envs.step(envs.action_space.sample())
        n, t0, c0 = 0, time.perf_counter(), time.process_time()
        while time.perf_counter() - t0 < seconds:
            envs.step(envs.action_space.sample())  # autoreset: an ended episode restarts on the next step
            n += num_envs
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    finally:
        envs.close()
    return {"steps": n, "wall_s": wall, "cpu_s": cpu}


def rate(r: dict[str, Any]) -> float:
    return float(r["steps"]) / float(r["wall_s"])


def run_line(name: str, i: int, runs: int, r: dict[str, Any]) -> str:
    extra = ""
    if "episodes" in r:
        extra = f", {r['episodes']} episodes ({r['collisions']} ended in a collision)"
    return (
        f"run {i + 1}/{runs} {name}: {rate(r):.0f} steps/s ({r['steps']} steps in {r['wall_s']:.2f} s{extra}; "
        f"CPU {r['cpu_s'] / r['wall_s']:.2f} s a wall second)"
    )


def cpu_rate(r: dict[str, Any]) -> float:
    """Steps a CPU second of the stepping process: the rate a quiet core would give, near enough."""
    return float(r["steps"]) / max(float(r["cpu_s"]), 1e-9)


def table(results: dict[str, list[dict[str, Any]]], labels: dict[str, str]) -> list[str]:
    lines = [
        "| environment | runs | steps/s min | median | max | sim s a wall second (median) "
        "| steps a CPU second (median) |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for key, runs in results.items():
        if not runs:
            continue
        rates = [rate(r) for r in runs]
        med = statistics.median(rates)
        # the vector env's work is in its worker processes, whose CPU time is not counted
        per_cpu = "–" if key == "vector" else f"{statistics.median(cpu_rate(r) for r in runs):.0f}"
        lines.append(
            f"| {labels[key]} | {len(rates)} | {min(rates):.0f} | {med:.0f} | {max(rates):.0f} "
            f"| {med * STEP_S:.0f} | {per_cpu} |"
        )
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument(
        "--irsim-python",
        default=sys.executable,
        help="an interpreter that imports irsim (default: this one); make one with: " + INSTALL_HINT,
    )
    ap.add_argument("--seconds", type=float, default=5.0, help="wall seconds each timed run lasts (5)")
    ap.add_argument("--runs", type=int, default=5, help="timed runs of each environment, interleaved (5)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-vec", action="store_true", help="skip the two-process vector env")
    args = ap.parse_args(argv)
    if args.seconds <= 0 or args.runs < 1:
        ap.error("--seconds must be positive and --runs at least 1")

    from bench.report import machine_info

    m = machine_info()
    dirty = _uncommitted("learn", "simd", "worlds")
    commit = (m["commit"] or "?").split(" ")[0] + (f" + uncommitted changes in {dirty}" if dirty else "")
    load = m.get("loadavg_at_start")
    print(f"machine: {m['cpu']}, {m['cores']} cores ({m['cores_usable']} usable); Python {m['python']}, "
          f"numpy {m['numpy']}; fleetsim fast paths {m['fast_paths']}", flush=True)  # fmt: skip
    print(f"commit: {commit}", flush=True)
    print("command: python -m bench.env_speed " + shlex.join(sys.argv[1:] if argv is None else argv), flush=True)
    if load:
        print(f"load average at start: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}", flush=True)

    ok, info = irsim_available(args.irsim_python)
    if ok:
        print(f"ir-sim {info} in {args.irsim_python}", flush=True)
    else:
        print(f"ir-sim: not available: {info}; install it with: {INSTALL_HINT} "
              "(then --irsim-python /some/venv/bin/python)", flush=True)  # fmt: skip

    labels = {
        "fleetsim": "fleetsim Navigate-v0 (lidar noise on)",
        "irsim": f"ir-sim {info} (step_time {STEP_S} s, 360-beam lidar, noise on)" if ok else "ir-sim",
        "vector": "fleetsim Navigate-v0, make_vec async, 2 envs (per env step)",
    }
    results: dict[str, list[dict[str, Any]]] = {"fleetsim": [], "irsim": [], "vector": []}
    for i in range(args.runs):
        seed = args.seed + i
        results["fleetsim"].append(run_fleetsim(args.seconds, seed))
        print(run_line("fleetsim", i, args.runs, results["fleetsim"][-1]), flush=True)
        if ok:
            r = run_irsim(args.irsim_python, args.seconds, seed)
            results["irsim"].append(r)
            print(run_line("ir-sim", i, args.runs, r), flush=True)
            if abs(float(r["step_time"]) - STEP_S) > 1e-9 or r["beams"] != 360:
                print(f"  note: ir-sim ran step_time {r['step_time']} s with {r['beams']} beams", flush=True)
        if not args.no_vec:
            results["vector"].append(run_vector(args.seconds, seed))
            print(run_line("fleetsim, 2 envs async", i, args.runs, results["vector"][-1]), flush=True)

    print()
    print("\n".join(table(results, labels)))
    ours = statistics.median(rate(r) for r in results["fleetsim"])
    print(f"\nfleetsim: {ours:.0f} steps/s (median), {ours * STEP_S:.0f} sim seconds a wall second")
    if results["irsim"]:
        theirs = statistics.median(rate(r) for r in results["irsim"])
        r0 = results["irsim"][0]
        print(f"ir-sim:   {theirs:.0f} steps/s (median), {theirs * STEP_S:.0f} sim seconds a wall second "
              f"(Python {r0['python']}, numpy {r0['numpy']}, shapely {r0['shapely']})")  # fmt: skip
        print(f"ratio of the medians, fleetsim / ir-sim: {ours / theirs:.1f}x (the issue asks for at least 10x)")
        per_cpu = statistics.median(cpu_rate(r) for r in results["fleetsim"]) / statistics.median(
            cpu_rate(r) for r in results["irsim"]
        )
        print(f"ratio of the medians of steps a CPU second: {per_cpu:.1f}x")
    if hasattr(os, "getloadavg"):
        load = list(os.getloadavg())
        print(f"load average at the end: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    return 0


def _uncommitted(*paths: str) -> str:
    """The given folders with uncommitted changes to tracked files, as 'learn/, simd/' ('' if none)."""
    with contextlib.suppress(OSError, subprocess.SubprocessError):
        r = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no", "--", *paths],
            cwd=ROOT, capture_output=True, text=True, timeout=5,
        )  # fmt: skip
        changed = {Path(line[3:]).parts[0] for line in r.stdout.splitlines() if len(line) > 3}
        return ", ".join(f"{p}/" for p in sorted(changed))
    return ""


if __name__ == "__main__":
    sys.exit(main())
