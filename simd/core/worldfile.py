"""World files: decoded once, strictly, at the edge.

A world file is untrusted text that a person typed. This module is the one place that turns it
into numbers the simulation trusts, so physics and lidar never re-check geometry in the step
loop. Decoding is strict (unknown fields and wrong types are errors, not warnings) because a
misspelt ``raduis`` that is silently ignored yields a world that loads and is quietly wrong.
Every error names the file and the msgspec location (``$.obstacles[3].radius``) so the author
can go straight to the offending line.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Annotated

import msgspec
import msgspec.yaml
import numpy as np
import numpy.typing as npt

import worlds
from fleetcommon.files import FileFormatError, ShippedFiles, split_location, yaml_syntax_problem

FloatArray = npt.NDArray[np.float64]

# Two polygon points closer than this are the same point: far below any wall thickness and far
# above the rounding noise of 4-decimal world files.
_MIN_EDGE_M = 1e-6
# |sin(turn)| at or below this counts as a straight continuation (a redundant or degenerate
# vertex). Geometric, not numeric: 1e-9 rad is a 1 nm deviation over a 1 m edge.
_MIN_TURN_SIN = 1e-9

PositiveFloat = Annotated[float, msgspec.Meta(gt=0.0)]
NonEmptyStr = Annotated[str, msgspec.Meta(min_length=1)]
#: the range ``nav_cell`` (and simd --nav-cell) may take, metres
NAV_CELL_RANGE_M = (0.2, 5.0)
NavCell = Annotated[float, msgspec.Meta(ge=NAV_CELL_RANGE_M[0], le=NAV_CELL_RANGE_M[1])]


class WorldFileError(FileFormatError):
    """A world that cannot be used, with where (file and location) and why."""


SHIPPED_WORLDS = ShippedFiles("world", worlds.WORLDS_DIR, WorldFileError, (".yaml", ".yml", ".map"))


# --- schema ---------------------------------------------------------------------------------


# Options are repeated on every class: msgspec does not inherit kw_only, and the type checker
# does not inherit frozen.


class Bounds(msgspec.Struct, forbid_unknown_fields=True, frozen=True, kw_only=True):
    x_min: float
    x_max: float
    y_min: float
    y_max: float


class Spawn(msgspec.Struct, forbid_unknown_fields=True, frozen=True, kw_only=True):
    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0


class _Obstacle(msgspec.Struct, forbid_unknown_fields=True, frozen=True, kw_only=True, tag_field="type"):
    name: NonEmptyStr | None = None


class BoxObstacle(_Obstacle, tag="box", frozen=True, kw_only=True):
    """Axis-aligned box, written as extents because that is how wall tables are published."""

    x_min: float
    x_max: float
    y_min: float
    y_max: float


class RectObstacle(_Obstacle, tag="rect", frozen=True, kw_only=True):
    """Rotated box, written as an SDF-style pose and size so model poses copy across unchanged."""

    x: float
    y: float
    size_x: PositiveFloat
    size_y: PositiveFloat
    yaw: float = 0.0


class PolygonObstacle(_Obstacle, tag="polygon", frozen=True, kw_only=True):
    points: Annotated[list[tuple[float, float]], msgspec.Meta(min_length=3)]


class CircleObstacle(_Obstacle, tag="circle", frozen=True, kw_only=True):
    x: float
    y: float
    radius: PositiveFloat


Obstacle = BoxObstacle | RectObstacle | PolygonObstacle | CircleObstacle


class WorldFile(msgspec.Struct, forbid_unknown_fields=True, frozen=True, kw_only=True):
    name: NonEmptyStr
    description: str = ""
    bounds: Bounds
    default_spawn: Spawn = msgspec.field(default_factory=Spawn)
    obstacles: list[Obstacle] = msgspec.field(default_factory=list)
    nav_cell: NavCell | None = None


# --- output ---------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class WorldGeometry:
    """The validated world in the one shape the simulator consumes.

    Every obstacle but circles is a convex counter-clockwise polygon, so collision and ray
    casting need only two primitives. Arrays are read-only because one geometry may be shared
    by several simulations. Equality is identity: element-wise array comparison has no single
    truth value.
    """

    name: str
    source: str
    bounds: tuple[float, float, float, float]
    default_spawn: tuple[float, float, float]
    polygons: tuple[FloatArray, ...]
    circles: FloatArray
    #: the cells navigation lays over this world for its traffic (m) when its robots fit in
    #: them (bigger robots get bigger cells); None: as small as the robots fit in
    nav_cell: float | None = None

    def segments(self) -> FloatArray:
        """Every polygon edge as (x0, y0, x1, y1), the form a vectorised ray caster wants."""
        if not self.polygons:
            return np.zeros((0, 4), dtype=np.float64)
        starts = np.concatenate(self.polygons)
        ends = np.concatenate([np.roll(p, -1, axis=0) for p in self.polygons])
        return np.hstack([starts, ends])


# --- entry points ---------------------------------------------------------------------------


def load_world(name_or_path: str | os.PathLike[str]) -> WorldGeometry:
    """Load a shipped world by bare name (``turtlebot3_world``) or any world file by path.

    A bare name has no path separator and no ``.yaml``/``.yml`` suffix; anything else is a
    path, so a local file never shadows a shipped world by accident.
    """
    data, source = SHIPPED_WORLDS.read(name_or_path)
    try:
        world = msgspec.yaml.decode(data, type=WorldFile)
    except msgspec.ValidationError as exc:
        raise _validation_error(source, exc) from exc
    except msgspec.DecodeError as exc:
        raise _yaml_error(source, exc) from exc
    return _build(world, source)


def world_from_dict(data: Mapping[str, object], source: str = "<dict>") -> WorldGeometry:
    """Validate an in-memory world exactly as a file would be, for generated worlds."""
    try:
        world = msgspec.convert(data, type=WorldFile)
    except msgspec.ValidationError as exc:
        raise _validation_error(source, exc) from exc
    return _build(world, source)


# --- resolution and error wording -----------------------------------------------------------


def _validation_error(source: str, exc: msgspec.ValidationError) -> WorldFileError:
    reason, location = split_location(str(exc))
    return WorldFileError(source, reason, location or "$")


def _yaml_error(source: str, exc: msgspec.DecodeError) -> WorldFileError:
    reason, where = yaml_syntax_problem(exc)
    return WorldFileError(source, reason, where)


# --- semantic checks and conversion ---------------------------------------------------------


class _Invalid(Exception):
    """A semantic problem found below the point where its location is known."""


def _first_non_finite(value: object, location: str) -> tuple[str, float] | None:
    if isinstance(value, float):
        return None if math.isfinite(value) else (location, value)
    if isinstance(value, msgspec.Struct):
        for field in value.__struct_fields__:
            found = _first_non_finite(getattr(value, field), f"{location}.{field}")
            if found:
                return found
    elif isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            found = _first_non_finite(item, f"{location}[{i}]")
            if found:
                return found
    return None


def _check_interval(lo_name: str, lo: float, hi_name: str, hi: float) -> None:
    if not lo < hi:
        raise _Invalid(f"{lo_name} ({lo}) must be less than {hi_name} ({hi})")


def _convex_ccw(points: Sequence[tuple[float, float]]) -> FloatArray:
    """The points as a counter-clockwise array, if they form a strictly convex polygon.

    Strictly convex (no repeated or collinear vertices) because pymunk and the ray caster both
    assume every vertex is a real corner. Either winding is accepted since authors copy outlines
    from tools that disagree on it.
    """
    p = np.asarray(points, dtype=np.float64)
    k = len(p)
    edges = np.roll(p, -1, axis=0) - p  # edge i runs from point i to point i+1
    lengths = np.hypot(edges[:, 0], edges[:, 1])
    short = np.flatnonzero(lengths <= _MIN_EDGE_M)
    if short.size:
        i = int(short[0])
        raise _Invalid(f"points {i} and {(i + 1) % k} coincide (degenerate polygon)")
    nxt = np.roll(edges, -1, axis=0)
    cross = edges[:, 0] * nxt[:, 1] - edges[:, 1] * nxt[:, 0]  # turn at point i+1
    dot = edges[:, 0] * nxt[:, 0] + edges[:, 1] * nxt[:, 1]
    sin_turn = cross / (lengths * np.roll(lengths, -1))
    flat = np.flatnonzero(np.abs(sin_turn) <= _MIN_TURN_SIN)
    if flat.size:
        i = (int(flat[0]) + 1) % k
        raise _Invalid(f"point {i} is collinear with its neighbours (degenerate polygon or redundant point)")
    if not (np.all(cross > 0) or np.all(cross < 0)):
        sign = np.sign(cross)
        i = (int(np.flatnonzero(sign != sign[0])[0]) + 1) % k
        raise _Invalid(f"polygon is not convex (it turns the other way at point {i})")
    turning = float(np.sum(np.arctan2(cross, dot)))
    if not math.isclose(abs(turning), 2 * math.pi, abs_tol=1e-6):
        raise _Invalid("polygon is not convex (its outline crosses itself)")
    return p if cross[0] > 0 else p[::-1].copy()


def _box(x_min: float, x_max: float, y_min: float, y_max: float) -> FloatArray:
    return np.array([[x_min, y_min], [x_max, y_min], [x_max, y_max], [x_min, y_max]], np.float64)


def _rect(ob: RectObstacle) -> FloatArray:
    hx, hy = ob.size_x / 2.0, ob.size_y / 2.0
    local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]], dtype=np.float64)
    c, s = math.cos(ob.yaw), math.sin(ob.yaw)
    rotation = np.array([[c, -s], [s, c]], dtype=np.float64)
    return local @ rotation.T + np.array([ob.x, ob.y], dtype=np.float64)


def _obstacle_polygon(ob: BoxObstacle | RectObstacle | PolygonObstacle) -> FloatArray:
    match ob:
        case BoxObstacle():
            _check_interval("x_min", ob.x_min, "x_max", ob.x_max)
            _check_interval("y_min", ob.y_min, "y_max", ob.y_max)
            return _box(ob.x_min, ob.x_max, ob.y_min, ob.y_max)
        case RectObstacle():
            return _rect(ob)
        case PolygonObstacle():
            return _convex_ccw(ob.points)


def _build(world: WorldFile, source: str) -> WorldGeometry:
    bad = _first_non_finite(world, "$")
    if bad:
        raise WorldFileError(source, f"must be a finite number, got {bad[1]}", bad[0])

    b = world.bounds
    try:
        _check_interval("x_min", b.x_min, "x_max", b.x_max)
        _check_interval("y_min", b.y_min, "y_max", b.y_max)
    except _Invalid as exc:
        raise WorldFileError(source, str(exc), "$.bounds") from None

    polygons: list[FloatArray] = []
    circles: list[tuple[float, float, float]] = []
    for i, ob in enumerate(world.obstacles):
        if isinstance(ob, CircleObstacle):
            circles.append((ob.x, ob.y, ob.radius))
            continue
        location = f"$.obstacles[{i}]" + (".points" if isinstance(ob, PolygonObstacle) else "")
        try:
            polygon = _obstacle_polygon(ob)
        except _Invalid as exc:
            raise WorldFileError(source, str(exc), location) from None
        polygon.setflags(write=False)
        polygons.append(polygon)

    s = world.default_spawn
    if not (b.x_min < s.x < b.x_max and b.y_min < s.y < b.y_max):
        raise WorldFileError(
            source,
            f"spawn point ({s.x}, {s.y}) is outside the bounds "
            f"x in ({b.x_min}, {b.x_max}), y in ({b.y_min}, {b.y_max})",
            "$.default_spawn",
        )

    circle_array = np.array(circles, dtype=np.float64).reshape(-1, 3)
    circle_array.setflags(write=False)
    return WorldGeometry(
        name=world.name,
        source=source,
        bounds=(b.x_min, b.x_max, b.y_min, b.y_max),
        default_spawn=(s.x, s.y, s.yaw),
        polygons=tuple(polygons),
        circles=circle_array,
        nav_cell=world.nav_cell,
    )
