"""The compiled lidar kernel (simd/core/lidar/_raycast.c) against the numpy kernel, its reference.

Both must return the same bits: every hit distance is the same float64 expression of the same
inputs (see the docstrings of simd/core/lidar/ and simd/core/lidar/_raycast.c).  The cases where the kernels
may differ are degenerate and documented there (a segment or a circle boundary within ~1e-4 m
of a sensor while range_min is ~0; a ray exactly through a segment end); the random scenes keep
clear of them.

Also: the argument checks of simd.core.lidar._raycast.cast (wrong types, shapes, lengths, inconsistent
grids must raise, never crash), the choice of kernel (FLEETSIM_LIDAR) and thread safety.
"""

from __future__ import annotations

import importlib
import math
import os
import subprocess
import sys
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from types import ModuleType
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from fleetcommon.arrays import F64, I64
from simd.core import lidar
from simd.core.lidar import LidarSpec, StaticScene
from tests.core.test_lidar import POSES, SCENES, box, no_circles, no_segments, regular, robot

pytestmark = pytest.mark.skipif(
    lidar.NATIVE_UNAVAILABLE is not None, reason=f"native lidar kernel: {lidar.NATIVE_UNAVAILABLE}"
)

SPEC = LidarSpec()
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def both(
    scene: StaticScene,
    spec: LidarSpec,
    origins: F64,
    headings: F64,
    owners: I64,
    dyn: F64,
    dyn_owner: I64,
) -> tuple[F64, F64]:
    """float64 scans of the numpy and the native kernel, which must be equal bit for bit; the
    public float32 scans too."""
    args = lidar._inputs(scene, spec, origins, headings, owners, dyn, dyn_owner)
    ref = lidar._cast64_numpy(scene, spec, *args)
    got = lidar._cast64_native(scene, spec, *args)
    assert got.shape == ref.shape == (len(origins), spec.samples)
    differ = np.flatnonzero(got.view(np.uint64) != ref.view(np.uint64))
    if len(differ):
        sensor, beam = np.unravel_index(differ[:8], got.shape)
        pytest.fail(
            f"{len(differ)} beams differ, e.g. sensor {sensor}, beam {beam}: "
            f"native {got.ravel()[differ[:8]]}, numpy {ref.ravel()[differ[:8]]}"
        )
    got32 = lidar.cast_native(scene, spec, origins, headings, owners, dyn, dyn_owner)
    ref32 = lidar.cast_numpy(scene, spec, origins, headings, owners, dyn, dyn_owner)
    assert got32.dtype == ref32.dtype == np.float32
    assert np.array_equal(got32.view(np.uint32), ref32.view(np.uint32))
    return ref, got


def fleet(poses: F64, ids: I64, clockwise: bool = False) -> tuple[F64, I64]:
    """Burger outlines of robots at poses (x, y, yaw), and their owner ids per segment."""
    if len(poses) == 0:
        return no_segments(), np.zeros(0, dtype=np.int64)
    dyn = np.concatenate([robot(x, y, yaw, clockwise) for x, y, yaw in poses])
    return dyn, np.repeat(ids.astype(np.int64), 12)


def sensors_of(poses: F64) -> tuple[F64, F64]:
    """Lidar origins (0.032 m behind the centre) and headings of robots at poses."""
    yaw = poses[:, 2]
    return poses[:, :2] - 0.032 * np.column_stack([np.cos(yaw), np.sin(yaw)]), yaw


# --- the scenes of test_lidar.py --------------------------------------------------------------


@pytest.mark.parametrize("scene", SCENES, ids=[s[0] for s in SCENES])
def test_scenes_of_the_oracle_tests(scene: tuple[str, F64, F64, F64, list[int]]) -> None:
    """Every pose of test_lidar.py as one batch of sensors of robot 1."""
    _, segments, circles, dyn, owners = scene
    poses = np.array(POSES)
    both(
        StaticScene(segments, circles, SPEC.range_max),
        SPEC,
        poses[:, :2],
        poses[:, 2],
        np.ones(len(poses), dtype=np.int64),
        dyn,
        np.array(owners, dtype=np.int64),
    )


