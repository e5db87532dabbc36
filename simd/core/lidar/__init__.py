"""2D ray casting for the TurtleBot3 LDS-01 lidar: a numpy kernel and its compiled twin.

Contract (Gazebo ``ray`` sensor semantics, before noise and masking, which the caller applies):

* A sensor at ``origin`` with yaw ``heading`` fires ``spec.samples`` rays at the angles
  ``heading + angle_min + k * angle_increment``; the last ray is at ``angle_max`` (6.28 for the
  LDS-01, 0.0032 rad short of a full turn: no beam looks into that gap).
* A ray starts at ``range_min`` from the origin.  The result is the distance from the origin to
  the first crossing of an obstacle *boundary* at a distance ``t`` with
  ``range_min <= t <= range_max``, or ``+inf`` when there is none.
* Consequently a ray that starts inside a circle or a closed polygon reports that shape's far
  side (its boundary), as in Gazebo, whose rays also start at ``range_min``; anything nearer
  than ``range_min`` is invisible.
* Obstacles are static segments (polygons given as their edges), static circles, and the robots'
  outline segments (``dyn_segments``), each tagged with its robot id; a sensor never sees the
  segments of its own robot.
* A ray exactly collinear with a segment does not hit that segment, and a ray that grazes a free
  segment end, a circle tangentially or a range limit to within rounding may go either way
  (measure-zero cases; a closed outline still stops a ray at its vertices, see EPS_SEG).

Two kernels.  ``cast`` runs the compiled kernel, simd/core/lidar/_raycast.c (module ``simd.core.lidar._raycast``, built
with the package where there is a C compiler), else the numpy kernel, ``cast_numpy``, which stays
the reference: tests/core/test_lidar_native.py checks that both return the same bits, and
tests/core/test_lidar.py checks both against an independent per-beam oracle.  ``KERNEL`` names the one
that ``cast`` uses ("native" or "numpy"; ``NATIVE_UNAVAILABLE`` says why not native).
``FLEETSIM_LIDAR=numpy`` forces numpy, ``=native`` fails at import if the module is missing, and
``auto`` (the default) takes what is there; when FLEETSIM_LIDAR is unset, the switch of all the
compiled fast paths, FLEETSIM_NATIVE, decides alike.

Why a compiled twin.  The numpy kernel below pays for ~200 numpy calls and a few MB of
temporaries per batch, whatever the batch: with 100 robots a batch of 100 sensors took ~2 ms
here (~6.5 ms measured inside the busy daemon, ~30% of its tick).  The C kernel does the same work
sensor by sensor, in registers and one row of scratch, with the GIL released.  Medians of
bench/lidar_bench.py (the two kernels interleaved call by call, on the 2-core development VM):

    world (bench/lidar_bench.py)    robots  sensors    numpy    native   speed-up
    arena (bench/arena.py grid)        100      100   2.05 ms  0.34 ms     6.0x
    arena                             1000      100   3.32 ms  0.56 ms     6.0x
    arena                             1000      167   5.19 ms  0.91 ms     5.8x
    random (60 m square)               100      100   2.05 ms  0.29 ms     7.1x
    random                            1000      100   4.44 ms  0.80 ms     5.6x
    random                            1000      167   5.87 ms  1.14 ms     5.0x

(the naive every-beam-x-every-primitive reference takes 45-350 ms for these, 150-330x the C
kernel); alone, without the numpy calls in between to evict its data, the C kernel runs ~30%
faster.  Its cost is spread over many small pieces (a few hundred cycles per robot in range:
finding the group, its beam run, ~6 front faces of 8-beam vector chunks, each a division per
beam), which is why it does not go much further single-threaded.

Where each part lives: ``spec`` (the layout and the shared tolerances), ``scene`` (the
static geometry's grid), ``dyngrid`` (the robots' outlines of one call), ``numpy_kernel`` (the
reference; why it has its shape is in its docstring) and ``native_kernel`` (the compiled twin and
how it keeps the reference's results).
"""

from __future__ import annotations

import functools

import numpy as np

