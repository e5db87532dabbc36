"""Robots simulated elsewhere (the other daemons of a shared fleet), as this world sees them.

A ghost is an outline for the lidar, at the pose its own daemon gave, and, while it is near
one of this world's robots, a kinematic body in the physics (this world's robots bump into it
and cannot push it). A fleet of thousands has thousands of ghosts moving every tick, so they
are kept as columns (their poses are arrays each tick), and only those within ``NEAR_M`` of
one of this world's robots are bodies: moving kinematic bodies cost pymunk more than this
world's own robots (3 000 beside 3 000 robots: +5 ms a tick), and a robot can only touch a
ghost that is near. A ghost reaches its new pose by moving: the physics is given the velocity
that takes it there in one tick, so a robot it meets is met by a moving body, as on its own
daemon; a ghost that jumps farther than a robot can go in a tick (its daemon reset it, or its
poses came late) is put there instead, and so is one that comes near.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from fleetcommon.arrays import F64, I64
from simd.core.models import MODELS, RobotModel
from simd.core.physics import Physics

#: a ghost that moves farther than this in one tick (m, rad) is put there, not driven there
JUMP_M = 0.1
JUMP_RAD = 0.5
#: the side of the grid cells that decide which ghosts are bodies: a ghost is one while it is
#: in the cell of one of this world's robots or a neighbouring one (within 0.5 to 1 m; two
#: robots touch within 0.45 m of each other, and close in at most 2 cm a tick)
NEAR_M = 0.5


@dataclass(frozen=True)
class GhostColumns:
    """Ghosts as columns: ``names[i]`` of model ``models[i]`` at (x[i], y[i], yaw[i])."""

    names: list[str]
    models: list[str]
    x: F64
    y: F64
    yaw: F64

    @classmethod
    def from_mapping(cls, ghosts: Mapping[str, tuple[str, float, float, float]]) -> GhostColumns:
        """From namespace -> (model, x, y, yaw)."""
        rows = list(ghosts.values())
        return cls(
            names=list(ghosts),
            models=[r[0] for r in rows],
            x=np.array([r[1] for r in rows], dtype=np.float64),
            y=np.array([r[2] for r in rows], dtype=np.float64),
            yaw=np.array([r[3] for r in rows], dtype=np.float64),
        )


class Ghosts:
    """This world's ghosts: which there are (bodies in ``physics``) and where they are going."""

    def __init__(self, physics: Physics, bounds: tuple[float, float, float, float]) -> None:
        self._physics = physics
        self.names: list[str] = []
        self._model_names: list[str] = []
        self.models: list[RobotModel] = []
        self.x, self.y, self.yaw = np.zeros(0), np.zeros(0), np.zeros(0)
        self._outline = np.zeros((0, 0, 2))
        x0, x1, y0, y1 = bounds
        self._origin = (x0 - 2 * NEAR_M, y0 - 2 * NEAR_M)
        self._cells = (int((x1 - x0) / NEAR_M) + 5, int((y1 - y0) / NEAR_M) + 5)
        self._bodies: dict[str, str] = {}  # the ghosts that are bodies now: name -> model

    def __len__(self) -> int:
        return len(self.names)

    def update(self, cols: GhostColumns) -> None:
        """The ghosts now: those not named leave, new ones arrive where they are, the others
        go to their new poses in the next tick. Unknown models and poses that are not finite
        are left out."""
        finite = np.isfinite(cols.x) & np.isfinite(cols.y) & np.isfinite(cols.yaw)
        known = np.array([m in MODELS for m in cols.models], dtype=bool) if cols.models != self._model_names else None
        keep = finite if known is None else finite & known
        if keep.all():
            names, models, x, y, yaw = cols.names, cols.models, cols.x, cols.y, cols.yaw
        else:
            idx = np.flatnonzero(keep).tolist()
            names, models = [cols.names[i] for i in idx], [cols.models[i] for i in idx]
            x, y, yaw = cols.x[keep], cols.y[keep], cols.yaw[keep]
        if names != self.names or models != self._model_names:
            self._rebuild(names, models)
        self.x, self.y, self.yaw = (np.asarray(c, dtype=np.float64) for c in (x, y, yaw))

    def _rebuild(self, names: list[str], models: list[str]) -> None:
        """A new set of ghosts (rare: a robot spawned, deleted, or a daemon came or went)."""
        self.names, self._model_names = list(names), list(models)
        self.models = [MODELS[m] for m in models]
        self._outline = np.stack([m.outline for m in self.models]) if self.models else np.zeros((0, 0, 2))

    def _near(self, own_x: F64, own_y: F64) -> npt.NDArray[np.bool_]:
        """Which ghosts are in the cell of one of this world's robots or next to it."""
        nx, ny = self._cells
        grid = np.zeros((nx + 2, ny + 2), dtype=bool)

        def cells(x: F64, y: F64) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
            cx = np.clip(((x - self._origin[0]) / NEAR_M).astype(np.intp), 0, nx - 1) + 1
            cy = np.clip(((y - self._origin[1]) / NEAR_M).astype(np.intp), 0, ny - 1) + 1
            return cx, cy

        ox, oy = cells(own_x, own_y)
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                grid[ox + dx, oy + dy] = True
        gx, gy = cells(self.x, self.y)
        near: npt.NDArray[np.bool_] = grid[gx, gy]
        return near

    def velocities(self, dt: float, own_x: F64, own_y: F64) -> F64 | None:
        """Make the ghosts near this world's robots (at ``own_x``, ``own_y``) its bodies, and
        return the world velocities (vx, vy, w rows, in the order the physics was given) that
        take each to its pose in one tick of ``dt``; a ghost that would jump, or that just
        became a body, is put there (and gets zero)."""
        if not len(self.names) and not self._bodies:
            return None  # a world of its own (every daemon not in a shared fleet): nothing to do
        physics = self._physics
        near = self._near(own_x, own_y) if len(self.names) and len(own_x) else np.zeros(len(self.names), dtype=bool)
        idx = np.flatnonzero(near)
        names = [self.names[i] for i in idx.tolist()]
        wanted = {n: self._model_names[i] for n, i in zip(names, idx.tolist(), strict=True)}
        fresh = np.zeros(len(idx), dtype=bool)
        if wanted != self._bodies:
            for key, model in self._bodies.items():
                if wanted.get(key) != model:
                    physics.remove_ghost(key)
            for k, (key, model) in enumerate(wanted.items()):
                if self._bodies.get(key) != model:
                    i = idx[k]
                    physics.add_ghost(key, MODELS[model], float(self.x[i]), float(self.y[i]), float(self.yaw[i]))
                    fresh[k] = True
            physics.order_ghosts(names)
            self._bodies = wanted
        elif names != list(self._bodies):
            physics.order_ghosts(names)  # the same bodies in another order
            self._bodies = wanted
        if not names:
            return None
        now = physics.ghost_poses()
        tx, ty, tyaw = self.x[idx], self.y[idx], self.yaw[idx]
        dx, dy = tx - now[:, 0], ty - now[:, 1]
        dth = np.arctan2(np.sin(tyaw - now[:, 2]), np.cos(tyaw - now[:, 2]))
        jump = fresh | (np.hypot(dx, dy) > JUMP_M) | (np.abs(dth) > JUMP_RAD)
        if jump.any():
            for k in np.flatnonzero(jump).tolist():
                physics.place_ghost(names[k], float(tx[k]), float(ty[k]), float(tyaw[k]))
            dx, dy, dth = np.where(jump, 0.0, dx), np.where(jump, 0.0, dy), np.where(jump, 0.0, dth)
        return np.stack([dx / dt, dy / dt, dth / dt], axis=1)

    @property
    def bodies(self) -> int:
        """How many ghosts are bodies in the physics now."""
        return len(self._bodies)

    def lidar_columns(self) -> tuple[F64, F64, F64, I64, F64] | None:
        """x, y, yaw, ids (never a robot id of this world) and outlines, for the lidar."""
        if not self.names:
            return None
        ids = -1 - np.arange(len(self.names), dtype=np.int64)
        return self.x, self.y, self.yaw, ids, self._outline

    def as_dict(self) -> dict[str, tuple[RobotModel, float, float, float]]:
        """namespace -> (model, x, y, yaw): for tests and messages, not the tick."""
        return {
            n: (m, float(x), float(y), float(yaw))
            for n, m, x, y, yaw in zip(self.names, self.models, self.x, self.y, self.yaw, strict=True)
        }
