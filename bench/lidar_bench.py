"""Micro-benchmark of the lidar kernels of simd.core.lidar (not collected by pytest).

Times one tick's batch of sensors (167 = 1 000 robots x 5 Hz / 30 Hz) for the numpy kernel
(``cast_numpy``, the reference), the compiled kernel (``cast_native``, simd/core/lidar/_raycast.c, when it is
built) and a naive numpy reference (every beam x every primitive within range), all in the same
process, and checks that they agree: native and numpy bit for bit, numpy and naive to 1e-4 m.
Native and numpy calls are interleaved batch by batch, so that a slower spell of a shared
machine hits both alike; the ratios are of the medians.

Two worlds of burger outlines (12 edges each) at their poses:

* ``random`` (default): a 60x60 m arena (walls, 25 boxes, 40 pillars) with the robots at random
  free poses, so the density of robots grows with their number;
* ``arena``: the fleet benchmark's world (bench/arena.py): robots on a 2 m grid with pillars
  between them, walls and pens, so that every robot sees ~8 neighbours whatever the fleet size.

    python -m bench.lidar_bench [--world random|arena] [--robots 1000] [--sensors 167]
                                [--repeats 21] [--naive-repeats 3] [--profile]
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import numpy.typing as npt

from fleetcommon.arrays import F64

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from simd.core import lidar
from simd.core.lidar import LidarSpec, StaticScene, cast_native, cast_numpy
from simd.core.models import BURGER as BURGER_MODEL
from simd.core.worldfile import world_from_dict

ARENA = 60.0
# the burger footprint outline (12 vertices), as the simulator uses it
BURGER = BURGER_MODEL.outline
LIDAR_OFFSET = (-0.032, 0.0)


def box_segments(cx: float, cy: float, w: float, h: float) -> F64:
    x0, x1, y0, y1 = cx - w / 2, cx + w / 2, cy - h / 2, cy + h / 2
    pts = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    return np.array([(*pts[i], *pts[(i + 1) % 4]) for i in range(4)])


World = tuple[StaticScene, F64, F64, F64, F64, npt.NDArray[np.int64]]


def outlines(pose: F64) -> tuple[F64, npt.NDArray[np.int64]]:
    """Burger outlines at the poses (x, y, yaw), as (12 N, 4) segments, and their robot ids."""
    c, s = np.cos(pose[:, 2])[:, None], np.sin(pose[:, 2])[:, None]
    wx = pose[:, 0:1] + BURGER[:, 0] * c - BURGER[:, 1] * s
    wy = pose[:, 1:2] + BURGER[:, 0] * s + BURGER[:, 1] * c
    dyn = np.stack([wx, wy, np.roll(wx, -1, axis=1), np.roll(wy, -1, axis=1)], axis=2)
    ids = np.repeat(np.arange(len(pose), dtype=np.int64), len(BURGER))
    return dyn.reshape(-1, 4), ids


def build_arena(robots: int) -> World:
    """The fleet benchmark's world and spawn poses (bench/arena.py)."""
    from bench.arena import make_arena

    arena = make_arena(robots)
    geometry = world_from_dict(arena.world)
    segments, circles = geometry.segments(), geometry.circles
    pose = np.array(arena.poses, dtype=np.float64)
    dyn, ids = outlines(pose)
    return StaticScene(segments, circles, 3.5), segments, circles, pose, dyn, ids


def build_world(robots: int, seed: int = 1) -> World:
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
    dyn, ids = outlines(pose)
    return scene, segments, circles, pose, dyn, ids


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


Kernel = Callable[[npt.NDArray[np.int64]], npt.NDArray[np.float32]]


def timed(fn: Kernel, batches: list[npt.NDArray[np.int64]], repeats: int) -> dict[str, list[float]]:
    """Wall and CPU seconds of each call over rotating batches."""
    wall: list[float] = []
    cpu: list[float] = []
    for r in range(repeats):
        rows = batches[r % len(batches)]
        t, c = time.perf_counter(), time.process_time()
        fn(rows)
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return {"wall": wall, "cpu": cpu}


def interleaved(
    fns: dict[str, Kernel], batches: list[npt.NDArray[np.int64]], repeats: int
) -> dict[str, dict[str, list[float]]]:
    """Like ``timed`` for several kernels, alternating them call by call (the order flips each
    round) so that a slower spell of the machine costs them alike."""
    out: dict[str, dict[str, list[float]]] = {name: {"wall": [], "cpu": []} for name in fns}
    names = list(fns)
    for r in range(repeats):
        rows = batches[r % len(batches)]
        for name in names if r % 2 == 0 else names[::-1]:
            t, c = time.perf_counter(), time.process_time()
            fns[name](rows)
            out[name]["wall"].append(time.perf_counter() - t)
            out[name]["cpu"].append(time.process_time() - c)
    return out


