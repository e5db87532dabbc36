"""Exclusive claims on a fine grid, for robots that drive smooth paths in the open.

In an open world (a world file, a map_server map) robots follow any-angle paths, not a
lattice: the floor is cut into small cells (10 cm) and a robot holds the cells under the
square about its circle (its circumscribed radius plus a margin) and, ahead of it, those its
square will sweep along its path. A cell has one holder at most, so two robots' circles never
overlap while each stays within its cells; a robot drives only as far as its claims reach.

The claims along a path are worked out once per path (:meth:`ClaimGrid.path_claims`): sample
by sample, the cells its square needs that no earlier sample needed. A sample is taken whole
or not at all (a robot that waits never holds half a step it cannot take, which would block
others for nothing), and cells are let go once the robot has passed them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

FREE = -1
#: the grid's cells (m)
CELL_M = 0.1
#: distance between the path points whose squares are claimed
SAMPLE_M = 0.05
#: a cell held only because the robot stands on it (not for its path)
UNDER = -math.inf


@dataclass(frozen=True)
class Claims:
    """A path's claims: at path distance ``at[j]`` the robot needs the cells
    ``cells[first[j]:first[j + 1]]`` that no earlier sample needed; ``until[k]`` is the last
    path distance that needs ``cells[k]``."""

    cells: I64
    first: I64
    at: F64
    until: F64
    length: float
    step: float

    def ahead(self, taken: int, to: float) -> I64:
        """The cells the samples from ``taken`` up to path distance ``to`` need."""
        j = int(np.searchsorted(self.at, to, side="right"))
        return self.cells[int(self.first[min(taken, len(self.at))]) : int(self.first[max(j, taken)])]


@dataclass(eq=False)
class Holder:
    """One robot on the grid."""

    slot: int
    radius: float  # half-side of the square it holds about itself
    claims: Claims | None = None
    taken: int = 0  # samples of ``claims`` taken
    held: dict[int, float] = field(default_factory=dict)  # cell -> path distance after which it may go
    box: tuple[int, ...] = ()
    blocked_by: int = FREE  # who holds the next cell it needs


class ClaimGrid:
    """The fine cells of one world and who holds each."""

    def __init__(self, bounds: tuple[float, float, float, float], cell: float = CELL_M) -> None:
        x_min, x_max, y_min, y_max = bounds
        self.x0, self.y0, self.cell = x_min, y_min, cell
        self.width = max(1, math.ceil((x_max - x_min) / cell - 1e-9))
        self.height = max(1, math.ceil((y_max - y_min) / cell - 1e-9))
        self.owner = np.full(self.width * self.height, FREE, dtype=np.int64)

    def box(self, x: float, y: float, r: float) -> tuple[int, ...]:
        """The cells (flat) that the square of half-side ``r`` about (x, y) overlaps."""
        c0 = max(0, math.floor((x - r - self.x0) / self.cell))
        c1 = min(self.width - 1, math.floor((x + r - self.x0) / self.cell))
        r0 = max(0, math.floor((y - r - self.y0) / self.cell))
        r1 = min(self.height - 1, math.floor((y + r - self.y0) / self.cell))
        return tuple(row * self.width + col for row in range(r0, r1 + 1) for col in range(c0, c1 + 1))

    def index(self, x: float, y: float) -> int | None:
        col = math.floor((x - self.x0) / self.cell)
        row = math.floor((y - self.y0) / self.cell)
        if 0 <= row < self.height and 0 <= col < self.width:
            return row * self.width + col
        return None

    def centre(self, index: int) -> tuple[float, float]:
        row, col = divmod(index, self.width)
        return self.x0 + (col + 0.5) * self.cell, self.y0 + (row + 0.5) * self.cell

    def path_claims(self, points: F64, radius: float) -> Claims:
        """The claims of a polyline ``points`` (n, 2) for a square of half-side ``radius``."""
        seg = np.diff(points, axis=0)
        cum = np.concatenate(([0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))))
        length = float(cum[-1])
        s = np.linspace(0.0, length, max(2, math.ceil(length / SAMPLE_M) + 1))
        xs, ys = np.interp(s, cum, points[:, 0]), np.interp(s, cum, points[:, 1])
        c0 = np.floor((xs - radius - self.x0) / self.cell).astype(np.int64)
        c1 = np.floor((xs + radius - self.x0) / self.cell).astype(np.int64)
        r0 = np.floor((ys - radius - self.y0) / self.cell).astype(np.int64)
        r1 = np.floor((ys + radius - self.y0) / self.cell).astype(np.int64)
        span = int(max((c1 - c0).max(), (r1 - r0).max())) + 1
        sample_of, cell_of = [], []
        for dr in range(span):
            for dc in range(span):
                row, col = r0 + dr, c0 + dc
                ok = (row <= r1) & (col <= c1) & (row >= 0) & (col >= 0) & (row < self.height) & (col < self.width)
                sample_of.append(np.flatnonzero(ok))
                cell_of.append((row * self.width + col)[ok])
        samples, cells = np.concatenate(sample_of), np.concatenate(cell_of)
        order = np.lexsort((cells, samples))
        samples, cells = samples[order], cells[order]
        uniq, first_seen = np.unique(cells, return_index=True)
        _, last_rev = np.unique(cells[::-1], return_index=True)
        last_at = s[samples[len(cells) - 1 - last_rev]]
        new = np.zeros(len(cells), dtype=bool)
        new[first_seen] = True
        new_cells = cells[new]
        until = last_at[np.searchsorted(uniq, new_cells)]
        first = np.searchsorted(samples[new], np.arange(len(s) + 1)).astype(np.int64)
        return Claims(new_cells, first, s, until, length, float(s[1] - s[0]))

    # -- holding --------------------------------------------------------------------------------

    def stand(self, h: Holder, x: float, y: float) -> int:
        """The robot is at (x, y): it holds the free cells under it and lets go of those it
        stood on before that its path does not need. Returns the slot of a robot holding a
        cell under it (they stand too close), or FREE."""
        box = self.box(x, y, h.radius)
        owner, crowd = self.owner, FREE
        for c in box:
            o = int(owner[c])
            if o == FREE:
                owner[c] = h.slot
                h.held.setdefault(c, UNDER)
            elif o != h.slot:
                crowd = o
        if box != h.box:
            for c in h.box:
                if c not in box and h.held.get(c, 0.0) == UNDER:
                    self._let_go(h, c)
            h.box = box
        return crowd

    def follow(self, h: Holder, claims: Claims | None) -> None:
        """A new path (or none): what was claimed for the old one and is not under the robot goes."""
        for c in [c for c, until in h.held.items() if until != UNDER and c not in h.box]:
            self._let_go(h, c)
        for c in h.box:
            if c in h.held:
                h.held[c] = UNDER
        h.claims, h.taken, h.blocked_by = claims, 0, FREE

    def advance(self, h: Holder, progress: float, ahead: float) -> float:
        """At path distance ``progress``: take the samples up to ``progress + ahead`` in order,
        each whole, stopping at the first with a cell another robot holds; let go of the cells
        passed. Returns the path distance the robot may drive to."""
        claims = h.claims
        if claims is None:
            return progress
        owner, slot, held = self.owner, h.slot, h.held
        cells, first, at, until = claims.cells, claims.first, claims.at, claims.until
        j, n = h.taken, len(at)
        h.blocked_by = FREE
        while j < n and at[j] <= progress + ahead:
            a, b = int(first[j]), int(first[j + 1])
            blocker = next((int(owner[c]) for c in cells[a:b].tolist() if owner[c] not in (FREE, slot)), FREE)
            if blocker != FREE:
                h.blocked_by = blocker
                break
            for k in range(a, b):
                c = int(cells[k])
                owner[c] = slot
                if held.get(c, UNDER) < until[k]:
                    held[c] = float(until[k])
            j += 1
        h.taken = j
        behind = progress - claims.step
        for c in [c for c, keep in held.items() if UNDER < keep < behind and c not in h.box]:
            self._let_go(h, c)
        if j >= n:
            return claims.length
        return float(at[j - 1]) if j > 0 else 0.0

    def clear_start(self, h: Holder, claims: Claims, reach: float) -> bool:
        """Whether the first ``reach`` metres of ``claims`` need no cell another robot holds
        (a way the robot could set off on now)."""
        end = int(claims.first[int(np.searchsorted(claims.at, reach, side="right"))])
        owners = self.owner[claims.cells[:end]]
        return not bool(np.any((owners != FREE) & (owners != h.slot)))

    def retract(self, h: Holder, progress: float) -> None:
        """Give back the samples claimed beyond ``progress`` (a robot making way must not
        stand in the way with claims it cannot use)."""
        claims = h.claims
        if claims is None:
            return
        j = int(np.searchsorted(claims.at, progress, side="right"))
        if j >= h.taken:
            return
        for k in range(int(claims.first[j]), int(claims.first[h.taken])):
            c = int(claims.cells[k])
            if c not in h.box:
                self._let_go(h, c)
        h.taken = j

    def release(self, h: Holder) -> None:
        for c in list(h.held):
            self._let_go(h, c)
        h.box, h.claims, h.taken, h.blocked_by = (), None, 0, FREE

    def _let_go(self, h: Holder, c: int) -> None:
        h.held.pop(c, None)
        if self.owner[c] == h.slot:
            self.owner[c] = FREE

    def corridor(self, h: Holder, progress: float, length: float) -> I64:
        """The cells the robot holds and those its path needs for ``length`` m beyond
        ``progress``: what a robot making way for it must keep clear of."""
        ahead = h.claims.ahead(h.taken, progress + length) if h.claims is not None else np.zeros(0, np.int64)
        return np.unique(np.concatenate([np.fromiter(h.held, dtype=np.int64, count=len(h.held)), ahead]))
