"""Meetings: robots that wait for each other in a circle, and where one of them can make way.

Each waiting robot waits for one other (the holder of the next cell it needs,
simd/nav/traffic.py), so the waits form a graph in which every robot has at most one
outgoing edge; its cycles are the deadlocks. Two robots meeting head on in a corridor one
robot wide are a cycle of two; four robots around a block, a cycle of four.

Making way: the robot plans to the nearest place from which it blocks none of the others'
remaining ways (their claimed cells and the cells their paths still need), moving only
through cells that nobody else holds. In a corridor that is back out of it, past the
corridor's mouth and to one side.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import numpy.typing as npt

from simd.nav.traffic import FREE, Traffic

I64 = npt.NDArray[np.int64]
B = npt.NDArray[np.bool_]

#: how far (m) a robot looks for a place to make way from
REFUGE_REACH_M = 8.0


def wait_cycles(waits: Mapping[int, int]) -> list[list[int]]:
    """The cycles of the wait-for graph ``waits`` (slot -> the slot it waits for), each once,
    in a deterministic order (by the smallest slot that leads into it)."""
    seen: dict[int, int] = {}  # slot -> the walk it was first met on
    cycles: list[list[int]] = []
    for start in sorted(waits):
        if start in seen:
            continue
        walk: list[int] = []
        node: int | None = start
        while node is not None and node not in seen:
            seen[node] = start
            walk.append(node)
            node = waits.get(node)
        if node is not None and seen[node] == start:  # closed on this walk: a new cycle
            cycles.append(walk[walk.index(node) :])
    return cycles


def refuge(
    traffic: Traffic,
    me: int,
    start: tuple[float, float],
    radius: float,
    standable: B,
    avoid: I64,
) -> tuple[float, float] | None:
    """The centre of the nearest traffic cell (by steps through the floor) where a robot of
    ``radius`` standing there touches none of the cells in ``avoid``, reached through cells
    that are standable (``standable``: flat, one per traffic cell) and not held by anyone but
    ``me``. None when there is no such cell within REFUGE_REACH_M."""
    w, h = traffic.width, traffic.height
    banned = np.zeros(w * h, dtype=bool)
    banned[avoid] = True
    owner = traffic.owner
    passable = standable & ((owner == FREE) | (owner == me))
    col = math.floor((start[0] - traffic.x0) / traffic.cell)
    row = math.floor((start[1] - traffic.y0) / traffic.cell)
    if not (0 <= row < h and 0 <= col < w):
        return None
    steps = math.ceil(REFUGE_REACH_M / traffic.cell)
    frontier = [row * w + col]
    seen = {frontier[0]}
    for _ in range(steps):
        nxt: list[int] = []
        for c in frontier:
            r, q = divmod(c, w)
            for rr, qq in ((r + 1, q), (r - 1, q), (r, q + 1), (r, q - 1)):
                if 0 <= rr < h and 0 <= qq < w:
                    n = rr * w + qq
                    if n not in seen and passable[n]:
                        seen.add(n)
                        nxt.append(n)
        for c in nxt:
            cx, cy = traffic.centre(c)
            if not any(banned[k] for k in traffic.box(cx, cy, radius)):
                return cx, cy
        if not nxt:
            return None
        frontier = nxt
    return None