def report(name: str, t: dict[str, list[float]], sensors: int, samples: int) -> float:
    """Print one kernel's line; returns its median wall time (ms)."""
    med = statistics.median(t["wall"]) * 1e3
    p10 = float(np.percentile(t["wall"], 10)) * 1e3
    cpu = statistics.median(t["cpu"]) * 1e3
    beams = sensors * samples
    print(
        f"{name:7s}: median {med:7.3f} ms (p10 {p10:.3f}, CPU {cpu:.3f}) per batch of {sensors}; "
        f"{beams / med * 1e3 / 1e6:6.2f} M beams/s; {med / (1e3 / 30):.1%} of a 30 Hz tick"
    )
    return med


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--world", choices=["random", "arena"], default="random")
    ap.add_argument("--robots", type=int, default=1000)
    ap.add_argument("--sensors", type=int, default=167)
    ap.add_argument("--repeats", type=int, default=21)
    ap.add_argument("--naive-repeats", type=int, default=3)
    ap.add_argument("--profile", action="store_true", help="cProfile the numpy kernel")
    args = ap.parse_args(argv)
    for flag in ("robots", "sensors", "repeats", "naive_repeats"):
        if getattr(args, flag) < 1:
            ap.error(f"--{flag.replace('_', '-')} must be at least 1")

    spec = LidarSpec()
    t0 = time.perf_counter()
    build = build_arena if args.world == "arena" else build_world
    scene, segments, circles, pose, dyn, ids = build(args.robots)
    print(
        f"world {args.world}: {args.robots} robots, {len(dyn)} dynamic segments, {len(segments)} static "
        f"segments, {len(circles)} circles; built in {time.perf_counter() - t0:.2f} s"
    )
    native = lidar.NATIVE_UNAVAILABLE is None
    print(f"lidar.KERNEL = {lidar.KERNEL!r}" + ("" if native else f" ({lidar.NATIVE_UNAVAILABLE})"))
    rng = np.random.default_rng(7)
    batches = [rng.choice(args.robots, size=args.sensors, replace=False) for _ in range(16)]

    def run_numpy(rows: npt.NDArray[np.int64]) -> npt.NDArray[np.float32]:
        o, h = sensors(pose, rows)
        return cast_numpy(scene, spec, o, h, rows.astype(np.int64), dyn, ids)

    def run_native(rows: npt.NDArray[np.int64]) -> npt.NDArray[np.float32]:
        o, h = sensors(pose, rows)
        return cast_native(scene, spec, o, h, rows.astype(np.int64), dyn, ids)

    def run_naive(rows: npt.NDArray[np.int64]) -> npt.NDArray[np.float32]:
        o, h = sensors(pose, rows)
        return naive_cast(spec, segments, circles, o, h, rows.astype(np.int64), dyn, ids)

    # agreement on the first batches
    got, ref = run_numpy(batches[0]), run_naive(batches[0])
    same_inf = np.array_equal(np.isinf(got), np.isinf(ref))
    fin = np.isfinite(got) & np.isfinite(ref)
    err = float(np.max(np.abs(got[fin] - ref[fin]))) if fin.any() else 0.0
    print(f"numpy vs naive: same +inf beams {same_inf}, max |diff| {err:.2e} m, hits {int(fin.sum())}/{got.size}")
    if native:
        differ = sum(int(np.count_nonzero(run_native(b) != run_numpy(b))) for b in batches)
        print(f"native vs numpy: {differ} of {len(batches) * got.size} beams differ (bitwise, 16 batches)")

    kernels: dict[str, Kernel] = {"numpy": run_numpy}
    if native:
        kernels["native"] = run_native
    for fn in kernels.values():
        fn(batches[1])  # warm-up
    times = interleaved(kernels, batches, args.repeats)
    naive = timed(run_naive, batches, args.naive_repeats)
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs (timings are wall clock)")
    med = {name: report(name, t, args.sensors, spec.samples) for name, t in times.items()}
    med["naive"] = report("naive", naive, args.sensors, spec.samples)
    print(f"numpy  speed-up vs naive: {med['naive'] / med['numpy']:.1f}x")
    if native:
        print(
            f"native speed-up vs numpy: {med['numpy'] / med['native']:.1f}x, "
            f"vs naive: {med['naive'] / med['native']:.0f}x"
        )

    if args.profile:
        prof = cProfile.Profile()
        prof.enable()
        for r in range(20):
            run_numpy(batches[r % len(batches)])
        prof.disable()
        pstats.Stats(prof).sort_stats("tottime").print_stats(25)


if __name__ == "__main__":
    main()
