"""Robots simulated elsewhere (the other daemons of a shared fleet), as this world sees them.

A ghost is a kinematic body in the physics (this world's robots bump into it and cannot push
it) and an outline for the lidar, at the pose its own daemon gave. A fleet of thousands has
thousands of ghosts moving every tick, so they are kept as columns: the set of ghosts changes
rarely (a body added or removed then, one by one), their poses every tick (arrays only). A
ghost reaches its new pose by moving: the physics is given the velocity that takes it there
in one tick, so a robot it meets is met by a moving body, as on its own daemon; a ghost that
jumps farther than a robot can go in a tick (its daemon reset it, or its poses came late) is
put there instead.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from simd.core.models import MODELS, RobotModel
from simd.core.physics import Physics

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

#: a ghost that moves farther than this in one tick (m, rad) is put there, not driven there
JUMP_M = 0.1
JUMP_RAD = 0.5


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

    def __init__(self, physics: Physics) -> None:
        self._physics = physics
        self.names: list[str] = []
        self._model_names: list[str] = []
        self.models: list[RobotModel] = []
        self.x, self.y, self.yaw = np.zeros(0), np.zeros(0), np.zeros(0)
        self._outline = np.zeros((0, 0, 2))

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
            self._rebuild(names, models, x, y, yaw)
        self.x, self.y, self.yaw = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64), np.asarray(yaw)

    def _rebuild(self, names: list[str], models: list[str], x: F64, y: F64, yaw: F64) -> None:
        """A new set of ghosts (rare: a robot spawned, deleted, or a daemon came or went)."""
        physics, was = self._physics, dict(zip(self.names, self._model_names, strict=True))
        now = dict(zip(names, models, strict=True))
        for key, model in was.items():
            if now.get(key) != model:
                physics.remove_ghost(key)
        for i, (key, model) in enumerate(now.items()):
            if was.get(key) != model:
                physics.add_ghost(key, MODELS[model], float(x[i]), float(y[i]), float(yaw[i]))
        physics.order_ghosts(names)
        self.names, self._model_names = list(names), list(models)
        self.models = [MODELS[m] for m in models]
        self._outline = np.stack([m.outline for m in self.models]) if self.models else np.zeros((0, 0, 2))

    def velocities(self, dt: float) -> F64 | None:
        """The world velocities (vx, vy, w rows) that take each ghost to its pose in one tick
        of ``dt``; ghosts that would jump are put there first (and get zero)."""
        if not self.names:
            return None
        now = self._physics.ghost_poses()
        dx, dy = self.x - now[:, 0], self.y - now[:, 1]
        dth = np.arctan2(np.sin(self.yaw - now[:, 2]), np.cos(self.yaw - now[:, 2]))
        jump = (np.hypot(dx, dy) > JUMP_M) | (np.abs(dth) > JUMP_RAD)
        if jump.any():
            for i in np.flatnonzero(jump).tolist():
                self._physics.place_ghost(self.names[i], float(self.x[i]), float(self.y[i]), float(self.yaw[i]))
            dx, dy, dth = np.where(jump, 0.0, dx), np.where(jump, 0.0, dy), np.where(jump, 0.0, dth)
        return np.stack([dx / dt, dy / dt, dth / dt], axis=1)

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
