"""Fleet traffic: the floor cut into cells that robots hold one at a time.

Why reservations, rather than reciprocal avoidance alone: a warehouse's aisles are one robot
wide, and velocity obstacles (ORCA and kin) neither promise that two robots never touch when
they meet there, nor get them past each other. Here every robot holds the cells under its
circle (its circumscribed radius plus a margin, as a square) and, before it drives on, the cells
its circle will sweep along its path a little way ahead. A cell has one holder at most, so two
robots' circles never overlap while each stays within its cells; a robot whose next cell is
held stops short of it and *waits for* the holder. Who waits for whom forms a graph whose
cycles are deadlocks (two robots meeting head on in a corridor, four around a block); the
navigator breaks them (simd/nav/navigator.py): the robot of lower priority plans around or
makes way.

Every robot in the world holds the cells under it, navigating or not (a robot driven by
teleop, or standing still, is an obstacle the others wait for or plan around).

The claims along a path are worked out once per path (:func:`path_claims`): the ordered cells
its circle needs, with the path distance from which each is needed and up to which it is
kept. A robot then claims the next ones as it goes and lets go of those behind it, so each
control step costs a few dictionary operations per robot.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

#: distance between the path points whose circles are claimed (also at most a fifth of a cell)
SAMPLE_M = 0.05
FREE = -1


@dataclass(frozen=True)
class Claims:
    """The cells a robot's circle sweeps along one path, sample by sample: at path distance
    ``at[j]`` it needs the cells ``cells[first[j]:first[j + 1]]`` that no earlier sample
    needed; ``until[cells index]`` is the last path distance that needs that cell. A sample's
    cells are taken all at once or not at all, so a waiting robot never holds half of a step
    it cannot take (which would block others for nothing)."""

    cells: I64
    first: I64  # len(at) + 1 offsets into cells
    at: F64
    until: F64  # one per entry of cells
    length: float
    step: float


@dataclass(eq=False)
class Hold:
    """One robot's standing in the traffic: the claims of its path, how far it has claimed,
    and every cell it holds (-> the path distance after which it may go; -inf for a cell held
    only because the robot stands on it)."""

    slot: int
    radius: float  # the half-side of the square it holds about itself
    claims: Claims | None = None
    claimed: int = 0  # claims.cells[:claimed] have been taken (some since let go)
    held: dict[int, float] = field(default_factory=dict)
    footprint: tuple[int, ...] = ()
    #: the slot of the robot holding the next cell it needs, or FREE
    blocked_by: int = FREE
    #: a cell under the robot is held by this other robot (they stand too close): FREE if not
    crowded_by: int = FREE


class Traffic:
    """The cells of the floor and who holds each (the ``owner`` of a cell is a robot's slot)."""

    def __init__(self, bounds: tuple[float, float, float, float], cell: float) -> None:
        if not (math.isfinite(cell) and cell > 0):
            raise ValueError(f"traffic cell must be > 0, got {cell}")
        x_min, x_max, y_min, y_max = bounds
        self.x0, self.y0, self.cell = x_min, y_min, cell
        self.width = max(1, math.ceil((x_max - x_min) / cell - 1e-9))
        self.height = max(1, math.ceil((y_max - y_min) / cell - 1e-9))
        self.owner = np.full(self.width * self.height, FREE, dtype=np.int64)

    # -- geometry -------------------------------------------------------------------------------

    def box(self, x: float, y: float, r: float) -> tuple[int, ...]:
        """The cells (flat indices) that the square of half-side ``r`` about (x, y) overlaps,
        clipped to the floor (a robot outside the world's bounds holds nothing there)."""
        c0 = max(0, math.floor((x - r - self.x0) / self.cell))
        c1 = min(self.width - 1, math.floor((x + r - self.x0) / self.cell))
        r0 = max(0, math.floor((y - r - self.y0) / self.cell))
        r1 = min(self.height - 1, math.floor((y + r - self.y0) / self.cell))
        return tuple(row * self.width + col for row in range(r0, r1 + 1) for col in range(c0, c1 + 1))

    def centre(self, index: int) -> tuple[float, float]:
        row, col = divmod(index, self.width)
        return self.x0 + (col + 0.5) * self.cell, self.y0 + (row + 0.5) * self.cell

    def path_claims(self, points: F64, radius: float, grow: float = 0.0) -> Claims:
        """The claims of a polyline ``points`` (n, 2) for a circle of ``radius`` at its start,
        growing by ``grow`` over the first ``grow`` metres (how far the robot may stray from its
        path once it drives: standing at the start, it strays nowhere, and a robot right
        beside it does not block its first step)."""
        seg = np.diff(points, axis=0)
        cum = np.concatenate(([0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))))
        length = float(cum[-1])
        step = min(SAMPLE_M, self.cell / 5)
        s = np.linspace(0.0, length, max(2, math.ceil(length / step) + 1))
        xs = np.interp(s, cum, points[:, 0])
        ys = np.interp(s, cum, points[:, 1])
        r = radius + np.minimum(s, grow)
        c0 = np.floor((xs - r - self.x0) / self.cell).astype(np.int64)
        c1 = np.floor((xs + r - self.x0) / self.cell).astype(np.int64)
        r0 = np.floor((ys - r - self.y0) / self.cell).astype(np.int64)
        r1 = np.floor((ys + r - self.y0) / self.cell).astype(np.int64)
        span = int(max((c1 - c0).max(), (r1 - r0).max())) + 1
        sample_of, cell_of = [], []
        for dr in range(span):
            for dc in range(span):
                row, col = r0 + dr, c0 + dc
                ok = (row <= r1) & (col <= c1) & (row >= 0) & (col >= 0) & (row < self.height) & (col < self.width)
                sample_of.append(np.flatnonzero(ok))
                cell_of.append((row * self.width + col)[ok])
        samples = np.concatenate(sample_of)
        cells = np.concatenate(cell_of)
        order = np.lexsort((cells, samples))
        samples, cells = samples[order], cells[order]
        uniq, first_seen = np.unique(cells, return_index=True)
        _, last_rev = np.unique(cells[::-1], return_index=True)
        last_seen = len(cells) - 1 - last_rev
        new = np.zeros(len(cells), dtype=bool)
        new[first_seen] = True
        until_of = dict(zip(uniq.tolist(), s[samples[last_seen]].tolist(), strict=True))
        new_cells = cells[new]
        first = np.searchsorted(samples[new], np.arange(len(s) + 1)).astype(np.int64)
        until = np.array([until_of[c] for c in new_cells.tolist()], dtype=np.float64)
        return Claims(new_cells, first, s, until, length, float(s[1] - s[0]))

    # -- holding --------------------------------------------------------------------------------

    def stand(self, hold: Hold, x: float, y: float) -> None:
        """Hold the cells under the robot at (x, y) and let go of those it left behind that its
        path no longer needs (``progress`` is not known here: see :meth:`advance`)."""
        fp = self.box(x, y, hold.radius)
        owner = self.owner
        hold.crowded_by = FREE
        for c in fp:
            o = owner[c]
            if o == FREE:
                owner[c] = hold.slot
                hold.held.setdefault(c, -math.inf)
            elif o != hold.slot:
                hold.crowded_by = int(o)
        if fp != hold.footprint:
            for c in hold.footprint:
                if c not in fp and hold.held.get(c, 0.0) == -math.inf:
                    self._let_go(hold, c)
            hold.footprint = fp

    def follow(self, hold: Hold, claims: Claims | None) -> None:
        """A new path (or none): cells claimed for the old one and not under the robot are let go."""
        for c in [c for c, until in hold.held.items() if until != -math.inf and c not in hold.footprint]:
            self._let_go(hold, c)
        for c in hold.footprint:
            if c in hold.held:
                hold.held[c] = -math.inf
        hold.claims, hold.claimed, hold.blocked_by = claims, 0, FREE

    def advance(self, hold: Hold, progress: float, ahead: float) -> float:
        """At path distance ``progress``: take the samples needed up to ``progress + ahead``,
        in order, each whole, stopping at the first of which another robot holds a cell; let go
        of the cells passed. Returns the path distance the robot may drive to (its frontier)."""
        claims = hold.claims
        if claims is None:
            return progress
        owner, slot, held = self.owner, hold.slot, hold.held
        cells, first, at, until = claims.cells, claims.first, claims.at, claims.until
        j, n = hold.claimed, len(at)
        hold.blocked_by = FREE
        reach = progress + ahead
        while j < n and at[j] <= reach:
            a, b = int(first[j]), int(first[j + 1])
            blocker = FREE
            for k in range(a, b):
                o = owner[cells[k]]
                if o != FREE and o != slot:
                    blocker = int(o)
                    break
            if blocker != FREE:
                hold.blocked_by = blocker
                break
            for k in range(a, b):
                c = int(cells[k])
                owner[c] = slot
                keep = float(until[k])
                if held.get(c, -math.inf) < keep:
                    held[c] = keep
            j += 1
        hold.claimed = j
        behind = progress - claims.step
        for c in [c for c, keep in held.items() if -math.inf < keep < behind and c not in hold.footprint]:
            self._let_go(hold, c)
        if j >= n:
            return claims.length
        return max(0.0, float(at[j - 1])) if j > 0 else 0.0

    def retract(self, hold: Hold, progress: float) -> None:
        """Give back what was claimed ahead of the robot (kept: the cells under it and the
        samples up to ``progress``): a robot that makes way for another must not stand in
        its way with claims it cannot use."""
        claims = hold.claims
        if claims is None:
            return
        j = int(np.searchsorted(claims.at, progress, side="right"))
        if j >= hold.claimed:
            return
        for k in range(int(claims.first[j]), int(claims.first[hold.claimed])):
            c = int(claims.cells[k])
            if c not in hold.footprint:
                self._let_go(hold, c)
        hold.claimed = j

    def release(self, hold: Hold) -> None:
        """The robot left the world: every cell it held is free."""
        for c in list(hold.held):
            self._let_go(hold, c)
        hold.footprint, hold.claims, hold.claimed, hold.blocked_by = (), None, 0, FREE

    def _let_go(self, hold: Hold, c: int) -> None:
        hold.held.pop(c, None)
        if self.owner[c] == hold.slot:
            self.owner[c] = FREE

    def held_by(self, slots: set[int]) -> I64:
        """The cells any of ``slots`` holds (flat indices)."""
        if not slots:
            return np.zeros(0, dtype=np.int64)
        return np.flatnonzero(np.isin(self.owner, list(slots)))
