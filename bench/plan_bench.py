"""How fast the grid planner (simd/nav/grid_search.py) plans, compiled and in Python.

    python -m bench.plan_bench [--size 400] [--blocked 0.2] [--pairs 50] [--seed 0]

A size x size grid with ``--blocked`` of its cells blocked at random and the others costing
uniform floats in [1, 5]; ``--pairs`` start/goal pairs drawn among the free cells, each goal
among the cells its start reaches (``reachable``), so that every plan finds its path. Each
pair is planned by both twins in turn (a slower spell of a shared machine hits both alike),
their paths must be the same array, and the medians and their ratio are printed, with the
median time ``smooth`` takes for those paths and for a 2000-point one. Numbers are printed, not checked: they belong in
grid_search.py's docstring, with the machine they were measured on.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np

from simd.nav.grid_search import NATIVE_UNAVAILABLE, plan_native, plan_python, reachable, smooth


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--size", type=int, default=400, help="cells a side (default 400)")
    parser.add_argument("--blocked", type=float, default=0.2, help="share of blocked cells (default 0.2)")
    parser.add_argument("--pairs", type=int, default=50, help="start/goal pairs (default 50)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if NATIVE_UNAVAILABLE is not None:
        print(f"plan_bench: the compiled planner is not used ({NATIVE_UNAVAILABLE}); build it first", file=sys.stderr)
        return 1

    rng = np.random.default_rng(args.seed)
    cost = rng.uniform(1.0, 5.0, (args.size, args.size)).astype(np.float32)
    cost[rng.random(cost.shape) < args.blocked] = np.inf
    free = np.isfinite(cost)
    cells = np.argwhere(free)
    times: dict[str, list[float]] = {"compiled": [], "python": [], "smooth": []}
    lengths, kept = [], []
    for _ in range(args.pairs):
        sr, sc = cells[rng.integers(len(cells))].tolist()
        goals = np.argwhere(reachable(free, (sr, sc)))
        gr, gc = goals[rng.integers(len(goals))].tolist()
        paths = {}
        for name, planner in (("compiled", plan_native), ("python", plan_python)):
            t0 = time.perf_counter()
            paths[name] = planner(cost, (sr, sc), (gr, gc))
            times[name].append(time.perf_counter() - t0)
        path = paths["compiled"]
        if path is None or paths["python"] is None or not np.array_equal(path, paths["python"]):
            raise RuntimeError(f"the twins differ from {(sr, sc)} to {(gr, gc)}")
        t0 = time.perf_counter()
        kept.append(len(smooth(free, path)))
        times["smooth"].append(time.perf_counter() - t0)
        lengths.append(len(path))

    ms = {name: 1e3 * statistics.median(values) for name, values in times.items()}
    print(f"grid {args.size}x{args.size}, {free.mean():.0%} free, costs in [1, 5], {args.pairs} reachable pairs")
    print(f"path length: median {statistics.median(lengths):.0f} cells (max {max(lengths)})")
    print(f"plan, compiled: median {ms['compiled']:.2f} ms (max {1e3 * max(times['compiled']):.2f})")
    print(f"plan, python:   median {ms['python']:.2f} ms (max {1e3 * max(times['python']):.2f})")
    print(f"python / compiled: {ms['python'] / ms['compiled']:.1f}x")
    print(f"smooth: median {ms['smooth']:.2f} ms ({statistics.median(kept):.0f} points kept)")
    long_path_smoothing(rng)
    return 0


def long_path_smoothing(rng: np.random.Generator, points: int = 2000, repeats: int = 15) -> None:
    """The median time ``smooth`` takes for the first ``points`` points of a corner-to-corner
    path across a 1400x1400 grid blocked as the one above."""
    side = 1400
    cost = rng.uniform(1.0, 5.0, (side, side)).astype(np.float32)
    cost[rng.random(cost.shape) < 0.2] = np.inf
    cost[0, 0] = cost[-1, -1] = 1.0
    free = np.isfinite(cost)
    path = plan_native(cost, (0, 0), (side - 1, side - 1))
    if path is None or len(path) < points:
        print("smooth of a long path: no long path on this grid (another --seed?)")
        return
    path = path[:points]
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        kept = smooth(free, path)
        times.append(time.perf_counter() - t0)
    print(f"smooth of a {points}-point path: median {1e3 * statistics.median(times):.2f} ms ({len(kept)} points kept)")


if __name__ == "__main__":
    sys.exit(main())