from fleetcommon.arrays import F32, F64, I64
from simd.core.lidar import native_kernel, numpy_kernel
from simd.core.lidar.native_kernel import KERNEL, NATIVE_UNAVAILABLE, native_spec_args
from simd.core.lidar.outlines import outline_segments
from simd.core.lidar.scene import StaticScene
from simd.core.lidar.spec import EPS_CULL, STATIC_CELL, LidarSpec

__all__ = [
    "KERNEL",
    "NATIVE_UNAVAILABLE",
    "STATIC_CELL",
    "LidarSpec",
    "StaticScene",
    "cast",
    "cast_native",
    "cast_numpy",
    "native_spec_args",
    "outline_segments",
]


def _inputs(scene: StaticScene, spec: LidarSpec, *arrays: np.ndarray) -> tuple[F64, F64, I64, F64, I64]:
    """Checked, contiguous float64 / int64 copies (or views) of ``cast``'s array arguments, in
    its order: origins, headings, sensor_owner, dyn_segments, dyn_owner."""
    origins, headings, sensor_owner, dyn_segments, dyn_owner = arrays
    org = np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 2)
    hdg = np.ascontiguousarray(headings, dtype=np.float64).reshape(-1)
    sown = np.ascontiguousarray(sensor_owner, dtype=np.int64).reshape(-1)
    dseg = np.ascontiguousarray(dyn_segments, dtype=np.float64).reshape(-1, 4)
    down = np.ascontiguousarray(dyn_owner, dtype=np.int64).reshape(-1)
    if len(hdg) != len(org) or len(sown) != len(org) or len(down) != len(dseg):
        raise ValueError("origins/headings/sensor_owner and dyn_segments/dyn_owner lengths differ")
    if spec.range_max > scene.range_max + EPS_CULL:
        raise ValueError("spec.range_max exceeds the range the StaticScene was indexed for")
    return org, hdg, sown, dseg, down


def _cast64_numpy(scene: StaticScene, spec: LidarSpec, org: F64, hdg: F64, sown: I64, dseg: F64, down: I64) -> F64:
    """The numpy kernel on checked inputs, in float64 (for the kernels' bit-for-bit tests)."""
    return numpy_kernel.cast64(scene, spec, org, hdg, sown, dseg, down)


def _cast64_native(scene: StaticScene, spec: LidarSpec, org: F64, hdg: F64, sown: I64, dseg: F64, down: I64) -> F64:
    """The compiled kernel on checked inputs, in float64 (for the kernels' bit-for-bit tests)."""
    return native_kernel.cast(scene, spec, org, hdg, sown, dseg, down, np.float64).astype(np.float64, copy=False)


def cast(
    scene: StaticScene,
    spec: LidarSpec,
    origins: np.ndarray,
    headings: np.ndarray,
    sensor_owner: np.ndarray,
    dyn_segments: np.ndarray,
    dyn_owner: np.ndarray,
    *,
    kernel: str | None = None,
) -> F32:
    """Cast every beam of every sensor; see the module docstring for the contract.

    origins (N, 2) sensor positions; headings (N,) sensor yaw; sensor_owner (N,) robot id of each
    sensor; dyn_segments (M, 4) robot outline edges ``x0, y0, x1, y1`` in the world frame;
    dyn_owner (M,) their robot ids.  Returns (N, samples) float32 distances, ``+inf`` where no
    boundary is crossed within [range_min, range_max].  ``kernel`` is "native" or "numpy"; by
    default the one ``KERNEL`` names.
    """
    args = _inputs(scene, spec, origins, headings, sensor_owner, dyn_segments, dyn_owner)
    if (kernel or KERNEL) == "native":
        return native_kernel.cast(scene, spec, *args, np.float32).astype(np.float32, copy=False)
    return numpy_kernel.cast64(scene, spec, *args).astype(np.float32)


#: ``cast`` with the numpy kernel (the reference), whatever ``KERNEL`` is.
cast_numpy = functools.partial(cast, kernel="numpy")
#: ``cast`` with the compiled kernel; RuntimeError if it is not available (see ``KERNEL``).
cast_native = functools.partial(cast, kernel="native")
