"""The pymunk world: static geometry, robot bodies, and batched state transfer.

Only the simulation thread touches this object (pymunk is not thread-safe). Robot
velocities are written and poses read for all bodies at once through ``pymunk.batch``,
so the per-tick cost does not grow with a Python loop over robots.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import numpy.typing as npt
import pymunk
import pymunk.batch

from fleetcommon.arrays import F64
from simd.core.carry import positions
from simd.core.models import RobotModel
from simd.core.worldfile import WorldGeometry

_ROBOT = 1
_STATIC = 2
_GET_FIELDS = pymunk.batch.BodyFields.BODY_ID | pymunk.batch.BodyFields.POSITION | pymunk.batch.BodyFields.ANGLE
_SET_FIELDS = pymunk.batch.BodyFields.VELOCITY | pymunk.batch.BodyFields.ANGULAR_VELOCITY


class Physics:
    """Rigid-body world stepping robots with velocities chosen by the drive controller."""

    def __init__(self, world: WorldGeometry, substeps: int = 2) -> None:
        self.space = pymunk.Space()
        # Contacts here are robots pushed by velocities set every tick, not stacks: 5 solver
        # passes leave the same contact depths as 10 (wall 1.7 mm, head-on 2.9 mm; five robots
        # in a row pushing into a wall 0.6 mm in all, 6.9 mm with 10) and take ~0.07-0.1 ms
        # off the tick of 100 wandering robots.
        self.space.iterations = 5
        # pymunk's defaults are tuned for pixels: 0.1 of allowed overlap would let a robot
        # sink 10 cm into a wall, and through a thin one. Work in metres.
        self.space.collision_slop = 0.0005
        # Robots get their wheel velocity each tick, which pymunk integrates before it solves
        # contacts; correcting 70 % of any overlap per 1/60 s (default: 10 %) keeps a robot
        # pushing into a wall within ~2 mm of it at 2 substeps, with no jitter (measured: 21 mm
        # with the defaults; 3.4 mm at 50 %; 3 substeps at 50 % cost 50 % more for 2.0 mm).
        self.space.collision_bias = pow(0.3, 60)
        self.substeps = substeps
        self.space.add(*_static_shapes(world, self.space.static_body))
        self._bodies: dict[int, pymunk.Body] = {}  # robot id -> body
        #: model name -> the blocker's probe body for that model
        self._probes: dict[str, tuple[RobotModel, pymunk.Body, list[pymunk.Shape]]] = {}
        self._rid_of_body: dict[int, int] = {}  # pymunk's body id -> robot id (Body.id is slow to read)
        self._ghosts: dict[str, pymunk.Body] = {}  # robots simulated elsewhere, by namespace
        self._ghost_key_of_body: dict[int, str] = {}
        self._ghost_order: dict[str, int] = {}  # namespace -> its index in the caller's ghost columns
        self._ghost_rows = np.zeros(0, dtype=np.int64)  # pymunk's iteration order -> ghost index (-1: not one)
        self._ghost_now = np.zeros((0, 3))  # the ghosts' poses after the last step, in ghost order
        self._order_dirty = True  # a robot was added or removed since the rows were computed
        self._rows_cache: tuple[npt.NDArray[np.int64], npt.NDArray[np.bool_]] = (
            np.zeros(0, dtype=np.int64),
            np.zeros(0, dtype=bool),
        )
        self._rows_n = 0
        self._n_iter = 0
        # pymunk.batch.Buffer() mallocs arrays that nothing ever frees (pymunk 7.3): the
        # struct, and whatever get_space_bodies grows them to (~39 kB for 1 000 bodies). One
        # per tick leaked ~4 GB an hour at 1 000 robots in real time. These two live as long as
        # the world: one pymunk fills (clear() and refill reuses its array), one that points at
        # our numpy velocities (pymunk must never grow that one).
        self._read_buf = pymunk.batch.Buffer()
        self._write_buf = pymunk.batch.Buffer()
        self._velocities = np.zeros((0, 3), dtype=np.float64)
        self._in_order = False

    # -- robots -------------------------------------------------------------------------

    def _make_body(self, model: RobotModel) -> tuple[pymunk.Body, list[pymunk.Shape]]:
        return _robot_body(model)

    def blocker(
        self, model: RobotModel, x: float, y: float, yaw: float, ignore: int | None = None, robots: bool = True
    ) -> int | None:
        """What the footprint at this pose would overlap: -1 for static geometry, a robot
        id for a robot, None if the place is free. Robot ``ignore`` does not count (a robot
        being moved may overlap where it stands now), nor any robot without ``robots``."""
        # one probe body per model, moved from query to query (never added to the space):
        # placing a thousand robots asks this some ten thousand times
        probe = self._probes.get(model.name)
        if probe is None or probe[0] is not model:  # a model of the same name is another model
            probe = self._probes[model.name] = (model, *self._make_body(model))
        for other in _overlapping(self.space, probe[1], probe[2], x, y, yaw):
            if other.body is self.space.static_body:
                return -1
            rid = getattr(other.body, "rid", None)
            if robots and rid is not None and rid != ignore:
                return int(rid)
        return None

    def add_robot(self, rid: int, model: RobotModel, x: float, y: float, yaw: float) -> None:
        body, shapes = self._make_body(model)
        body.position = (x, y)
        body.angle = yaw
        body.rid = rid
        self.space.add(body, *shapes)
        # A diff-drive base turns about the wheel axle midpoint (base_footprint), not about
        # the chassis' centre of mass, and the velocities we set are those of that point.
        # Changing the centre of gravity moves the body's origin, so place it afterwards.
        body.center_of_gravity = (0.0, 0.0)
        body.position = (x, y)
        body.angle = yaw
        self.space.reindex_shapes_for_body(body)
        self._bodies[rid] = body
        self._rid_of_body[body.id] = rid
        self._order_dirty = True

    def add_ghost(self, key: str, model: RobotModel, x: float, y: float, yaw: float) -> None:
        """Add a robot simulated elsewhere: a kinematic body with the model's footprint, which
        this world's robots bump into but cannot push."""
        body = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
        shapes = []
        for x0, x1, y0, y1 in model.collision_boxes():
            s = pymunk.Poly(body, [(x0, y0), (x1, y0), (x1, y1), (x0, y1)])
            s.friction = 0.0
            s.collision_type = _ROBOT
            shapes.append(s)
        body.position = (x, y)
        body.angle = yaw
        self.space.add(body, *shapes)
        self._ghosts[key] = body
        self._ghost_key_of_body[body.id] = key
        self._order_dirty = True

    def place_ghost(self, key: str, x: float, y: float, yaw: float) -> None:
        """Teleport a ghost (it jumped: its daemon reset it, or its poses came late)."""
        self._teleport(self._ghosts[key], x, y, yaw)

    def remove_ghost(self, key: str) -> None:
        body = self._ghosts.pop(key)
        del self._ghost_key_of_body[body.id]
        self.space.remove(body, *body.shapes)
        self._order_dirty = True

    def order_ghosts(self, keys: list[str]) -> None:
        """The order of the caller's ghost columns (every ghost named once)."""
        self._ghost_order = {k: i for i, k in enumerate(keys)}
        self._order_dirty = True
        self._ghost_now = np.array([(*self._ghosts[k].position, self._ghosts[k].angle) for k in keys]).reshape(-1, 3)

    def ghost_poses(self) -> npt.NDArray[np.float64]:
        """The ghosts' poses (x, y, yaw rows, in the order of ``order_ghosts``) as the last step left them."""
        return self._ghost_now

    def remove_robot(self, rid: int) -> None:
        body = self._bodies.pop(rid)
        del self._rid_of_body[body.id]
        self.space.remove(body, *body.shapes)
        self._order_dirty = True

    def place(self, rid: int, x: float, y: float, yaw: float) -> None:
        """Teleport a robot (reset), stopping it."""
        self._teleport(self._bodies[rid], x, y, yaw)

    def _teleport(self, body: pymunk.Body, x: float, y: float, yaw: float) -> None:
        body.position = (x, y)
        body.angle = yaw
        body.velocity = (0.0, 0.0)
        body.angular_velocity = 0.0
        self.space.reindex_shapes_for_body(body)

    # -- batched state --------------------------------------------------------------------

    def _rows(self, rids: npt.NDArray[np.int64]) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.bool_]]:
        """For each body in pymunk's iteration order, its row in the caller's arrays, and
        which bodies are robots. Recomputed only after a robot is added or removed: the
        caller's rows change only then too."""
        if self._order_dirty or self._rows_n != len(rids):
            buf = self._read_buf
            buf.clear()
            pymunk.batch.get_space_bodies(self.space, pymunk.batch.BodyFields.BODY_ID, buf)
            ids = np.frombuffer(buf.int_buf(), dtype=np.uintp)
            # with numpy, not dicts over every body: ~15 ms of Python after each spawn or
            # delete at 20 000 robots, ~1 ms so
            of_body = self._rid_of_body
            robot_bodies = np.fromiter(of_body.keys(), dtype=np.uintp, count=len(of_body))
            row_of_robot = positions(rids, np.fromiter(of_body.values(), dtype=np.int64, count=len(of_body)))
            rows = _through(positions(robot_bodies, ids), row_of_robot)
            key_of, order = self._ghost_key_of_body, self._ghost_order
            ghost_bodies = np.fromiter(key_of.keys(), dtype=np.uintp, count=len(key_of))
            ghost_index = np.array([order.get(key, -1) for key in key_of.values()], dtype=np.int64)
            self._ghost_rows = _through(positions(ghost_bodies, ids), ghost_index)
            self._rows_cache = (rows, rows >= 0)
            self._rows_n = len(rids)
            self._n_iter = len(ids)
            self._velocities = np.zeros((len(ids), 3), dtype=np.float64)  # bodies not ours stay 0
            self._write_buf.set_float_buf(self._velocities.reshape(-1))  # pymunk reads it in place
            # usually pymunk iterates our robots in our order first, then the static body (until
            # a delete reorders them): then the rows are plain slices
            n = len(rids)
            self._in_order = bool(np.array_equal(rows[:n], np.arange(n)) and np.all(rows[n:] < 0))
            self._order_dirty = False
        return self._rows_cache

    def step(
        self,
        rids: npt.NDArray[np.int64],
        vx: F64,
        vy: F64,
        w: F64,
        dt: float,
        ghost_v: npt.NDArray[np.float64] | None = None,
    ) -> None:
        """Set each robot's world velocity (rows aligned with ``rids``) and each ghost's
        (``ghost_v``: vx, vy, w rows in ghost order; none: they stand still) and advance ``dt``."""
        rows, ok = self._rows(rids)
        if self._n_iter:
            out = self._velocities
            if self._in_order:
                n = len(rids)
                out[:n, 0], out[:n, 1], out[:n, 2] = vx, vy, w
            else:
                r = rows[ok]
                out[ok, 0] = vx[r]
                out[ok, 1] = vy[r]
                out[ok, 2] = w[r]
            if self._ghost_order:
                g = self._ghost_rows
                is_ghost = g >= 0
                out[is_ghost] = 0.0 if ghost_v is None else ghost_v[g[is_ghost]]
            pymunk.batch.set_space_bodies(self.space, _SET_FIELDS, self._write_buf)
        h = dt / self.substeps
        for _ in range(self.substeps):
            self.space.step(h)

    def poses(self, rids: npt.NDArray[np.int64]) -> tuple[F64, F64, F64]:
        """Positions and headings of the robots, rows aligned with ``rids``."""
        n = len(rids)
        if not n and not self._ghost_order:
            return np.zeros(0), np.zeros(0), np.zeros(0)
        rows, ok = self._rows(rids)
        buf = self._read_buf
        buf.clear()
        pymunk.batch.get_space_bodies(self.space, _GET_FIELDS, buf)
        data = np.frombuffer(buf.float_buf(), dtype=np.float64).reshape(-1, 3)
        if self._ghost_order:
            g = self._ghost_rows
            is_ghost = g >= 0
            now = np.empty((len(self._ghost_order), 3))
            now[g[is_ghost]] = data[is_ghost]
            self._ghost_now = now
        if self._in_order:
            return data[:n, 0].copy(), data[:n, 1].copy(), data[:n, 2].copy()
        x = np.zeros(n)
        y = np.zeros(n)
        a = np.zeros(n)
        r = rows[ok]
        x[r] = data[ok, 0]
        y[r] = data[ok, 1]
        a[r] = data[ok, 2]
        return x, y, a


