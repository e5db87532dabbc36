"""How fast the cell graph's distance fields (simd/nav/cells.py's ``dijkstra``) are worked out,
compiled and in Python.

    python -m bench.cells_bench [--width 134] [--height 123] [--blocked 0.3] [--goals 50] [--seed 0]

Two floors of ``--width`` x ``--height`` cells (the defaults are the 1 000-robot warehouse's):
``--blocked`` of the cells blocked at random, and the 1 000-robot warehouse map
(worlds/warehouse.py) when that is the size asked for. The moves are those CellGraph allows
between free cells (a diagonal only past two free side cells), the cell 0.35 m (a burger's):
the eight moves, and the sixteen CellGraph.distances searches (``with_knights`` of the eight).
Each floor gets ``--goals`` goals drawn among its free cells; each goal is searched over both
move sets by both twins in turn (a slower spell of a shared machine hits all four alike),
their arrays must be the same bit for bit, and the medians and their ratio are printed.
Numbers are printed, not checked: they belong in cells.py's docstring, with the machine they
were measured on.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np
import numpy.typing as npt

from simd.nav.cells import MOVES, NATIVE_UNAVAILABLE, dijkstra_native, dijkstra_python, with_knights
from worlds.warehouse import warehouse_for_robots

CELL_M = 0.35


def moves_of(free: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """(cells, 8): both ends free, and for a diagonal both side cells."""
    rows, cols = free.shape
    padded = np.zeros((rows + 2, cols + 2), dtype=bool)
    padded[1:-1, 1:-1] = free
    out = np.zeros((rows, cols, len(MOVES)), dtype=bool)
    for k, (dr, dc) in enumerate(MOVES):
        ok = free & padded[1 + dr : 1 + dr + rows, 1 + dc : 1 + dc + cols]
        if dr and dc:
            ok &= padded[1 + dr : 1 + dr + rows, 1 : 1 + cols] & padded[1 : 1 + rows, 1 + dc : 1 + dc + cols]
        out[:, :, k] = ok
    return out.reshape(rows * cols, len(MOVES))


def measure(name: str, free: npt.NDArray[np.bool_], goals: int, rng: np.random.Generator) -> None:
    eight = moves_of(free)
    width = free.shape[1]
    move_sets = {"8 moves": eight, "16 moves": with_knights(eight, width)}
    twins = (("compiled", dijkstra_native), ("python", dijkstra_python))
    times: dict[tuple[str, str], list[float]] = {(kind, twin): [] for kind in move_sets for twin, _ in twins}
    reached = []
    for goal in rng.choice(np.flatnonzero(free), goals).tolist():
        for kind, moves in move_sets.items():
            fields = {}
            for twin, search in twins:
                t0 = time.perf_counter()
                fields[twin] = search(moves, width, goal, CELL_M)
                times[kind, twin].append(time.perf_counter() - t0)
            if not np.array_equal(fields["compiled"], fields["python"]):
                raise RuntimeError(f"the twins differ for goal {goal} over {kind} on the {name}")
        reached.append(int(np.isfinite(fields["compiled"]).sum()))
    print(f"{name}: {free.shape[1]}x{free.shape[0]} cells, {free.mean():.0%} free, {goals} goals, "
          f"median {statistics.median(reached):.0f} cells reached")  # fmt: skip
    for kind in move_sets:
        ms = {twin: 1e3 * statistics.median(times[kind, twin]) for twin, _ in twins}
        worst = {twin: 1e3 * max(times[kind, twin]) for twin, _ in twins}
        print(f"  {kind}:")
        print(f"    compiled: median {ms['compiled']:.3f} ms (max {worst['compiled']:.3f})")
        print(f"    python:   median {ms['python']:.2f} ms (max {worst['python']:.2f})")
        print(f"    python / compiled: {ms['python'] / ms['compiled']:.0f}x")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--width", type=int, default=134, help="cells a row (default 134)")
    parser.add_argument("--height", type=int, default=123, help="rows (default 123)")
    parser.add_argument("--blocked", type=float, default=0.3, help="share of blocked cells (default 0.3)")
    parser.add_argument("--goals", type=int, default=50, help="goals a floor (default 50)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if NATIVE_UNAVAILABLE is not None:
        print(f"cells_bench: the compiled search is not used ({NATIVE_UNAVAILABLE}); build it first", file=sys.stderr)
        return 1
    rng = np.random.default_rng(args.seed)
    measure("random floor", rng.random((args.height, args.width)) >= args.blocked, args.goals, rng)
    rows = warehouse_for_robots(1000, seed=args.seed).splitlines()[4:]
    if (len(rows), len(rows[0])) == (args.height, args.width):
        free = np.array([[ch == "." for ch in row] for row in rows])
        measure("1 000-robot warehouse", free, args.goals, rng)
    return 0


if __name__ == "__main__":
    sys.exit(main())