# --- random scenes ----------------------------------------------------------------------------

coord = st.floats(-4.0, 4.0, allow_nan=False)
segment = st.tuples(coord, coord, coord, coord)
circle = st.tuples(coord, coord, st.floats(0.01, 2.5))
pose = st.tuples(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0), st.floats(-7.0, 7.0))


@settings(max_examples=40, derandomize=True, deadline=None)
@given(
    segments=st.lists(segment, max_size=12),
    circles=st.lists(circle, max_size=4),
    robots=st.lists(st.tuples(pose, st.booleans(), st.integers(0, 3)), max_size=10),
    extra=st.lists(pose, max_size=3),
)
def test_random_scenes(
    segments: list[tuple[float, float, float, float]],
    circles: list[tuple[float, float, float]],
    robots: list[tuple[tuple[float, float, float], bool, int]],
    extra: list[tuple[float, float, float]],
) -> None:
    """Walls, pillars and overlapping robots (either winding, shared ids) at random; sensors on
    every robot (often inside others or in pillars) and a few more."""
    segs = np.array(segments, dtype=np.float64).reshape(-1, 4)
    cirs = np.array(circles, dtype=np.float64).reshape(-1, 3)
    dyn = np.concatenate([no_segments()] + [robot(*p, clockwise=cw) for p, cw, _ in robots])
    ids = np.repeat(np.array([i for _, _, i in robots], dtype=np.int64), 12)
    poses = np.array([p for p, _, _ in robots] + extra, dtype=np.float64).reshape(-1, 3)
    owners = np.array([i for _, _, i in robots] + [-1] * len(extra), dtype=np.int64)
    assume(len(poses) > 0)
    origins, headings = sensors_of(poses)
    assume(clear_of_ties(SPEC, origins, headings, np.concatenate([segs, dyn])))
    both(StaticScene(segs, cirs, SPEC.range_max), SPEC, origins, headings, owners, dyn, ids)


def clear_of_degenerate(origins: F64, segments: F64, circles: F64, margin: float = 1e-3) -> bool:
    """No segment and no circle boundary within margin of a sensor: with range_min ~0 the
    kernels may differ there (documented)."""
    if len(segments):
        a = segments[None, :, :2] - origins[:, None, :]
        e = segments[None, :, 2:] - segments[None, :, :2]
        ee = np.maximum(np.sum(e * e, axis=2), 1e-300)
        u = np.clip(-np.sum(a * e, axis=2) / ee, 0.0, 1.0)
        d = np.hypot(a[..., 0] + u * e[..., 0], a[..., 1] + u * e[..., 1])
        if (d < margin).any():
            return False
    if len(circles):
        d = np.hypot(circles[None, :, 0] - origins[:, None, 0], circles[None, :, 1] - origins[:, None, 1])
        if (np.abs(d - circles[None, :, 2]) < margin).any():
            return False
    return True


def clear_of_ties(spec: LidarSpec, origins: F64, headings: F64, segments: F64, tol: float = 1e-7) -> bool:
    """No segment end exactly on a beam's ray (within tol rad): such a ray may hit or miss it,
    and the kernels need not agree (e.g. with a full 2*pi of beams the first and the last beam
    coincide, and the numpy kernel may report a hit on one only)."""
    if len(segments) == 0:
        return True
    ends = np.concatenate([segments[:, :2], segments[:, 2:]])
    rel = ends[None, :, :] - origins[:, None, :]
    bearing = np.arctan2(rel[..., 1], rel[..., 0]) - (headings[:, None] + spec.angle_min)
    k = np.mod(bearing, 2 * math.pi) / spec.angle_increment  # beam units from the first beam
    near_beam = np.minimum(np.abs(k - np.round(k)), np.abs(k - (2 * math.pi / spec.angle_increment)))
    return bool(np.all(near_beam * spec.angle_increment > tol))


