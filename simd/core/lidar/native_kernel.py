"""The compiled kernel (simd/core/lidar/_raycast.c): its typed interface, its arguments, and
how it is found (simd/core/native.py's registry; ``FLEETSIM_LIDAR`` overrides the switch).

How the C kernel keeps the numpy kernel's results.  Every number that a hit distance is made of
is the same float64 expression of the same inputs, in the same order: cos/sin of the beam-0
bearings and the beam table come from numpy, outline groups, their closed-loop test and their
orientation are worked out as here, and the file is compiled with -ffp-contract=off (no FMA) and
without -ffast-math.  What differs is only which beams are *tested* for a primitive: the C kernel
takes bearings in float64 and pads arcs by EPS_ANGLE_NATIVE, tests a robot outline on all the
beams of its bounding circle when they are few, tests beams in chunks of 8, skips static pieces
beyond range_max, and culls back faces and groups on a radius bound 1e-12 above numpy's.  It
tests every (primitive, beam) pair that the numpy kernel tests, so the scans are bit for bit the
same (7 000 random scenes and specs: no beam differed; 10 000 more with sensors snapped onto the
geometry: only the cases below) except where an extra pair hits, which takes a degenerate case:
with range_min ~0, a sensor on (within ~1e-4 m of) a segment or a circle boundary, where every
ray meets it at t ~ 0 and the numpy kernel reports only the beams of the arc it picked; and a ray
exactly through a segment end (e.g. with a full 2*pi of beams the first and the last beam
coincide, and a segment that starts exactly on that ray is hit by both in C, by one in numpy).
Non-finite coordinates: the numpy kernel may raise, the C kernel reports misses.
"""

from __future__ import annotations

import functools
from typing import Protocol
from typing import cast as _typed

import numpy as np
import numpy.typing as npt

from fleetcommon.arrays import F64, I64
from simd.core import native
from simd.core.lidar.scene import StaticScene
from simd.core.lidar.spec import (
    DYN_CELL,
    EPS_ANGLE_NATIVE,
    EPS_CULL,
    EPS_SEG,
    GROUP_MAX,
    GROUP_MAX_RADIUS,
    LidarSpec,
    beam_table,
)

# The compiled kernel's arguments (_raycast.c, cast): the static scene's index (scene.SceneArgs),
# the sensors and moving segments of the call, the spec and the tolerances, the output rows.
_SpecArgs = tuple[F64, int, float, float, float, float, float, float, int, float, float]


class _NativeModule(Protocol):
    """The API of the compiled kernel, simd.core.lidar._raycast (simd/core/lidar/_raycast.c)."""

    def cast(
        self,
        pieces: F64,
        circles: F64,
        seg_bounds: I64,
        seg_items: I64,
        cir_bounds: I64,
        cir_items: I64,
        grid_x0: float,
        grid_y0: float,
        grid_cell: float,
        grid_nx: int,
        grid_ny: int,
        origins: F64,
        h0: F64,
        cos_h0: F64,
        sin_h0: F64,
        owners: I64,
        dyn_segments: F64,
        dyn_owner: I64,
        table: F64,
        samples: int,
        angle_increment: float,
        range_min: float,
        range_max: float,
        eps_angle: float,
        eps_seg: float,
        eps_cull: float,
        group_max: int,
        group_max_radius: float,
        dyn_cell: float,
        out: npt.NDArray[np.float64] | npt.NDArray[np.float32],
        /,
    ) -> None: ...

    def outline_segments(
        self, x: F64, y: F64, cos_yaw: F64, sin_yaw: F64, outline: F64, corners: int, out: F64, /
    ) -> None: ...


@functools.lru_cache(maxsize=8)
def native_spec_args(spec: LidarSpec) -> _SpecArgs:
    return (
        beam_table(spec),
        spec.samples,
        spec.angle_increment,
        spec.range_min,
        spec.range_max,
        EPS_ANGLE_NATIVE,
        EPS_SEG,
        EPS_CULL,
        GROUP_MAX,
        GROUP_MAX_RADIUS,
        DYN_CELL,
    )


def _load_native() -> tuple[_NativeModule | None, str | None]:
    """The compiled kernel, or None and the reason why it is not used (simd/core/native.py's switch,
    which FLEETSIM_LIDAR overrides for the lidar alone)."""
    module, why = native.load("raycast")
    return (_typed(_NativeModule, module), None) if module is not None else (None, why)


_NATIVE, NATIVE_UNAVAILABLE = _load_native()

#: The kernel that ``cast`` uses: "native" (simd.core.lidar._raycast) or "numpy" (``cast_numpy``).
#: ``NATIVE_UNAVAILABLE`` says why the native kernel is not used, when it is not.
KERNEL = "native" if _NATIVE is not None else "numpy"


def cast(
    scene: StaticScene, spec: LidarSpec, org: F64, hdg: F64, sown: I64, dseg: F64, down: I64, dtype: type[np.floating]
) -> npt.NDArray[np.floating]:
    """The compiled kernel on checked inputs (see ``_inputs`` in __init__.py): (N, samples)
    distances of ``dtype`` (float64, or float32 rounded in C)."""
    if _NATIVE is None:
        raise RuntimeError(f"the native lidar kernel is not available: {NATIVE_UNAVAILABLE}")
    out = np.empty((len(org), spec.samples), dtype=dtype)
    if len(org) == 0:
        return out
    h0 = hdg + spec.angle_min  # beam-0 bearings; cos/sin from numpy, exactly as the numpy kernel
    _NATIVE.cast(*scene._native_args, org, h0, np.cos(h0), np.sin(h0), sown, dseg, down, *native_spec_args(spec), out)
    return out


def outline_segments(x: F64, y: F64, cos_yaw: F64, sin_yaw: F64, outline: F64, corners: int, out: F64) -> None:
    """The compiled ``outline_segments`` (see simd/core/lidar/outlines.py) into ``out``."""
    if _NATIVE is None:
        raise RuntimeError(f"the native lidar kernel is not available: {NATIVE_UNAVAILABLE}")
    _NATIVE.outline_segments(x, y, cos_yaw, sin_yaw, outline, corners, out)
