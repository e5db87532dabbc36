"""Micro-benchmark of simd.lidar.cast (not collected by pytest).

Builds a 60x60 m arena (walls, pillars, boxes) with 1 000 burger outlines (12 edges each) at
random free poses, then times one tick's batch of sensors (167 = 1 000 robots x 5 Hz / 30 Hz)
for ``cast`` and for a naive numpy reference (every beam x every primitive within range) run in
the same process, and checks that both agree.

    python tests/bench_lidar.py [--robots 1000] [--sensors 167] [--repeats 9] [--profile]
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import resource
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import numpy.typing as npt

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from simd.lidar import LidarSpec, StaticScene, cast
from simd.models import BURGER as BURGER_MODEL

F64 = npt.NDArray[np.float64]

ARENA = 60.0
# the burger footprint outline (12 vertices), as the simulator uses it
BURGER = BURGER_MODEL.outline
LIDAR_OFFSET = (-0.032, 0.0)


def box_segments(cx: float, cy: float, w: float, h: float) -> F64:
    x0, x1, y0, y1 = cx - w / 2, cx + w / 2, cy - h / 2, cy + h / 2
    pts = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    return np.array([(*pts[i], *pts[(i + 1) % 4]) for i in range(4)])


def build_world(robots: int, seed: int = 1) -> tuple[StaticScene, F64, F64, F64, F64, npt.NDArray[np.int64]]:
    """Arena and robots: scene, static segments, circles, robot poses (x, y, yaw), outlines, ids."""
    rng = np.random.default_rng(seed)
    segs = [box_segments(ARENA / 2, ARENA / 2, ARENA, ARENA)]
    boxes = rng.uniform(3, ARENA - 3, size=(25, 2))
    for bx, by in boxes:
        segs.append(box_segments(bx, by, rng.uniform(0.4, 2.0), rng.uniform(0.4, 2.0)))
    segments = np.concatenate(segs)
    circles = np.column_stack([rng.uniform(3, ARENA - 3, size=(40, 2)), rng.uniform(0.1, 0.4, 40)])
    scene = StaticScene(segments, circles, 3.5)

    # random free poses: rejection sampling against obstacles and earlier robots
    poses: list[tuple[float, float, float]] = []
    placed = np.zeros((0, 2))
    while len(poses) < robots:
        x, y = rng.uniform(0.5, ARENA - 0.5, size=2)
        if np.any(np.hypot(circles[:, 0] - x, circles[:, 1] - y) < circles[:, 2] + 0.2):
            continue
        if np.any(np.max(np.abs(boxes - (x, y)), axis=1) < 1.25):
            continue
        if len(placed) and np.min(np.hypot(*(placed - (x, y)).T)) < 0.35:
            continue
        poses.append((x, y, rng.uniform(-np.pi, np.pi)))
        placed = np.vstack([placed, (x, y)])
    pose = np.array(poses)
    c, s = np.cos(pose[:, 2])[:, None], np.sin(pose[:, 2])[:, None]
    wx = pose[:, 0:1] + BURGER[:, 0] * c - BURGER[:, 1] * s
    wy = pose[:, 1:2] + BURGER[:, 0] * s + BURGER[:, 1] * c
    dyn = np.stack([wx, wy, np.roll(wx, -1, axis=1), np.roll(wy, -1, axis=1)], axis=2)
    ids = np.repeat(np.arange(robots, dtype=np.int64), len(BURGER))
    return scene, segments, circles, pose, dyn.reshape(-1, 4), ids


def sensors(pose: F64, rows: npt.NDArray[np.int64]) -> tuple[F64, F64]:
    x, y, yaw = pose[rows].T
    ox = x + LIDAR_OFFSET[0] * np.cos(yaw) - LIDAR_OFFSET[1] * np.sin(yaw)
    oy = y + LIDAR_OFFSET[0] * np.sin(yaw) + LIDAR_OFFSET[1] * np.cos(yaw)
    return np.column_stack([ox, oy]), yaw


def naive_cast(
    spec: LidarSpec,
    segments: F64,
    circles: F64,
    origins: F64,
    headings: F64,
    sensor_owner: npt.NDArray[np.int64],
    dyn: F64,
    dyn_owner: npt.NDArray[np.int64],
) -> npt.NDArray[np.float32]:
    """Every beam against every primitive within range_max, vectorised per sensor."""
    rmin, rmax = spec.range_min, spec.range_max
    out = np.full((len(origins), spec.samples), np.inf)
    all_seg = np.concatenate([segments, dyn])
    all_owner = np.concatenate([np.full(len(segments), -1, dtype=np.int64), dyn_owner])
    a = all_seg[:, :2]
    e = all_seg[:, 2:] - a
    ee = np.einsum("ij,ij->i", e, e)
    rel = spec.angles()
    for i, (o, h) in enumerate(zip(origins, headings, strict=True)):
        w = o - a
        u = np.clip(np.einsum("ij,ij->i", w, e) / ee, 0.0, 1.0)
        d = np.hypot(*(w - u[:, None] * e).T)
        sel = np.flatnonzero((d <= rmax) & (all_owner != sensor_owner[i]))
        dirs = np.column_stack([np.cos(h + rel), np.sin(h + rel)])  # (B, 2)
        p = a[sel] - o  # (K, 2)
        ek = e[sel]
        with np.errstate(divide="ignore", invalid="ignore"):
            den = dirs[:, None, 0] * ek[None, :, 1] - dirs[:, None, 1] * ek[None, :, 0]
            t = (p[None, :, 0] * ek[None, :, 1] - p[None, :, 1] * ek[None, :, 0]) / den
            s = (p[None, :, 0] * dirs[:, None, 1] - p[None, :, 1] * dirs[:, None, 0]) / den
        ok = (t >= rmin) & (t <= rmax) & (s >= 0.0) & (s <= 1.0)
        best = np.where(ok, t, np.inf).min(axis=1, initial=np.inf)
        f = o - circles[:, :2]
        fd = np.hypot(*f.T)
        csel = np.flatnonzero(np.abs(fd - circles[:, 2]) <= rmax)
        fc = f[csel]
        b = dirs @ fc.T  # (B, C)
        cc = np.einsum("ij,ij->i", fc, fc) - circles[csel, 2] ** 2
        disc = b * b - cc[None, :]
        root = np.sqrt(np.maximum(disc, 0.0))
        tc = np.where(-b - root >= rmin, -b - root, -b + root)
        okc = (disc >= 0) & (tc >= rmin) & (tc <= rmax)
        best = np.minimum(best, np.where(okc, tc, np.inf).min(axis=1, initial=np.inf))
        out[i] = best
    return out.astype(np.float32)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, default=1000)
    ap.add_argument("--sensors", type=int, default=167)
    ap.add_argument("--repeats", type=int, default=21)
    ap.add_argument("--naive-repeats", type=int, default=3)
    ap.add_argument("--profile", action="store_true", help="cProfile the fast kernel")
    args = ap.parse_args()

    spec = LidarSpec()
    t0 = time.perf_counter()
    scene, segments, circles, pose, dyn, ids = build_world(args.robots)
    print(
        f"world: {args.robots} robots, {len(dyn)} dynamic segments, {len(segments)} static "
        f"segments, {len(circles)} circles; built in {time.perf_counter() - t0:.2f} s"
    )
    rng = np.random.default_rng(7)
    batches = [rng.choice(args.robots, size=args.sensors, replace=False) for _ in range(16)]

    def run_fast(rows: npt.NDArray[np.int64]) -> npt.NDArray[np.float32]:
        o, h = sensors(pose, rows)
        return cast(scene, spec, o, h, rows.astype(np.int64), dyn, ids)

    def run_naive(rows: npt.NDArray[np.int64]) -> npt.NDArray[np.float32]:
        o, h = sensors(pose, rows)
        return naive_cast(spec, segments, circles, o, h, rows.astype(np.int64), dyn, ids)

    # agreement on the first batch
    got, ref = run_fast(batches[0]), run_naive(batches[0])
    same_inf = np.array_equal(np.isinf(got), np.isinf(ref))
    fin = np.isfinite(got) & np.isfinite(ref)
    err = float(np.max(np.abs(got[fin] - ref[fin]))) if fin.any() else 0.0
    print(f"agreement with naive: same +inf beams {same_inf}, max |diff| {err:.2e} m, hits {int(fin.sum())}/{got.size}")

    run_fast(batches[1])  # warm-up

    def timed(fn: Callable[[npt.NDArray[np.int64]], object], repeats: int) -> dict[str, float]:
        """Wall/CPU times (ms) and minor page faults per call over rotating batches."""
        wall, cpu = [], []
        faults0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        for r in range(repeats):
            rows = batches[r % len(batches)]
            t, c = time.perf_counter(), time.process_time()
            fn(rows)
            wall.append(time.perf_counter() - t)
            cpu.append(time.process_time() - c)
        faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults0
        return {
            "med": statistics.median(wall) * 1e3,
            "p10": float(np.percentile(wall, 10)) * 1e3,
            "cpu": statistics.median(cpu) * 1e3,
            "faults": faults / repeats,
        }

    fast = timed(run_fast, args.repeats)
    naive = timed(run_naive, args.naive_repeats)
    beams = args.sensors * spec.samples
    tick_ms = 1e3 / 30
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs (timings are wall clock)")
    print(
        f"cast : median {fast['med']:6.2f} ms (p10 {fast['p10']:.2f}, CPU {fast['cpu']:.2f}) per batch of "
        f"{args.sensors}; {beams / fast['med'] * 1e3 / 1e6:.2f} M beams/s; {fast['med'] / tick_ms:.0%} of a "
        f"30 Hz tick; {fast['faults']:.0f} page faults/call"
    )
    print(
        f"naive: median {naive['med']:6.2f} ms (CPU {naive['cpu']:.2f}) per batch; "
        f"{beams / naive['med'] * 1e3 / 1e6:.2f} M beams/s"
    )
    print(f"speed-up vs naive: {naive['med'] / fast['med']:.1f}x")

    if args.profile:
        prof = cProfile.Profile()
        prof.enable()
        for r in range(20):
            run_fast(batches[r % len(batches)])
        prof.disable()
        pstats.Stats(prof).sort_stats("tottime").print_stats(25)


if __name__ == "__main__":
    main()