@st.composite
def specs(draw: st.DrawFn) -> LidarSpec:
    samples = draw(st.integers(2, 400))
    angle_min = draw(st.floats(-4.0, 4.0))
    fov = draw(st.sampled_from([2 * math.pi, 6.28, math.pi, 1.0]) | st.floats(0.05, 2 * math.pi))
    range_min = draw(st.sampled_from([0.0, 0.12]) | st.floats(0.0, 0.5))
    range_max = draw(st.floats(range_min + 0.1, 3.5))
    return LidarSpec(samples, angle_min, angle_min + fov, range_min, range_max)


@settings(max_examples=30, derandomize=True, deadline=None)
@given(
    spec=specs(),
    segments=st.lists(segment, max_size=8),
    circles=st.lists(circle, max_size=3),
    robots=st.lists(st.tuples(pose, st.booleans()), max_size=6),
    extra=st.lists(pose, min_size=1, max_size=3),
)
def test_random_specs(
    spec: LidarSpec,
    segments: list[tuple[float, float, float, float]],
    circles: list[tuple[float, float, float]],
    robots: list[tuple[tuple[float, float, float], bool]],
    extra: list[tuple[float, float, float]],
) -> None:
    """Beam layouts that wrap or not, short fields of view, range_min 0; robots of their own."""
    segs = np.array(segments, dtype=np.float64).reshape(-1, 4)
    cirs = np.array(circles, dtype=np.float64).reshape(-1, 3)
    dyn, ids = fleet(np.array([p for p, _ in robots]).reshape(-1, 3), np.arange(len(robots)))
    if robots:
        dyn = np.concatenate([robot(*p, clockwise=cw) for p, cw in robots])
    poses = np.array([p for p, _ in robots] + extra, dtype=np.float64).reshape(-1, 3)
    owners = np.concatenate([np.arange(len(robots)), np.full(len(extra), -1)]).astype(np.int64)
    origins, headings = sensors_of(poses)
    assume(clear_of_ties(spec, origins, headings, np.concatenate([segs, dyn])))
    if spec.range_min < 0.01:
        assume(clear_of_degenerate(origins, np.concatenate([segs, dyn]), cirs))
    both(StaticScene(segs, cirs, 3.5), spec, origins, headings, owners, dyn, ids)


# --- particular scenes ------------------------------------------------------------------------


def test_robots_overlapping_and_sensors_inside_shapes() -> None:
    """A pile of robots, sensors inside other robots, pillars and boxes (far sides seen)."""
    rng = np.random.default_rng(11)
    poses = np.column_stack([rng.uniform(-0.4, 0.4, 30), rng.uniform(-0.4, 0.4, 30), rng.uniform(-4, 4, 30)])
    dyn, ids = fleet(poses, np.arange(30) + 100)
    walls = np.concatenate([box(-0.3, -0.2, 0.25, 0.3), regular(0.1, -0.1, 0.5, 7), box(-3, -3, 3, 3)])
    pillars = np.array([[0.0, 0.0, 0.35], [0.2, 0.25, 0.9], [-1.0, 0.5, 0.2]])
    origins, headings = sensors_of(poses)
    ref, _ = both(StaticScene(walls, pillars, 3.5), SPEC, origins, headings, np.arange(30) + 100, dyn, ids)
    assert np.isfinite(ref).mean() > 0.9


def test_empty_static_scene() -> None:
    rng = np.random.default_rng(12)
    poses = np.column_stack([rng.uniform(-3, 3, 40), rng.uniform(-3, 3, 40), rng.uniform(-4, 4, 40)])
    dyn, ids = fleet(poses, np.arange(40))
    origins, headings = sensors_of(poses)
    ref, _ = both(StaticScene(no_segments(), no_circles()), SPEC, origins, headings, np.arange(40), dyn, ids)
    assert np.isfinite(ref).any()


def test_no_dynamic_segments() -> None:
    rng = np.random.default_rng(13)
    walls = np.concatenate([box(-4, -4, 4, 4), box(-1, -1, 0.5, 0.2), regular(2, 2, 0.7, 5)])
    pillars = np.column_stack([rng.uniform(-3, 3, 12), rng.uniform(-3, 3, 12), rng.uniform(0.05, 0.4, 12)])
    origins = np.column_stack([rng.uniform(-3.5, 3.5, 50), rng.uniform(-3.5, 3.5, 50)])
    headings = rng.uniform(-7, 7, 50)
    scene = StaticScene(walls, pillars, 3.5)
    ref, _ = both(scene, SPEC, origins, headings, np.arange(50), no_segments(), np.zeros(0, dtype=np.int64))
    assert np.isfinite(ref).mean() > 0.5


