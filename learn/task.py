"""What one navigating robot sees, does and is judged by: shared by the single-robot and the
fleet environments (learn/navigate.py, learn/navigate_fleet.py)."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from gymnasium import spaces

from fleetcommon.arrays import F32
from learn.reach import Reachable, reachable
from simd.core.models import RobotModel
from simd.core.worldfile import WorldGeometry
from simd.engine.local import LocalFleet

GOAL_RADIUS = 0.2
COLLISION_MARGIN = 0.02
PROGRESS_REWARD = 10.0
ARRIVAL_REWARD = 10.0
COLLISION_REWARD = -10.0
#: from this many robots on, the fleet's arrays are worked through in wide passes (fewer, and
#: numpy's per-call cost decides)
MANY_ROWS = 64
#: the discrete actions: turn rates (rad/s) at DISCRETE_SPEED m/s, as the ROBOTIS DQN stage
DISCRETE_TURNS = (-1.5, -0.75, 0.0, 0.75, 1.5)
DISCRETE_SPEED = 0.15


def check_settings(model: str, beams: int, max_steps: int) -> RobotModel:
    """The model of this name, once the settings both environments share are sound (else ValueError)."""
    from simd.core.models import MODELS

    if model not in MODELS:
        raise ValueError(f"model must be one of {', '.join(MODELS)}, got {model!r}")
    if not 1 <= beams <= 360 or 360 % beams:
        raise ValueError(f"beams must divide 360 (e.g. 24, 36, 360), got {beams}")
    if max_steps < 1:
        raise ValueError(f"max_steps must be >= 1, got {max_steps}")
    return MODELS[model]


def observation_bounds(model: RobotModel, beams: int, diagonal: float) -> tuple[F32, F32]:
    """The observation box: sectors 0..1, goal distance 0..diagonal, bearing ±π, the velocities."""
    vmax, wmax = model.max_linear_velocity, model.max_angular_velocity
    low = np.concatenate([np.zeros(beams), [0.0, -math.pi, -vmax, -wmax]]).astype(np.float32)
    high = np.concatenate([np.ones(beams), [diagonal, math.pi, vmax, wmax]]).astype(np.float32)
    return low, high


@dataclass(frozen=True)
class Spaces:
    """Both environments' spaces for one robot, and the observation box's bounds (typed)."""

    observation: Any  # a spaces.Box (typed loosely by gymnasium)
    action: spaces.Space[Any]
    low: F32
    high: F32


def spaces_for(model: RobotModel, beams: int, world: WorldGeometry, discrete: bool) -> Spaces:
    """The observation box (its distance bound the world's diagonal) and the action space.
    Actions are (linear, angular) as fractions of the model's limits: the symmetric, normalised
    box that Gymnasium's checker and Stable-Baselines3 ask for ((1, 1) is full speed ahead,
    turning left), or the discrete turns."""
    x0, x1, y0, y1 = world.bounds
    low, high = observation_bounds(model, beams, math.hypot(x1 - x0, y1 - y0))
    action: Any = (
        spaces.Discrete(len(DISCRETE_TURNS)) if discrete else spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
    )
    return Spaces(spaces.Box(low, high, dtype=np.float32), action, low, high)


def command(action: Any, model: RobotModel, discrete: bool) -> tuple[float, float]:
    """(v m/s, w rad/s) for an action: a discrete choice, or fractions -1..1 of the limits (clipped)."""
    if discrete:
        try:  # a whole number (an int, a numpy integer, a 0-d array); not 2.7, not "1"
            k = int(action) if not isinstance(action, (str, bytes)) and float(action) == int(action) else -1
        except (TypeError, ValueError, OverflowError):
            k = -1
        if not 0 <= k < len(DISCRETE_TURNS):
            raise ValueError(f"a discrete action is 0..{len(DISCRETE_TURNS) - 1}, got {action!r}")
        return DISCRETE_SPEED, DISCRETE_TURNS[k]
    try:
        a = np.asarray(action, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.shape != (2,) or not np.isfinite(a).all():
        raise ValueError(f"an action is two finite numbers (linear, angular in -1..1 of the limits), got {action!r}")
    # clipped as np.clip does (the values are finite), scaled in Python floats: the same
    # products, without a numpy call each that a step of one robot would notice
    v, w = np.minimum(np.maximum(a, -1.0), 1.0).tolist()
    return v * model.max_linear_velocity, w * model.max_angular_velocity


def command_many(actions: list[Any], model: RobotModel, discrete: bool) -> npt.NDArray[np.float64]:
    """(v, w) rows for a list of actions, as :func:`command` gives them one by one (ValueError
    naming the first bad one's position in ``str(index)`` form via :func:`command`'s message)."""
    k = len(actions)
    try:
        a = np.asarray(actions, dtype=np.float64)
    except (TypeError, ValueError):
        a = None
    if a is not None and discrete and a.shape == (k,) and not any(isinstance(x, (str, bytes)) for x in actions):
        turn = np.trunc(a)
        if np.all((turn == a) & (turn >= 0) & (turn < len(DISCRETE_TURNS))):
            out = np.empty((k, 2))
            out[:, 0] = DISCRETE_SPEED
            out[:, 1] = np.asarray(DISCRETE_TURNS)[turn.astype(np.int64)]
            return out
    elif a is not None and not discrete and a.size == 2 * k:
        a = a.reshape(k, 2)
        if np.all(np.isfinite(a)):
            out = np.clip(a, -1.0, 1.0) * np.array([model.max_linear_velocity, model.max_angular_velocity])
            return np.asarray(out, dtype=np.float64)
    for i, action in enumerate(actions):  # one is wrong: say which, in command()'s words
        try:
            command(action, model, discrete)
        except ValueError as e:
            raise ValueError(f"action {i}: {e}") from None
    raise ValueError("the actions do not stack into one array (mixed shapes?)")


class KeepClear:
    """Points a new place keeps a metre from (other robots' starts and goals), filed in 1 m
    cells: placing a thousand robots asks about two thousand points tens of thousands of
    times, and only the points in the 3 x 3 cells around a place can be within a metre."""

    def __init__(self, points: Iterable[tuple[float, float]] = ()) -> None:
        self._cells: dict[tuple[int, int], list[tuple[float, float]]] = {}
        for p in points:
            self.add(*p)

    def add(self, x: float, y: float) -> None:
        self._cells.setdefault((math.floor(x), math.floor(y)), []).append((x, y))

    def near(self, x: float, y: float) -> bool:
        """Whether a point is less than a metre from (x, y)."""
        cx, cy = math.floor(x), math.floor(y)
        for i in (cx - 1, cx, cx + 1):
            for j in (cy - 1, cy, cy + 1):
                for p in self._cells.get((i, j), ()):
                    if math.dist((x, y), p) < 1.0:
                        return True
        return False


def free_pose(
    places: LocalFleet, model: RobotModel, rng: np.random.Generator,
    keep_clear: KeepClear | Iterable[tuple[float, float]] = (), region: Reachable | None = None, tries: int = 10_000,
) -> tuple[float, float, float]:  # fmt: skip
    """A pose where the footprint is clear with 15 cm to spare each way, inside the bounds, in
    ``region`` (where the robot can drive from the world's spawn, learn/reach.py), and at least
    a metre from the points in ``keep_clear`` (other robots' starts and goals; a
    :class:`KeepClear` that the caller adds to as it places, or any points)."""
    if not isinstance(keep_clear, KeepClear):
        keep_clear = KeepClear(keep_clear)
    x0, x1, y0, y1 = places.geometry.bounds
    pad = 0.3
    for _ in range(tries):
        x, y = float(rng.uniform(x0 + pad, x1 - pad)), float(rng.uniform(y0 + pad, y1 - pad))
        yaw = float(rng.uniform(-math.pi, math.pi))
        if region is not None and not region.contains(x, y):
            continue
        if keep_clear.near(x, y):
            continue
        if not places.fits(model.name, x, y, yaw):
            continue
        if not any(places.touches(model, x + dx, y + dy, yaw)
                   for dx, dy in ((0.15, 0), (-0.15, 0), (0, 0.15), (0, -0.15))):  # fmt: skip
            return x, y, yaw
    raise RuntimeError(f"no free place in {places.geometry.name!r} after {tries} draws")


def collided(scan: F32, footprint: npt.NDArray[np.float64]) -> bool:
    """A return closer than COLLISION_MARGIN outside the footprint, or below the minimum range."""
    return bool((scan < footprint + COLLISION_MARGIN).any())  # collided_many's test for one row


def collided_many(scans: F32, footprint: npt.NDArray[np.float64]) -> npt.NDArray[np.bool_]:
    """:func:`collided` for each row of ``scans`` (one robot's scan a row)."""
    # -inf (a return below the minimum range) is below any threshold as it stands
    threshold = footprint + COLLISION_MARGIN
    if scans.dtype == np.float32 and len(scans) >= MANY_ROWS:  # as float32, twice as fast, the same answers:
        # for a float32 r, r < t exactly when r < the smallest float32 >= t (none lies between)
        rounded = threshold.astype(np.float32)
        up = np.nextafter(rounded, np.float32(np.inf))
        hit: npt.NDArray[np.bool_] = np.any(scans < np.where(rounded < threshold, up, rounded), axis=1)
        return hit
    return np.asarray(np.any(scans < threshold, axis=1))


def observe_many(
    poses: npt.NDArray[np.float64], velocities: npt.NDArray[np.float64], goals: npt.NDArray[np.float64],
    scans: F32, beams: int, range_max: float, low: F32, high: F32,
) -> F32:  # fmt: skip
    """The observations of n robots at once, a row each: ``poses`` (n, 3) x, y, yaw;
    ``velocities`` (n, 2) linear, angular; ``goals`` (n, 2); ``scans`` (n, samples). One numpy
    pass for the whole fleet: a thousand agents cost about what ten did one by one."""
    # the nearest return of each sector first, then its meaning: -inf (closer than the minimum
    # range) is 0, +inf (no return) the range limit; one pass over the scans instead of four
    per_sector = scans.reshape(len(scans), beams, -1)
    if len(scans) < MANY_ROWS:  # one call: each numpy call costs more than a few robots' sectors
        nearest = per_sector.min(axis=2)
    else:  # a few wide passes beat numpy's reduction over short rows (the same minima)
        nearest = per_sector[:, :, 0].copy()
        for k in range(1, per_sector.shape[2]):
            np.minimum(nearest, per_sector[:, :, k], out=nearest)
    nearest = np.where(np.isneginf(nearest), 0.0, np.minimum(nearest, range_max))
    dx, dy = goals[:, 0] - poses[:, 0], goals[:, 1] - poses[:, 1]
    heading = np.arctan2(dy, dx) - poses[:, 2]
    bearing = heading - math.tau * np.rint(heading / math.tau)  # to -π..π, as math.remainder
    # one concatenation, one clip: the sectors' bounds are 0..1, so the box's clip is theirs
    # (the same values as clipping them first and stacking the rest apart, in fewer calls);
    # the clip as the two ufuncs np.clip's loop is made of, bounds first (ties and NaN as it
    # gives them), without its Python wrapper
    rows = np.concatenate([nearest / range_max, np.hypot(dx, dy)[:, None], bearing[:, None], velocities], axis=1)
    obs: F32 = np.minimum(high, np.maximum(low, rows)).astype(np.float32)
    return obs


def drivable(world: WorldGeometry, model: RobotModel) -> Reachable:
    """Where a robot of this model can drive from the world's spawn (learn/reach.py)."""
    radius = float(np.max(np.hypot(model.outline[:, 0], model.outline[:, 1])))
    return reachable(world, radius)


def footprint_ranges(model: RobotModel, samples: int) -> npt.NDArray[np.float64]:
    """For each lidar beam, how far from the lidar the robot's own outline is along it."""
    angles = np.arange(samples) * (2 * math.pi / samples)
    ox, oy = model.lidar_offset
    pts = model.outline - np.array([ox, oy])
    a, b = pts, np.roll(pts, -1, axis=0)
    d = np.stack([np.cos(angles), np.sin(angles)], axis=1)  # (beams, 2)
    e = b - a  # (edges, 2)
    # solve t*d = a + u*e for t >= 0, 0 <= u <= 1 per beam and edge
    den = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (a[None, :, 0] * e[None, :, 1] - a[None, :, 1] * e[None, :, 0]) / den
        u = (a[None, :, 0] * d[:, None, 1] - a[None, :, 1] * d[:, None, 0]) / den
    t = np.where((den != 0) & (t >= 0) & (u >= 0) & (u <= 1), t, np.inf)
    return np.asarray(t.min(axis=1))
