"""Oracle tests of the lidar kernels against a slow, independent per-beam reference.

Every test runs the numpy kernel (``cast_numpy``) and, when simd.core.lidar._raycast is built, the compiled
one (``cast_native``); the oracle's scans are cached, so the second kernel costs little.

The reference casts every beam on its own: shapely intersects the beam, as the segment from
``origin + range_min * dir`` to ``origin + range_max * dir``, with all visible segments and
takes the distance from the origin to the intersection; pymunk's exact circle segment query
handles circles (queried backwards from the beam end when the beam starts inside the circle,
which is how the far side is found).  The kernel must agree to 1e-4 m and on which beams are
+inf.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import numpy as np
import numpy.typing as npt
import pymunk
import pytest
import shapely
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from shapely.geometry import MultiLineString, Point

from fleetcommon.arrays import F64
from simd.core import lidar
from simd.core.lidar import LidarSpec, StaticScene, cast_native, cast_numpy
from simd.core.models import BURGER as BURGER_MODEL

TOL = 1e-4  # m
GRAZE_DELTA = 1e-7  # m: perturbation that decides beams grazing an end, a tangent or a range limit
SPEC = LidarSpec()

# burger footprint outline: union of the chassis box and the two wheel boxes, 12 vertices
# the burger footprint outline (12 vertices), as the simulator uses it
BURGER = BURGER_MODEL.outline

Kernel = Callable[..., npt.NDArray[np.float32]]
# the kernels under test, as pytest parameters
KERNELS = [
    pytest.param(cast_numpy, id="numpy"),
    pytest.param(
        cast_native,
        id="native",
        marks=pytest.mark.skipif(
            lidar.NATIVE_UNAVAILABLE is not None, reason=f"native lidar kernel: {lidar.NATIVE_UNAVAILABLE}"
        ),
    ),
]


def available_kernels() -> list[tuple[str, Kernel]]:
    """The kernels that can run here, by name (for tests that check them all in one go)."""
    kernels: list[tuple[str, Kernel]] = [("numpy", cast_numpy)]
    if lidar.NATIVE_UNAVAILABLE is None:
        kernels.append(("native", cast_native))
    return kernels


def ring(points: F64) -> F64:
    """Closed polygon -> (k, 4) edge segments."""
    p = np.asarray(points, dtype=np.float64)
    return np.concatenate([p, np.roll(p, -1, axis=0)], axis=1)


def box(x0: float, y0: float, x1: float, y1: float) -> F64:
    return ring(np.array([(x0, y0), (x1, y0), (x1, y1), (x0, y1)]))


def regular(cx: float, cy: float, r: float, k: int, phase: float = 0.0) -> F64:
    a = phase + np.arange(k) * 2 * np.pi / k
    return ring(np.column_stack([cx + r * np.cos(a), cy + r * np.sin(a)]))


def robot(x: float, y: float, yaw: float, clockwise: bool = False) -> F64:
    """Outline edges of a burger at a pose, as a closed loop (counter-clockwise by default)."""
    c, s = math.cos(yaw), math.sin(yaw)
    pts = np.column_stack([x + BURGER[:, 0] * c - BURGER[:, 1] * s, y + BURGER[:, 0] * s + BURGER[:, 1] * c])
    return ring(pts[::-1] if clockwise else pts)


def no_segments() -> F64:
    return np.zeros((0, 4))


def no_circles() -> F64:
    return np.zeros((0, 3))


def oracle(
    origin: tuple[float, float],
    heading: float,
    segments: F64,
    circles: F64,
    spec: LidarSpec = SPEC,
) -> F64:
    """Per-beam reference scan (float64, +inf where nothing is hit), cached: every kernel is
    checked against the same scans."""
    seg = np.ascontiguousarray(segments, dtype=np.float64).reshape(-1, 4)
    cir = np.ascontiguousarray(circles, dtype=np.float64).reshape(-1, 3)
    key = (float(origin[0]), float(origin[1]), float(heading), seg.tobytes(), cir.tobytes(), spec)
    return _oracle_cached(*key).copy()


@functools.lru_cache(maxsize=4096)
def _oracle_cached(ox: float, oy: float, heading: float, seg: bytes, cir: bytes, spec: LidarSpec) -> F64:
    return _oracle((ox, oy), heading, np.frombuffer(seg).reshape(-1, 4), np.frombuffer(cir).reshape(-1, 3), spec)


def _oracle(
    origin: tuple[float, float],
    heading: float,
    segments: F64,
    circles: F64,
    spec: LidarSpec,
) -> F64:
    ox, oy = origin
    ang = heading + spec.angle_min + np.arange(spec.samples) * ((spec.angle_max - spec.angle_min) / (spec.samples - 1))
    dirs = np.column_stack([np.cos(ang), np.sin(ang)])
    start = np.array(origin) + spec.range_min * dirs
    end = np.array(origin) + spec.range_max * dirs
    out = np.full(spec.samples, np.inf)
    if len(segments):
        beams = shapely.linestrings(np.stack([start, end], axis=1))
        walls = MultiLineString([[(s[0], s[1]), (s[2], s[3])] for s in segments])
        # GEOS may leave a floating-point flag raised on a beam parallel to a wall, which numpy
        # then reports after the call, depending on what ran before in the process: not an error
        with np.errstate(divide="ignore", invalid="ignore"):
            dist = shapely.distance(Point(ox, oy), shapely.intersection(beams, walls))
        out = np.where(np.isnan(dist), out, dist)
    if len(circles):
        body = pymunk.Body(body_type=pymunk.Body.STATIC)
        shapes = [pymunk.Circle(body, float(r), offset=(float(x), float(y))) for x, y, r in circles]
        space = pymunk.Space()
        space.add(body, *shapes)
        for k in range(spec.samples):
            a, b = tuple(start[k]), tuple(end[k])
            for (x, y, r), shape in zip(circles, shapes, strict=True):
                if math.hypot(a[0] - x, a[1] - y) < r:  # starts inside: the far side, if in range
                    if math.hypot(b[0] - x, b[1] - y) < r:
                        continue
                    q = shape.segment_query(b, a, 0.0)
                else:
                    q = shape.segment_query(a, b, 0.0)
                if q is not None and q.shape is not None:
                    out[k] = min(out[k], math.hypot(q.point.x - ox, q.point.y - oy))
    return out


def run_cast(
    kernel: Kernel,
    origin: tuple[float, float],
    heading: float,
    static_segments: F64,
    circles: F64,
    dyn: F64 | None = None,
    dyn_owner: npt.NDArray[np.int64] | None = None,
    owner: int = 0,
) -> npt.NDArray[np.float32]:
    scene = StaticScene(static_segments, circles, SPEC.range_max)
    dyn = no_segments() if dyn is None else dyn
    dyn_owner = np.zeros(len(dyn), dtype=np.int64) if dyn_owner is None else dyn_owner
    res = kernel(
        scene,
        SPEC,
        np.array([origin], dtype=np.float64),
        np.array([heading]),
        np.array([owner], dtype=np.int64),
        dyn,
        dyn_owner,
    )
    assert res.shape == (1, SPEC.samples) and res.dtype == np.float32
    row: npt.NDArray[np.float32] = res[0]
    return row


def perturbed(segments: F64, circles: F64, spec: LidarSpec, delta: float) -> tuple[F64, F64, LidarSpec]:
    """Segments lengthened and circles grown by ``delta`` (shrunk if negative), range widened."""
    seg = segments.copy()
    e = seg[:, 2:] - seg[:, :2]
    e /= np.maximum(np.hypot(e[:, 0], e[:, 1]), 1e-300)[:, None]
    seg[:, :2] -= delta * e
    seg[:, 2:] += delta * e
    cir = circles.copy()
    cir[:, 2] = np.maximum(cir[:, 2] + delta, 0.0)
    wide = LidarSpec(spec.samples, spec.angle_min, spec.angle_max, spec.range_min - delta, spec.range_max + delta)
    return seg, cir, wide


def check_scan(
    got: npt.NDArray[np.float32],
    origin: tuple[float, float],
    heading: float,
    segments: F64,
    circles: F64,
    spec: LidarSpec = SPEC,
    label: str = "",
) -> None:
    """``got`` must match the oracle to TOL on every beam, hit or +inf alike.

    A beam that grazes a free segment end or a circle tangentially, or whose hit is at exactly
    range_min or range_max, flips between hit and miss under rounding.  Such a beam is accepted
    if it matches the oracle of the same scene perturbed by GRAZE_DELTA either way.
    """
    want = oracle(origin, heading, segments, circles, spec)
    bad = ~close(got, want)
    if bad.any():
        for delta in (GRAZE_DELTA, -GRAZE_DELTA):
            alt = oracle(origin, heading, *perturbed(segments, circles, spec, delta))
            bad &= ~close(got, alt)
    beams = np.flatnonzero(bad)[:10]
    assert not bad.any(), f"{label} beams {beams}: got {got[beams]}, want {want[beams]}"


def close(got: npt.NDArray[np.float32], want: F64) -> npt.NDArray[np.bool_]:
    g = got.astype(np.float64)
    both_inf = np.isinf(g) & np.isinf(want)
    with np.errstate(invalid="ignore"):
        return both_inf | (np.abs(g - want) <= TOL)


# --- parametrised scenes ---------------------------------------------------------------------

# (name, static segments, circles, dynamic segments, their owners); the sensor is robot 1
SCENES: list[tuple[str, F64, F64, F64, list[int]]] = [
    ("wall", np.array([[1.0, -2.0, 1.3, 2.5]]), no_circles(), no_segments(), []),
    ("box", box(0.7, -0.4, 1.6, 0.9), no_circles(), no_segments(), []),
    ("circle", no_segments(), np.array([[1.2, 0.7, 0.45]]), no_segments(), []),
    ("hexagon", regular(-1.1, 0.9, 0.6, 6, 0.3), no_circles(), no_segments(), []),
    (
        "concave_boxes",  # a U of three boxes around the sensor plus a box in the opening
        np.concatenate(
            [box(-1.5, 1.0, 1.5, 1.3), box(-1.5, -1.3, -1.2, 1.0), box(1.2, -1.3, 1.5, 1.0), box(-0.4, -2.2, 0.5, -1.9)]
        ),
        no_circles(),
        no_segments(),
        [],
    ),
    (
        "overlapping",
        np.concatenate([box(0.5, -0.5, 1.5, 0.5), box(1.0, 0.2, 2.0, 1.1)]),
        np.array([[1.5, -0.3, 0.6], [-1.0, -1.0, 0.8], [-1.3, -0.6, 0.5]]),
        no_segments(),
        [],
    ),
    ("other_robot", no_segments(), no_circles(), robot(0.9, 0.35, 2.0), [2] * 12),
    (
        "robots_both_windings",  # closed loops either way round, and one broken open
        no_segments(),
        no_circles(),
        np.concatenate([robot(0.5, 0.2, 0.3, clockwise=True), robot(-0.4, 0.5, 1.0), robot(0.1, -0.6, 2.0)[:-1]]),
        [2] * 12 + [3] * 12 + [4] * 11,
    ),
    (
        "touching_robot",  # rays start (at range_min) inside it: its far side is seen
        no_segments(),
        no_circles(),
        np.concatenate([robot(0.16, 0.0, 1.6), robot(-0.09, 0.13, -0.4, clockwise=True)]),
        [2] * 12 + [3] * 12,
    ),
    (
        "own_robot_excluded",  # own outline around the sensor, another robot and a wall beyond
        np.array([[-2.0, 1.6, 2.0, 1.7]]),
        no_circles(),
        np.concatenate([robot(0.032, 0.0, 0.0), robot(-0.6, -0.2, 1.0)]),
        [1] * 12 + [3] * 12,
    ),
    (
        "closer_than_range_min",  # a pillar entirely within range_min, a wall crossing it
        np.array([[0.08, -1.0, 0.08, 1.0]]),
        np.array([[-0.03, 0.02, 0.05]]),
        no_segments(),
        [],
    ),
    (
        "around_range_max",  # ring just inside range_max, wall just beyond, wall touching it
        np.array([[3.5 + 1e-3, -1.0, 3.5 + 1e-3, 1.0], [-1.0, -3.4995, 1.0, -3.4995]]),
        np.array([[0.0, 0.0, 3.5 - 1e-3]]),
        no_segments(),
        [],
    ),
    ("far_side_of_box", box(-0.5, -0.4, 0.9, 0.3), no_circles(), no_segments(), []),
    ("far_side_of_circle", no_segments(), np.array([[0.3, -0.2, 1.1]]), no_segments(), []),
    ("empty", no_segments(), no_circles(), no_segments(), []),
]

# (x, y, heading): headings at and around 0 / 2*pi and in the beam gap (6.28 .. 2*pi)
POSES = [
    (0.0, 0.0, 0.0),
    (0.013, -0.021, 1e-9),
    (-0.017, 0.011, -1e-9),
    (0.021, 0.004, 2 * math.pi - 1e-12),
    (0.007, -0.013, 2.0),
    (-0.009, 0.018, -2.7),
    (0.0, 0.0, 6.2816),
    (0.011, 0.006, 4 * math.pi + 0.9),
]


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("pose", POSES, ids=[f"pose{i}" for i in range(len(POSES))])
@pytest.mark.parametrize("scene", SCENES, ids=[s[0] for s in SCENES])
def test_against_oracle(
    scene: tuple[str, F64, F64, F64, list[int]], pose: tuple[float, float, float], kernel: Kernel
) -> None:
    _, segments, circles, dyn, owners = scene
    x, y, heading = pose
    got = run_cast(kernel, (x, y), heading, segments, circles, dyn, np.array(owners, dtype=np.int64), owner=1)
    visible = dyn[np.array(owners, dtype=np.int64) != 1] if len(dyn) else no_segments()
    check_scan(got, (x, y), heading, np.concatenate([segments, visible]), circles)


@pytest.mark.parametrize("kernel", KERNELS)
def test_empty_scene_is_all_inf(kernel: Kernel) -> None:
    got = run_cast(kernel, (3.0, -4.0), 1.0, no_segments(), no_circles())
    assert np.isposinf(got).all()


@pytest.mark.parametrize("kernel", KERNELS)
def test_range_semantics_exactly(kernel: Kernel) -> None:
    """Far side from inside, nothing nearer than range_min, +inf beyond range_max."""
    inside = run_cast(kernel, (0.0, 0.0), 0.3, no_segments(), np.array([[0.0, 0.0, 1.0]]))
    np.testing.assert_allclose(inside, 1.0, atol=1e-6)
    tiny = run_cast(kernel, (0.0, 0.0), 0.3, no_segments(), np.array([[0.0, 0.0, 0.1]]))
    assert np.isposinf(tiny).all()
    ring_in = run_cast(kernel, (0.0, 0.0), 0.0, no_segments(), np.array([[0.0, 0.0, 3.5 - 1e-4]]))
    np.testing.assert_allclose(ring_in, 3.5 - 1e-4, atol=1e-6)
    ring_out = run_cast(kernel, (0.0, 0.0), 0.0, no_segments(), np.array([[0.0, 0.0, 3.5 + 1e-4]]))
    assert np.isposinf(ring_out).all()


@pytest.mark.parametrize("kernel", KERNELS)
def test_last_beam_is_at_angle_max_not_two_pi(kernel: Kernel) -> None:
    """A thin post in the 6.28 .. 2*pi gap is missed; one on the last beam is hit."""
    gap_bearing = (6.28 + 2 * math.pi) / 2
    post = np.array([[2.0 * math.cos(gap_bearing), 2.0 * math.sin(gap_bearing), 0.002]])
    assert np.isposinf(run_cast(kernel, (0.0, 0.0), 0.0, no_segments(), post)).all()
    for heading in (0.0, 1.0, -2.0):
        last = np.array([[2.0 * math.cos(heading + 6.28), 2.0 * math.sin(heading + 6.28), 0.002]])
        got = run_cast(kernel, (0.0, 0.0), heading, no_segments(), last)
        assert np.isfinite(got[359]) and np.isinf(got[:358]).all()


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("offset", [(0.0, 0.0), (1234.5, -987.25)])
def test_batch_of_sensors_matches_single_scans(offset: tuple[float, float], kernel: Kernel) -> None:
    """Many sensors of a fleet in one call: each sees the others, never itself (also far from
    the world origin, where float32 bearings would lose precision if taken in world coordinates).
    """
    rng = np.random.default_rng(5)
    n = 12
    poses = np.column_stack([rng.uniform(-1.5, 1.5, n), rng.uniform(-1.5, 1.5, n), rng.uniform(-4, 4, n)])
    poses[:, :2] += offset
    dyn = np.concatenate([robot(*p) for p in poses])
    owner = np.repeat(np.arange(n, dtype=np.int64) + 10, 12)
    ox, oy = offset
    walls = box(ox - 2.5, oy - 2.5, ox + 2.5, oy + 2.5)
    pillars = np.array([[ox + 0.2, oy + 0.1, 0.15], [ox - 1.0, oy + 1.2, 0.3]])
    scene = StaticScene(walls, pillars, SPEC.range_max)
    origins = poses[:, :2] + np.column_stack([-0.032 * np.cos(poses[:, 2]), -0.032 * np.sin(poses[:, 2])])
    got = kernel(scene, SPEC, origins, poses[:, 2], np.arange(n, dtype=np.int64) + 10, dyn, owner)
    for i in range(n):
        visible = np.concatenate([walls, dyn[owner != i + 10]])
        check_scan(got[i], (origins[i, 0], origins[i, 1]), float(poses[i, 2]), visible, pillars)


@pytest.mark.parametrize("kernel", KERNELS)
def test_other_lidar_layouts(kernel: Kernel) -> None:
    """A partial-circle spec (no wrap-around), a full 2*pi one, and a narrow field of view (one
    turn is ~770 beam units: arcs that wrap past it once indexed beams that do not exist)."""
    segs = np.concatenate([box(-1.0, -1.0, 1.0, 1.0), regular(0.3, 0.2, 0.2, 5)])
    cir = np.array([[-0.4, 0.5, 0.2]])
    for spec in (
        LidarSpec(samples=181, angle_min=-math.pi / 2, angle_max=math.pi / 2, range_min=0.05, range_max=2.0),
        LidarSpec(samples=100, angle_min=0.0, angle_max=2 * math.pi, range_min=0.1, range_max=3.5),
        LidarSpec(samples=50, angle_min=-0.2, angle_max=0.2, range_min=0.05, range_max=2.0),
    ):
        scene = StaticScene(segs, cir, spec.range_max)
        for heading in (0.0, 3.0, -1.0):
            got = kernel(
                scene,
                spec,
                np.array([[0.01, -0.02]]),
                np.array([heading]),
                np.zeros(1, dtype=np.int64),
                no_segments(),
                np.zeros(0, dtype=np.int64),
            )[0]
            check_scan(got, (0.01, -0.02), heading, segs, cir, spec)


# --- random scenes ---------------------------------------------------------------------------

coord = st.floats(-4.0, 4.0, allow_nan=False)
segment = st.tuples(coord, coord, coord, coord).filter(lambda s: math.hypot(s[2] - s[0], s[3] - s[1]) > 1e-3)
circle = st.tuples(coord, coord, st.floats(0.01, 2.0))


@settings(max_examples=50, derandomize=True, deadline=None)
@given(
    segments=st.lists(segment, max_size=8),
    circles=st.lists(circle, max_size=3),
    robots=st.lists(st.tuples(coord, coord, st.floats(-7.0, 7.0), st.booleans()), max_size=3),
    origin=st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0)),
    heading=st.floats(-7.0, 7.0),
    own=st.integers(0, 3),
)
def test_random_scenes(
    segments: list[tuple[float, float, float, float]],
    circles: list[tuple[float, float, float]],
    robots: list[tuple[float, float, float, bool]],
    origin: tuple[float, float],
    heading: float,
    own: int,
) -> None:
    segs = np.array(segments, dtype=np.float64).reshape(-1, 4)
    cirs = np.array(circles, dtype=np.float64).reshape(-1, 3)
    # documented exclusion: a ray collinear with a segment does not hit it, so keep segments
    # whose supporting line passes through the sensor out of the random scenes
    ax, ay = segs[:, 0] - origin[0], segs[:, 1] - origin[1]
    ex, ey = segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]
    assume(bool(np.all(np.abs(ax * ey - ay * ex) > 1e-6 * np.hypot(ex, ey))))
    dyn = np.concatenate([no_segments()] + [robot(*r) for r in robots])
    owners = np.repeat(np.arange(len(robots), dtype=np.int64), 12)
    # both kernels in each example (hypothesis draws the examples once)
    for name, kernel in available_kernels():
        got = run_cast(kernel, origin, heading, segs, cirs, dyn, owners, owner=own)
        check_scan(got, origin, heading, np.concatenate([segs, dyn[owners != own]]), cirs, label=name)