def test_no_sensors() -> None:
    scene = StaticScene(box(-1, -1, 1, 1), no_circles())
    dyn, ids = fleet(np.array([[0.0, 0.0, 0.0]]), np.arange(1))
    out = lidar.cast_native(scene, SPEC, np.zeros((0, 2)), np.zeros(0), np.zeros(0, dtype=np.int64), dyn, ids)
    assert out.shape == (0, SPEC.samples) and out.dtype == np.float32


def test_world_large_enough_for_the_static_cell_to_double() -> None:
    """Walls 6 km apart: the static grid cell grows past STATIC_CELL; sensors near each wall,
    far from everything and outside the grid."""
    walls = np.concatenate([box(-3000, -3000, 3000, 3000), box(-3003, -3003, -2997, -2997), box(10, 10, 12, 11)])
    pillars = np.array([[2999.0, 0.0, 0.5], [11.0, 12.0, 0.3]])
    scene = StaticScene(walls, pillars, 3.5)
    assert scene.cell > lidar.STATIC_CELL
    origins = np.array(
        [[2998.0, 0.5], [-2999.0, -2999.5], [0.0, 2999.0], [11.0, 10.5], [11.0, 9.0], [0.0, 0.0], [9e3, 9e3]]
    )
    headings = np.array([0.1, 2.0, -1.0, 3.0, 1.5, 0.0, 0.7])
    ref, _ = both(scene, SPEC, origins, headings, np.arange(7), no_segments(), np.zeros(0, dtype=np.int64))
    assert np.isfinite(ref[:5]).any(axis=1).all() and np.isinf(ref[5:]).all()


def test_many_robots_spread_wide() -> None:
    """1 500 robots in clusters spread over 2 km (both dynamic grids grow their cells), 200
    sensors; crowded clusters so that most sensors see many robots."""
    rng = np.random.default_rng(14)
    centres = rng.uniform(-1000, 1000, size=(30, 2))
    poses = np.column_stack(
        [
            np.repeat(centres, 50, axis=0) + rng.normal(0, 2.0, size=(1500, 2)),
            rng.uniform(-np.pi, np.pi, 1500),
        ]
    )
    ids = rng.permutation(1500) + 7
    dyn, dyn_owner = fleet(poses, ids)
    rows = rng.choice(1500, 200, replace=False)
    origins, headings = sensors_of(poses[rows])
    pillars = np.column_stack([centres + 1.0, np.full(30, 0.3)])
    ref, _ = both(StaticScene(no_segments(), pillars, 3.5), SPEC, origins, headings, ids[rows], dyn, dyn_owner)
    assert np.isfinite(ref).mean() > 0.3


def test_segments_in_any_order_and_long_outlines() -> None:
    """Outlines shuffled (groups of one), runs longer than GROUP_MAX, wide groups split, open
    chains, zero-length and repeated segments: the grouping must not change any result."""
    rng = np.random.default_rng(15)
    poses = np.column_stack([rng.uniform(-2, 2, 12), rng.uniform(-2, 2, 12), rng.uniform(-4, 4, 12)])
    dyn, ids = fleet(poses, np.arange(12) % 5)  # owners repeat: runs of 24 and 36 segments
    order = rng.permutation(len(dyn))
    long_wall = regular(0.5, -0.5, 1.5, 40)  # one owner, 40 segments, wider than GROUP_MAX_RADIUS
    dot = np.array([[1.0, 1.0, 1.0, 1.0], [1.0, 1.0, 1.0, 1.0]])
    segments = np.concatenate([dyn, dyn[order], long_wall, dot, long_wall[:7]])
    owner = np.concatenate([ids, ids[order], np.full(40, 50), [51, 51], np.full(7, 52)]).astype(np.int64)
    origins, headings = sensors_of(poses)
    scene = StaticScene(box(-4, -4, 4, 4), no_circles())
    both(scene, SPEC, origins, headings, np.arange(12) % 5, segments, owner)


