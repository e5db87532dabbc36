"""How well and how fast fleet-map maps a world, against the world's true geometry.

    python -m bench.map_bench                                  # turtlebot3_world and _house, 1 and 4 robots
    python -m bench.map_bench --worlds turtlebot3_world --robots 1
    python -m bench.map_bench --worlds turtlebot3_house --odom-noise 0.05 --seeds 0 1 2 [--no-loops]

For each world, robot count and odometry noise it starts ``simd --lockstep --no-noise
--odom-noise F``, spawns the robots,
runs ``fleet-map --explore`` (which steps the daemon itself; with ``--match`` when F > 0, loop
closure included unless ``--no-loops``) and scores the saved map:

- **precision**: the share of occupied cells within one cell (1.5 cells between centres and a
  wall surface) of a true wall, pillar or block;
- **recall**: the share of true wall cells (cells a true obstacle covers, next to free space the
  robots could reach from their spawn) that have an occupied cell of the map within one cell;
- **coverage**: the share of that reachable free space the map holds as free;
- the sim seconds and wall seconds exploration took, and the grid's own speed (scans fused a
  second, to compare with 100 robots' 500 a second).

Every run is printed as it ends and the table at the end; ``--out`` also writes it as JSON.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.processes import free_port

ROOT = Path(__file__).resolve().parent.parent
#: spawn poses per world: the TurtleBot3 launches' (four-robot launch for turtlebot3_world)
POSES = {
    "turtlebot3_world": [(-2.0, -0.5), (0.5, -2.0), (2.0, 0.5), (-0.5, 2.0)],
    "turtlebot3_house": [(-2.0, -0.5), (6.0, 1.0), (1.0, -3.0), (-1.0, 3.0)],  # the launch's, then spread out
}


def run(world_name: str, robots: int, limit: float, tmp: Path, odom_noise: float = 0.0,
        loops: bool = True, seed: int = 0) -> dict[str, Any]:  # fmt: skip
    from clients.api import FleetClient
    from clients.mapping.evaluate import score
    from fleetcommon.mapfile import read_map

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    log = (tmp / f"simd-{world_name}-{robots}.log").open("w")
    daemon = subprocess.Popen(
        [sys.executable, "-m", "simd.cli", "--world", world_name, "--lockstep", "--no-noise", "-l", endpoint,
         "--odom-noise", str(odom_noise), "--seed", str(seed)],
        stdout=log, stderr=subprocess.STDOUT, cwd=ROOT,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 20
        while True:
            try:
                client = FleetClient(endpoint, timeout=1.0)
                client.clock()
                break
            except Exception:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.1)
        poses = POSES[world_name][:robots]
        for i, (x, y) in enumerate(poses):
            client.spawn(f"tb3_{i}", x, y)
        world = client.world()
        stem = tmp / f"{world_name}-{robots}-{odom_noise:g}-{seed}"
        t0 = time.monotonic()
        p = subprocess.run(
            [sys.executable, "-m", "clients.mapping.cli", "-e", endpoint, "-o", str(stem), "--explore",
             "--explore-limit", str(limit), *(["--match"] if odom_noise > 0 else []),
             *(["--no-loops"] if odom_noise > 0 and not loops else [])],
            capture_output=True, text=True, cwd=ROOT, timeout=900,
        )  # fmt: skip
        wall = time.monotonic() - t0
        if p.returncode != 0:
            raise RuntimeError(p.stderr[-2000:])
        sim = client.clock().tick / 30.0
        m = re.search(r"(\d+) scans from", p.stdout)
        scores = score(read_map(stem.with_name(stem.name + ".yaml")), world, poses)
        closing = re.search(r"loop closure: keyframes (\d+), closures (\d+), optimisations (\d+), redraws (\d+)",
                            p.stdout)  # fmt: skip
        out = {"world": world_name, "robots": robots, "odom_noise": odom_noise, "seed": seed, "sim_s": sim,
               "wall_s": wall,
               "scans": int(m.group(1)) if m else None, **scores,
               "loops": dict(zip(("keyframes", "closures", "optimisations", "redraws"),
                                 map(int, closing.groups()), strict=True)) if closing else None}  # fmt: skip
        client.close()
        return out
    finally:
        daemon.terminate()
        daemon.wait(10)
        log.close()


def grid_speed(seconds: float = 2.0) -> float:
    """Scans a second the grid fuses (360 beams, 3.5 m, in turtlebot3_world's extent)."""
    from clients.mapping.grid import Beams, LogOddsGrid

    g = LogOddsGrid((-4.0, 5.3, -4.1, 4.1), 0.05)
    beams = Beams(0.0, 6.28 / 359, 360, 0.12, 3.5)
    rng = np.random.default_rng(1)
    ranges = rng.uniform(0.3, 3.5, 360).astype(np.float32)
    ranges[rng.random(360) < 0.2] = np.inf
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        g.integrate(float(rng.uniform(-2, 2)), float(rng.uniform(-2, 2)), float(rng.uniform(-3, 3)), ranges, beams)
        n += 1
    return n / (time.perf_counter() - t0)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--worlds", nargs="+", default=["turtlebot3_world", "turtlebot3_house"], choices=sorted(POSES))
    ap.add_argument("--robots", nargs="+", type=int, default=[1, 4], choices=(1, 2, 3, 4))
    ap.add_argument("--limit", type=float, default=300.0, help="sim seconds of exploration at most (300)")
    ap.add_argument(
        "--odom-noise", nargs="+", type=float, default=[0.0, 0.05], help="simd --odom-noise values (0 and 0.05)"
    )
    ap.add_argument("--no-loops", action="store_true", help="scan matching without loop closure (fleet-map --no-loops)")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0], help="simd --seed values: other wheel slip draws (0)")
    ap.add_argument("--out", help="also write the results as JSON here")
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="map-bench-") as tmp:
        for world in args.worlds:
            for n in args.robots:
                for noise, seed in ((noise, seed) for noise in args.odom_noise for seed in args.seeds):
                    r = run(world, n, args.limit, Path(tmp), noise, not args.no_loops, seed)
                    rows.append(r)
                    quality = f"precision {r['precision']:.3f}, recall {r['recall']:.3f}, coverage {r['coverage']:.3f}"
                    closing = f"; loop closure {r['loops']}" if r["loops"] else ""
                    seeded = f" (seed {seed})" if seed else ""
                    print(f"{world}, {n} robot(s), odom noise {noise:g}{seeded}: {r['sim_s']:.0f} s sim, "
                          f"{r['wall_s']:.1f} s wall; {quality}{closing}", flush=True)  # fmt: skip
    speed = grid_speed()
    print()
    print("| world | robots | odometry noise | sim s | wall s | precision | recall | free space covered |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        seeded = f" (seed {r['seed']})" if r["seed"] else ""
        print(f"| {r['world']} | {r['robots']} | {r['odom_noise']:g}{seeded} | {r['sim_s']:.0f} | {r['wall_s']:.1f} "
              f"| {r['precision']:.3f} | {r['recall']:.3f} | {r['coverage']:.3f} |")  # fmt: skip
    print(f"\ngrid: {speed:.0f} scans fused a second on one core (100 robots send 500 a second)")
    if args.out:
        Path(args.out).write_text(json.dumps({"runs": rows, "grid_scans_per_s": speed}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