def _robot_body(model: RobotModel) -> tuple[pymunk.Body, list[pymunk.Shape]]:
    """A body with the exact footprint as two convex boxes (``RobotModel.collision_boxes``):
    contacts among robots pressing into walls and each other are most of pymunk's time,
    and two boxes make ~0.1 ms less of a 100-robot tick than chassis and two wheels."""
    body = pymunk.Body()
    boxes = model.collision_boxes()
    areas = [(x1 - x0) * (y1 - y0) for x0, x1, y0, y1 in boxes]
    shapes: list[pymunk.Shape] = []
    for (x0, x1, y0, y1), area in zip(boxes, areas, strict=True):
        s = pymunk.Poly(body, [(x0, y0), (x1, y0), (x1, y1), (x0, y1)])
        s.mass = model.mass * area / sum(areas)
        s.friction = 0.0
        s.collision_type = _ROBOT
        shapes.append(s)
    return body, shapes


def _static_shapes(world: WorldGeometry, static: pymunk.Body) -> list[pymunk.Shape]:
    """The world's walls and obstacles as shapes of ``static``."""
    shapes: list[pymunk.Shape] = []
    for poly in world.polygons:
        shapes.append(pymunk.Poly(static, [tuple(p) for p in poly]))
    for x, y, r in world.circles:
        shapes.append(pymunk.Circle(static, float(r), (float(x), float(y))))
    for s in shapes:
        s.collision_type = _STATIC
        s.friction = 0.0
    return shapes