@pytest.mark.parametrize(
    "spec",
    [
        LidarSpec(samples=90, angle_min=0.0, angle_max=2 * math.pi, range_min=0.0, range_max=3.5),
        LidarSpec(samples=181, angle_min=-math.pi / 2, angle_max=math.pi / 2, range_min=0.05, range_max=2.0),
        LidarSpec(samples=720, angle_min=-math.pi, angle_max=math.pi - 2 * math.pi / 720, range_min=0.1),
        LidarSpec(samples=7, angle_min=-1.0, angle_max=2.0, range_min=0.0, range_max=1.0),
        LidarSpec(samples=2, angle_min=0.5, angle_max=6.0, range_min=0.3, range_max=3.0),
    ],
    ids=["90_full_turn_rmin0", "181_half_turn", "720", "7_partial_rmin0", "2_beams"],
)
def test_other_lidar_layouts(spec: LidarSpec) -> None:
    rng = np.random.default_rng(16)
    poses = np.column_stack([rng.uniform(-2, 2, 25), rng.uniform(-2, 2, 25), rng.uniform(-7, 7, 25)])
    dyn, ids = fleet(poses, np.arange(25))
    walls = np.concatenate([box(-3, -3, 3, 3), regular(1.0, 0.5, 0.3, 6)])
    pillars = np.array([[-1.0, -1.0, 0.25], [0.5, 1.5, 0.6]])
    origins, headings = sensors_of(poses)
    assert clear_of_degenerate(origins, np.concatenate([walls, dyn]), pillars)
    both(StaticScene(walls, pillars, 3.5), spec, origins, headings, np.arange(25), dyn, ids)


def test_cast_dispatches_to_the_native_kernel() -> None:
    if lidar.KERNEL != "native":
        pytest.skip(f"KERNEL is {lidar.KERNEL!r}")
    scene = StaticScene(box(-2, -2, 2, 2), np.array([[0.5, 0.5, 0.2]]))
    dyn, ids = fleet(np.array([[1.0, -1.0, 0.3]]), np.arange(1) + 5)
    args = (scene, SPEC, np.array([[0.0, 0.0]]), np.array([0.4]), np.array([1]), dyn, ids)
    assert np.array_equal(lidar.cast(*args), lidar.cast_native(*args))


def test_non_finite_inputs_do_not_crash() -> None:
    """NaN and infinite coordinates give misses (the numpy kernel raises on some of them)."""
    scene = StaticScene(box(-2, -2, 2, 2), np.array([[0.5, 0.5, 0.2]]))
    dyn, ids = fleet(np.array([[1.0, -1.0, 0.3], [0.0, 1.0, 1.0]]), np.arange(2))
    dyn[3, 0] = np.nan
    dyn[14, 2] = np.inf
    origins = np.array([[0.0, 0.0], [np.nan, 0.0], [np.inf, 1.0], [0.2, 0.1]])
    headings = np.array([0.0, 0.0, 0.0, np.nan])
    out = lidar.cast_native(scene, SPEC, origins, headings, np.full(4, -1), dyn, ids)
    assert out.shape == (4, SPEC.samples)
    assert np.isfinite(out[0]).any() and np.isinf(out[1:]).all()


def test_threads_share_nothing() -> None:
    """Casts running at once in threads (the GIL is released) give the sequential results."""
    rng = np.random.default_rng(17)
    poses = np.column_stack([rng.uniform(-5, 5, 300), rng.uniform(-5, 5, 300), rng.uniform(-4, 4, 300)])
    dyn, ids = fleet(poses, np.arange(300))
    scene = StaticScene(box(-6, -6, 6, 6), np.array([[0.0, 0.0, 0.5]]))
    origins, headings = sensors_of(poses)
    batches = [np.arange(i, 300, 8) for i in range(8)]

    def run(rows: I64) -> npt.NDArray[np.float32]:
        return lidar.cast_native(scene, SPEC, origins[rows], headings[rows], rows, dyn, ids)

    sequential = [run(rows) for rows in batches]
    with ThreadPoolExecutor(max_workers=4) as pool:
        concurrent = list(pool.map(run, batches * 3))
    for i, out in enumerate(concurrent):
        assert np.array_equal(out, sequential[i % len(batches)])


# --- choice of kernel -------------------------------------------------------------------------


def kernel_in_subprocess(env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    code = "from simd.core import lidar; print(lidar.KERNEL, lidar.NATIVE_UNAVAILABLE)"
    clean = {k: v for k, v in os.environ.items() if k not in ("FLEETSIM_LIDAR", "FLEETSIM_NATIVE")}
    return subprocess.run(
        [sys.executable, "-c", code], env={**clean, **env}, cwd=ROOT, capture_output=True, text=True, timeout=60
    )


def test_environment_chooses_the_kernel() -> None:
    forced = kernel_in_subprocess({"FLEETSIM_LIDAR": "numpy"})
    assert forced.returncode == 0 and forced.stdout.split()[:2] == ["numpy", "FLEETSIM_LIDAR=numpy"], forced
    bad = kernel_in_subprocess({"FLEETSIM_LIDAR": "fast"})
    assert bad.returncode != 0 and "FLEETSIM_LIDAR='fast'" in bad.stderr, bad


# --- argument checks of simd.core.lidar._raycast.cast ----------------------------------------------------


def native_module() -> ModuleType:
    return importlib.import_module("simd.core.lidar._raycast")


def valid_args() -> list[Any]:
    """A valid positional argument list of simd.core.lidar._raycast.cast (3 sensors, 2 robots)."""
    scene = StaticScene(box(-2, -2, 2, 2), np.array([[0.5, 0.5, 0.2]]))
    dyn, ids = fleet(np.array([[1.0, -1.0, 0.3], [-1.0, 1.0, 2.0]]), np.arange(2))
    origins = np.array([[0.0, 0.0], [1.0, 1.0], [-1.0, -1.0]])
    h0 = np.array([0.0, 1.0, 2.0]) + SPEC.angle_min
    owners = np.array([-1, 0, 1], dtype=np.int64)
    out = np.empty((3, SPEC.samples))
    return [
        *scene._native_args,
        origins,
        h0,
        np.cos(h0),
        np.sin(h0),
        owners,
        dyn,
        ids,
        *lidar.native_spec_args(SPEC),
        out,
    ]


NAMES = [
    "pieces", "circles", "seg_bounds", "seg_items", "cir_bounds", "cir_items", "grid_x0", "grid_y0", "grid_cell",
    "grid_nx", "grid_ny", "origins", "h0", "cos_h0", "sin_h0", "owners", "dyn_segments", "dyn_owner", "table",
    "samples", "angle_increment", "range_min", "range_max", "eps_angle", "eps_seg", "eps_cull", "group_max",
    "group_max_radius", "dyn_cell", "out",
]  # fmt: skip


def test_valid_arguments_work() -> None:
    args = valid_args()
    assert len(args) == len(NAMES)
    native_module().cast(*args)
    assert np.isfinite(args[-1]).any()
    kwargs = dict(zip(NAMES, valid_args(), strict=True))
    native_module().cast(**kwargs)
    out32 = np.empty((3, SPEC.samples), dtype=np.float32)
    native_module().cast(*valid_args()[:-1], out32)
    assert np.array_equal(out32, args[-1].astype(np.float32))


Change = Callable[[Any], Any]

BAD: list[tuple[str, str, Change, type[Exception]]] = [
    ("origins", "float32", lambda a: a.astype(np.float32), TypeError),
    ("owners", "int32", lambda a: a.astype(np.int32), TypeError),
    ("dyn_owner", "float64", lambda a: a.astype(np.float64), TypeError),
    ("pieces", "int64", lambda a: a.astype(np.int64), TypeError),
    ("out", "float16", lambda a: np.zeros(a.shape, dtype=np.float16), TypeError),
    ("out", "int64", lambda a: np.zeros(a.shape, dtype=np.int64), TypeError),
    ("origins", "big-endian", lambda a: a.astype(">f8"), TypeError),
    ("origins", "list", lambda a: a.tolist(), TypeError),
    ("table", "bytes", lambda a: a.tobytes(), TypeError),
    ("h0", "None", lambda a: None, TypeError),
    ("origins", "strided", lambda a: np.repeat(a, 2, axis=0)[::2], ValueError),
    ("dyn_segments", "transposed", lambda a: np.asfortranarray(a), ValueError),
    ("origins", "3 columns", lambda a: np.zeros((3, 3)), ValueError),
    ("origins", "3-d", lambda a: a.reshape(3, 1, 2), ValueError),
    ("h0", "too short", lambda a: a[:2], ValueError),
    ("cos_h0", "too long", lambda a: np.append(a, 1.0), ValueError),
    ("owners", "2-d", lambda a: a.reshape(3, 1), ValueError),
    ("dyn_owner", "too short", lambda a: a[:-1], ValueError),
    ("dyn_segments", "odd length", lambda a: a.ravel()[:-1], ValueError),
    ("table", "too short", lambda a: a[:, :-1].copy(), ValueError),
    ("seg_bounds", "too short", lambda a: a[:-1], ValueError),
    ("cir_bounds", "too long", lambda a: np.append(a, a[-1]), ValueError),
    ("out", "too few rows", lambda a: a[:2], ValueError),
    ("out", "wrong width", lambda a: np.empty((3, 359)), ValueError),
    ("out", "read-only", lambda a: np.lib.stride_tricks.as_strided(a, writeable=False), ValueError),
    ("out", "strided", lambda a: np.empty((3, 720))[:, ::2], ValueError),
    ("samples", "0", lambda a: 0, ValueError),
    ("samples", "huge", lambda a: 1 << 40, ValueError),
    ("angle_increment", "0", lambda a: 0.0, ValueError),
    ("angle_increment", "nan", lambda a: math.nan, ValueError),
    ("eps_angle", "negative", lambda a: -1.0, ValueError),
    ("group_max", "0", lambda a: 0, ValueError),
    ("group_max", "1000", lambda a: 1000, ValueError),
    ("grid_nx", "0", lambda a: 0, ValueError),
    ("grid_ny", "huge", lambda a: 1 << 62, ValueError),
    ("grid_cell", "0", lambda a: 0.0, ValueError),
    ("grid_nx", "str", lambda a: "3", TypeError),
    # numbers that would reach the grids' float-to-index conversions as NaN or infinity
    ("range_max", "nan", lambda a: math.nan, ValueError),
    ("range_max", "1e200", lambda a: 1e200, ValueError),
    ("range_min", "nan", lambda a: math.nan, ValueError),
    ("range_min", "above range_max", lambda a: 10.0, ValueError),
    ("eps_cull", "nan", lambda a: math.nan, ValueError),
    ("eps_seg", "inf", lambda a: math.inf, ValueError),
    ("group_max_radius", "nan", lambda a: math.nan, ValueError),
    ("dyn_cell", "subnormal", lambda a: 1e-310, ValueError),
    ("grid_x0", "inf", lambda a: math.inf, ValueError),
    ("grid_cell", "inf", lambda a: math.inf, ValueError),
]


@pytest.mark.parametrize(("name", "what", "change", "error"), BAD, ids=[f"{b[0]}-{b[1]}" for b in BAD])
def test_bad_arguments_raise(name: str, what: str, change: Change, error: type[Exception]) -> None:
    args = valid_args()
    i = NAMES.index(name)
    args[i] = change(args[i])
    with pytest.raises(error):
        native_module().cast(*args)


def test_wrong_argument_count_raises() -> None:
    with pytest.raises(TypeError):
        native_module().cast(*valid_args()[:-1])
    with pytest.raises(TypeError):
        native_module().cast(*valid_args(), None)


@pytest.mark.parametrize(
    "corrupt",
    [
        lambda b, i: (b, np.where(i == i.max(), 10**9, i)),  # an item past the pieces
        lambda b, i: (b, -np.ones_like(i)),  # negative items
        lambda b, i: (np.where(np.arange(len(b)) == len(b) // 2, 10**12, b), i),  # a bound past the items
        lambda b, i: (b[::-1].copy(), i),  # decreasing bounds
    ],
    ids=["item_past_end", "negative_item", "bound_past_end", "decreasing_bounds"],
)
def test_inconsistent_static_grid_raises(corrupt: Callable[[I64, I64], tuple[I64, I64]]) -> None:
    """Every sensor cell's list is read, and checked as it is read."""
    args = valid_args()
    nx, ny = args[9], args[10]
    args[2], args[3] = corrupt(args[2], args[3])
    # sensors in every cell of the grid, so that the corrupt one is read
    gx, gy, cell = args[6], args[7], args[8]
    ix, iy = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    origins = np.column_stack([gx + (ix.ravel() + 0.5) * cell, gy + (iy.ravel() + 0.5) * cell])
    n = len(origins)
    args[11], args[12], args[13], args[14] = origins, np.zeros(n), np.ones(n), np.zeros(n)
    args[15] = np.full(n, -1, dtype=np.int64)
    args[-1] = np.empty((n, SPEC.samples))
    with pytest.raises(ValueError, match="inconsistent static grid"):
        native_module().cast(*args)


@pytest.mark.parametrize(
    "spec", [dict(range_max=1e200), dict(range_max=math.inf), dict(range_max=math.nan), dict(samples=1 << 25)]
)
def test_specs_the_kernels_cannot_serve_are_refused(spec: dict[str, float]) -> None:
    with pytest.raises(ValueError):
        LidarSpec(**spec)  # type: ignore[arg-type]


@pytest.mark.parametrize(("robots", "corners"), [(0, 4), (1, 1), (5, 3), (300, 12)])
def test_outline_segments_twins_give_the_same_bits(robots: int, corners: int) -> None:
    """The robots' outlines in the world frame, compiled and numpy, against the plain formula."""
    rng = np.random.default_rng(21 + robots)
    x, y, yaw = rng.uniform(-60, 60, robots), rng.uniform(-60, 60, robots), rng.uniform(-7, 7, robots)
    outline = rng.uniform(-0.3, 0.3, (robots, corners, 2))
    c, s = np.cos(yaw), np.sin(yaw)
    ox, oy = outline[:, :, 0], outline[:, :, 1]
    wx = x[:, None] + ox * c[:, None] - oy * s[:, None]
    wy = y[:, None] + ox * s[:, None] + oy * c[:, None]
    want = np.stack([wx, wy, np.roll(wx, -1, axis=1), np.roll(wy, -1, axis=1)], axis=2).reshape(-1, 4)
    for kernel in ("native", "numpy"):
        got = lidar.outline_segments(x, y, c, s, outline, kernel=kernel)
        assert got.shape == (robots * corners, 4)
        assert got.tobytes() == want.tobytes(), kernel


def test_outline_segments_refuses_what_does_not_fit() -> None:
    from simd.core.lidar import native_kernel

    ones, outline, out = np.ones(3), np.zeros((6, 2)), np.empty((6, 4))
    with pytest.raises(ValueError, match="corners"):
        native_kernel.outline_segments(ones, ones, ones, ones, outline, 0, out)
    with pytest.raises(ValueError, match="outline"):
        native_kernel.outline_segments(ones, ones, ones, ones, outline, 3, np.empty((9, 4)))
    with pytest.raises(ValueError, match="y"):
        native_kernel.outline_segments(ones, np.ones(2), ones, ones, outline, 2, out)
    with pytest.raises(TypeError, match="x"):
        native_kernel.outline_segments(np.ones(3, dtype=np.float32), ones, ones, ones, outline, 2, out)
    read_only = np.empty((6, 4))
    read_only.setflags(write=False)
    with pytest.raises(ValueError, match="writable"):
        native_kernel.outline_segments(ones, ones, ones, ones, outline, 2, read_only)
    native_kernel.outline_segments(ones, ones, ones, ones, outline, 2, out)  # and what fits runs
    assert np.array_equal(out[:, :2], np.ones((6, 2))) and np.array_equal(out[:, 2:], np.ones((6, 2)))