def _overlapping(
    space: pymunk.Space, body: pymunk.Body, shapes: list[pymunk.Shape], x: float, y: float, yaw: float
) -> Iterator[pymunk.Shape]:
    """The shapes of ``space`` that a probe (``body`` with ``shapes``, never added to the
    space) overlaps at this pose."""
    body.position = (x, y)
    body.angle = yaw
    for s in shapes:
        s.cache_bb()
        for hit in space.shape_query(s):
            if hit.shape is not None:
                yield hit.shape


class Walls:
    """The world's static geometry in a space of its own, for checking a pose off the
    simulation thread (a spawn answered at once: simd/engine/promises.py). It holds the same
    shapes the simulation's space does, so a pose it finds on a wall is one
    :meth:`Physics.blocker` finds on a wall. Not thread-safe: its owner serialises the calls."""

    def __init__(self, world: WorldGeometry) -> None:
        self.space = pymunk.Space()
        self.space.collision_slop = 0.0005  # as the simulation's space
        self.space.add(*_static_shapes(world, self.space.static_body))
        self._probes: dict[str, tuple[RobotModel, pymunk.Body, list[pymunk.Shape]]] = {}

    def blocked(self, model: RobotModel, x: float, y: float, yaw: float) -> bool:
        """Whether the model's footprint at this pose overlaps a wall or an obstacle."""
        probe = self._probes.get(model.name)
        if probe is None or probe[0] is not model:
            probe = self._probes[model.name] = (model, *_robot_body(model))
        return next(_overlapping(self.space, probe[1], probe[2], x, y, yaw), None) is not None


def _through(index: npt.NDArray[np.int64], values: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """``values[index]``, -1 where ``index`` is -1."""
    if not len(values):
        return np.full(len(index), -1, dtype=np.int64)
    return np.where(index >= 0, values[index], -1)
